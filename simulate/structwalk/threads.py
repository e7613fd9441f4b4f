"""Independent walk entries run two at a time on threads, with one progress, one cancel and one thread budget.

:func:`simulate.structwalk.walk.walk_structure` is made of independent ``(half, chunk)`` entries, each seeded
by its own ``(seed, half, node, chunk)`` streams. Run one after the other, the parts of an entry that are
not the kernel's parallel rows (the layer table, the interior closure, the symmetrisation: ~70 % of the
felt's cold walk) kept ONE core busy on a 2-core machine. :func:`run_entries` runs them on a
:class:`concurrent.futures.ThreadPoolExecutor` of ``workers`` threads, each with a share of the thread
budget for its compiled parallel loops (numba's thread count is thread-local: ``numba.set_num_threads``
in a worker does not change the caller's). The compiled hot loops are ``nogil=True`` so the threads
overlap (numpy releases the GIL in its own loops). An entry's numbers do not depend on the thread that
runs it nor on its kernel threads (every parallel loop writes disjoint elements; the rows are reduced in
batch order: :mod:`simulate.montecarlo.rows`), so the walk is bit-identical to the serial one
(``tests/fabric_optics/fitting/test_walk_threads.py``).

Interrupts (Ctrl-C answered within a second, finished entries kept): signals reach only the main thread,
which waits for the entries in an interruptible wait. On any exception there (KeyboardInterrupt, or a
worker's error) it sets a cancel event, drops the entries not started and re-raises at once; a running
entry stops at its next :meth:`Progress.tick` (each wavelength group of each exit-table node, each incident direction of the
layer table and of the interior closure: well under a second apart) by raising :class:`Cancelled`, so
the executor's exit join does not wait for a whole entry. An entry is stored by its worker as soon as it
is done. ``workers == 1`` runs the entries in the calling thread, in order: the serial walk.

Learnt from: the Python documentation of :mod:`concurrent.futures` (``wait``, ``shutdown(cancel_futures=)``)
and numba's "Setting the Number of Threads" (thread-local ``set_num_threads``) and ``nogil`` notes.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from typing import Any

import numba

__all__ = ["Cancelled", "Progress", "plan", "run_entries", "idle_cores", "MAX_WORKERS"]

#: at most this many entries at once: each holds its exit table (~0.6 GB on the felt's 7-wavelength chunks)
MAX_WORKERS = 2


class Cancelled(Exception):
    """Raised in a worker at its next progress tick once the walk was interrupted in the main thread."""


#: with ``threads=None``, a second worker only when at least this many cores were idle (:func:`idle_cores`)
IDLE_FOR_WORKER = 0.5


def idle_cores(seconds: float = 0.1) -> float | None:
    """Cores left idle by every process on the machine over ``seconds``, read from ``/proc/stat``.

    Two entries at once finish a walk sooner when the second core is free, but cost more CPU than one after
    the other (GIL hand-offs, page faults of two tables at once), so with the other core busy they are
    slower. The choice changes no number (bit-identical either way), only the time.

    Parameters
    ----------
    seconds : float
        How long to watch the machine's CPU counters.

    Returns
    -------
    float or None
        The number of idle cores (``cpu_count`` times the idle share of the interval), or None where
        ``/proc/stat`` cannot be read.
    """
    def sample() -> tuple[int, int]:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
        return v[3] + v[4], sum(v[:8])
    try:
        i0, t0 = sample()
        time.sleep(seconds)
        i1, t1 = sample()
    except (OSError, ValueError, IndexError):
        return None
    n = os.cpu_count() or 1
    return n * (i1 - i0) / max(t1 - t0, 1)


def plan(threads: int | None, n_entries: int) -> tuple[int, int | None]:
    """The number of worker threads for a walk's entries and the kernel threads each worker gets.

    One worker keeps ``threads`` as given (the serial walk); ``w`` workers split the budget,
    ``budget // w`` each (at least 1).

    Parameters
    ----------
    threads : int or None
        The walk's thread budget; None: numba's thread count of the caller (the cores), and a second
        worker only if :func:`idle_cores` finds at least :data:`IDLE_FOR_WORKER` cores idle.
    n_entries : int
        The entries left to walk (never more workers than entries, nor than :data:`MAX_WORKERS`).

    Returns
    -------
    (int, int or None)
        ``(workers, kernel threads per worker)``.
    """
    budget = numba.get_num_threads() if threads is None else int(threads)
    workers = max(1, min(MAX_WORKERS, budget, n_entries))
    if workers > 1 and threads is None:
        idle = idle_cores()
        if idle is not None and idle < IDLE_FOR_WORKER:
            workers = 1
    if workers == 1:
        return 1, threads
    return workers, max(1, budget // workers)


class Progress:
    """One monotone progress ``(photons, run, runs)`` from entries reported by several threads.

    ``report(entry)`` gives the entry's callback ``(photons so far, runs so far)``; :meth:`finish` moves the
    entry's final counts to the finished total. Every update and every call of ``callback`` is under one
    lock, so the calls see sums that never decrease (each entry's own counts only grow).
    """

    def __init__(self, callback: Callable[[int, int, int], None] | None, runs: int) -> None:
        self.callback, self.runs = callback, runs
        self.photons = self.run = 0
        self.partial: dict[Hashable, tuple[int, int]] = {}
        self.lock = threading.Lock()
        self.stop = threading.Event()

    def tick(self) -> None:
        """Raise :class:`Cancelled` when the walk was interrupted (called by the workers between steps)."""
        if self.stop.is_set():
            raise Cancelled

    def _emit(self) -> None:
        if self.callback is not None:
            p = self.photons + sum(v[0] for v in self.partial.values())
            r = self.run + sum(v[1] for v in self.partial.values())
            self.callback(p, r, self.runs)

    def report(self, entry: Hashable) -> Callable[[int, int], None]:
        """The progress callback of one entry.

        Parameters
        ----------
        entry : hashable
            The entry whose counts the callback reports.

        Returns
        -------
        callable
            ``report(photons, runs)``, the entry's counts so far; it raises :class:`Cancelled` when the
            walk was interrupted, and otherwise calls the walk's callback with the new sums.
        """

        def report(photons: int, done: int) -> None:
            self.tick()
            with self.lock:
                self.partial[entry] = (int(photons), int(done))
                self._emit()
        return report

    def finish(self, entry: Hashable, photons: int, runs: int) -> None:
        """Move a finished entry's counts from the running entries to the finished total.

        Parameters
        ----------
        entry : hashable
            The finished entry.
        photons : int
            The photons it walked.
        runs : int
            The runs it made.
        """
        with self.lock:
            self.partial.pop(entry, None)
            self.photons += int(photons)
            self.run += int(runs)
            self._emit()


def run_entries(entries: Sequence[Any], work: Callable[[Any, int | None], Any], finished: Callable[[Any, Any], None],
                *, workers: int, kernel_threads: int | None, progress: Progress) -> None:
    """Call ``finished(entry, work(entry, kernel_threads))`` for every entry, on threads when ``workers > 1``.

    With ``workers == 1`` the entries run in order in this thread; otherwise ``work`` runs on ``workers``
    threads and ``finished`` here, in completion order (module docstring: cancel, interrupts).

    Parameters
    ----------
    entries : sequence
        The entries to run.
    work : callable
        ``work(entry, kernel_threads) -> result``, run on a worker thread.
    finished : callable
        ``finished(entry, result)``, run in the calling thread as each entry is done.
    workers : int
        The number of worker threads (1: the serial walk in this thread).
    kernel_threads : int or None
        Each worker's thread count for its compiled parallel loops (None: numba's default).
    progress : Progress
        The walk's shared progress; its cancel event stops the running entries on an exception.
    """
    if workers <= 1:
        for e in entries:
            finished(e, work(e, kernel_threads))
        return

    def job(e: Any) -> Any:
        progress.tick()
        if kernel_threads is not None:
            numba.set_num_threads(int(kernel_threads))     # thread-local: this worker's compiled loops only
        return work(e, kernel_threads)

    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="walk")
    try:
        futures = {pool.submit(job, e): e for e in entries}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                finished(futures[f], f.result())
    except BaseException:
        progress.stop.set()                                # running entries stop at their next tick
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
