"""The structured walk's entries on threads (simulate.structwalk.threads via simulate.structwalk.walk.walk_structure):
the same arrays as the serial walk, bit for bit; one monotone progress; a failing or interrupted walk stops
the other workers at their next tick and skips the entries not started; ``--threads 1`` is serial.

The walks are tiny (one wavelength, three absorption nodes, the fit's smallest photons per row): two entries
(one chunk per half), i.e. two workers.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from simulate.config import load_config
from simulate.fiber import tablecache
from simulate.fiber.absorption import absorption_nodes
from simulate.structwalk import threads as walk_threads
from simulate.structwalk import walk as fit_structure

WL1 = np.array([550.0])
NODES = absorption_nodes(1.0, 3)
TARGET = 0.1


def _walk(threads, cache=False, progress=None):
    config = load_config("green-felt")
    nodye = dataclasses.replace(config, dye=None).fiber(WL1)
    return fit_structure.walk_structure(nodye, config, WL1, NODES, target_rel_err=TARGET, seed=3, threads=threads,
                                        cache=cache, progress=progress)


def test_plan_splits_the_budget_and_one_thread_is_serial():
    assert walk_threads.plan(1, 6) == (1, 1)
    assert walk_threads.plan(2, 6) == (2, 1)
    assert walk_threads.plan(4, 6) == (2, 2)
    assert walk_threads.plan(2, 1) == (1, 2)         # one entry left: the walk's own threads
    assert walk_threads.plan(2, 0) == (1, 2)


def test_automatic_budget_takes_a_second_worker_only_on_an_idle_core(monkeypatch):
    monkeypatch.setattr(walk_threads.numba, "get_num_threads", lambda: 2)
    monkeypatch.setattr(walk_threads, "idle_cores", lambda: 0.1)
    assert walk_threads.plan(None, 6) == (1, None)    # the other core busy: the serial walk
    assert walk_threads.plan(2, 6) == (2, 1)          # asked for explicitly: two workers anyway
    monkeypatch.setattr(walk_threads, "idle_cores", lambda: 1.2)
    assert walk_threads.plan(None, 6) == (2, 1)
    monkeypatch.setattr(walk_threads, "idle_cores", lambda: None)   # no /proc/stat: the budget decides
    assert walk_threads.plan(None, 6) == (2, 1)


def test_idle_cores_is_within_the_machine():
    idle = walk_threads.idle_cores(0.05)
    import os
    assert idle is None or 0.0 <= idle <= (os.cpu_count() or 1) + 1e-9


def test_threaded_walk_is_the_serial_walk_bit_for_bit(cache_dir):
    calls = []
    serial = _walk(1)
    threaded = _walk(2, cache=True, progress=lambda p, r, n: calls.append((p, r, n)))
    assert threaded.cache == "miss" and len(tablecache.entries(cache_dir)) == 2   # each entry stored
    assert len(serial.G) == len(threaded.G) == 2
    for a, b in zip(serial.G, threaded.G, strict=True):
        assert a.shape == b.shape and np.any(a != 0)
        np.testing.assert_array_equal(a, b)
    assert serial.scatterings == threaded.scatterings
    assert [g.tolist() for g in serial.groups] == [g.tolist() for g in threaded.groups]
    assert serial.photons == threaded.photons
    # one progress, monotone, ending at every photon and run
    photons, runs = [c[0] for c in calls], [c[1] for c in calls]
    assert photons == sorted(photons) and runs == sorted(runs)
    assert calls[0][:2] == (0, 0) and calls[-1] == (threaded.photons["exit_tables"], calls[-1][2], calls[-1][2])
    assert len(calls) > 4                            # moved inside the entries, not only at their ends
    again = _walk(2, cache=True)                     # read back: the hit is the walk
    assert again.cache == "hit"
    for a, b in zip(serial.G, again.G, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_failing_entry_stops_the_running_one_and_skips_the_rest():
    progress = walk_threads.Progress(None, 4)
    started, stopped = [], threading.Event()

    def work(e, kernel_threads):
        started.append(e)
        if e == 0:
            raise ValueError("broken entry")
        try:
            while True:                      # a long entry: runs until its next tick after the failure
                progress.tick()
                threading.Event().wait(0.01)
        finally:
            stopped.set()

    with pytest.raises(ValueError, match="broken entry"):
        walk_threads.run_entries([0, 1, 2, 3], work, lambda e, r: None, workers=2, kernel_threads=1,
                                 progress=progress)
    assert stopped.wait(10.0)                # the running worker left at its tick (Cancelled)
    assert progress.stop.is_set() and set(started) <= {0, 1, 2} and 3 not in started


def test_serial_entries_run_in_order_in_the_calling_thread():
    seen = []
    walk_threads.run_entries([2, 0, 1], lambda e, k: (e, threading.get_ident(), k),
                             lambda e, r: seen.append(r), workers=1, kernel_threads=None,
                             progress=walk_threads.Progress(None, 3))
    assert seen == [(2, threading.get_ident(), None), (0, threading.get_ident(), None),
                    (1, threading.get_ident(), None)]
