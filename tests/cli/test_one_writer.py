"""One writer per output: two writers started together on one output never both write it.

Each pair starts two forked processes at a barrier; each writes a different dataset to the same
output. Allowed outcomes: one writer is refused (the API's ``OutputBusyError``, or one line and exit 2
on the command line) and the output is the other's, whole; or (the first finished before the
second began) both succeeded one after the other and the output is the later one's. Counted as
failures: a *silent replacement* (both reported success with overlapping runs, or the output is not
the last successful writer's) and a *mixed output* (the files of two writers, which the reader
refuses, or a dataset that is neither writer's).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import fabric_optics as fo
from fabric_optics.api import OutputBusyError
from gonio.data.claim import OutputBusy, claim_output, lock_path, verify
from gonio.data.dataset import Dataset, make_dataset, new_meta, read_dataset

TRIES = 20
_CTX = mp.get_context("fork")


def _dataset(scale: float, name: str) -> Dataset:
    rows = [(ti, 0.0, to, 0.0, wl, scale * (1 + 0.01 * k), 0.001, 1)
            for k, (ti, to, wl) in enumerate((ti, to, wl) for ti in (0.0, 30.0)
                                             for to in (10.0, 40.0, 50.0) for wl in (450.0, 550.0, 650.0))]
    table = {c: [r[i] for r in rows] for i, c in enumerate(("theta_i", "phi_i", "theta_o", "phi_o",
                                                             "wavelength_nm", "beta", "u_beta", "n"))}
    return make_dataset(table, new_meta("simulated", {"name": name}))


def _writer(barrier, result, fn):
    barrier.wait()
    t0 = time.monotonic()
    try:
        fn()
        status = "ok"
    except OutputBusyError:
        status = "busy"
    except Exception as exc:   # noqa: BLE001 - reported to the parent, which fails the test
        status = f"{type(exc).__name__}: {exc}"
    result.put((status, t0, time.monotonic()))


def _race(fns):
    barrier = _CTX.Barrier(len(fns))
    queues = [_CTX.Queue() for _ in fns]
    procs = [_CTX.Process(target=_writer, args=(barrier, q, fn)) for q, fn in zip(queues, fns, strict=True)]
    for p in procs:
        p.start()
    out = [q.get(timeout=60) for q in queues]
    for p in procs:
        p.join(60)
    return out


def _judge(results, final, expected):
    """('silent' | 'mixed' | None) for one race: ``final`` is the content read back (None: the reader
    refused it), ``expected[i]`` writer i's content."""
    ok = [i for i, (s, _, _) in enumerate(results) if s == "ok"]
    if final is None or final not in expected:
        return "mixed"
    if len(ok) == 2:
        (_, a0, a1), (_, b0, b1) = results
        if not (a1 <= b0 or b1 <= a0):
            return "silent"
        last = 0 if a1 > b1 else 1
        return None if final == expected[last] else "silent"
    return None if len(ok) == 1 and final == expected[ok[0]] else "silent"


@pytest.mark.timeout(240)
def test_two_api_writers_with_force_never_mix_or_silently_replace(tmp_path):
    data = [_dataset(0.2, "first"), _dataset(0.6, "second")]
    expected = [tuple(d.table["beta"].round(9)) for d in data]
    tally = {"silent": 0, "mixed": 0, "refused": 0, "one after the other": 0}
    for k in range(TRIES):
        out = tmp_path / f"x{k}"
        results = _race([lambda d=d, out=out: fo.write_dataset(d, out, force=True) for d in data])
        assert all(s in ("ok", "busy") for s, _, _ in results), results
        try:
            final = tuple(read_dataset(out).table["beta"].round(9))
        except Exception:  # noqa: BLE001 - the reader refusing it is what "mixed" means
            final = None
        verdict = _judge(results, final, expected)
        if verdict:
            tally[verdict] += 1
        elif any(s == "busy" for s, _, _ in results):
            tally["refused"] += 1
        else:
            tally["one after the other"] += 1
        assert not lock_path(out).exists()          # released and removed by the holder
    print(f"write_dataset pairs: {tally}", file=sys.stderr)
    assert tally["silent"] == 0 and tally["mixed"] == 0, tally
    assert tally["refused"] > 0, tally                  # the race did happen


def _gonio(argv, err_file):
    from fabric_optics.cli.gonio import main

    sys.stderr = open(err_file, "w")             # the child's own files (pytest captures the parent's)
    sys.stdout = open(os.devnull, "w")
    try:
        code = main(argv)
    finally:
        sys.stderr.flush()
    if code:
        raise SystemExit(code)


def _cli_writer(barrier, result, argv, err_file):
    barrier.wait()
    t0 = time.monotonic()
    try:
        _gonio(argv, err_file)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    result.put((code, t0, time.monotonic()))


@pytest.mark.timeout(240)
def test_two_gonio_truth_commands_on_one_out_one_wins_the_other_is_one_line(tmp_path):
    samples = ["lambert:0.3", "lambert:0.8"]
    tally = {"silent": 0, "mixed": 0, "busy": 0, "exists": 0}
    for k in range(TRIES):
        out = tmp_path / f"t{k}"
        barrier = _CTX.Barrier(2)
        queues = [_CTX.Queue() for _ in samples]
        errs = [tmp_path / f"err{k}-{i}" for i in range(2)]
        procs = [_CTX.Process(target=_cli_writer, args=(barrier, q, ["truth", s, "--plan", "quick", "--out", str(out)],
                                                         str(e)))
                 for q, s, e in zip(queues, samples, errs, strict=True)]
        for p in procs:
            p.start()
        results = [q.get(timeout=60) for q in queues]
        for p in procs:
            p.join(60)
        codes = [c for c, _, _ in results]
        try:
            final = read_dataset(out).name
        except Exception:  # noqa: BLE001
            final = None
        if sorted(codes) != [0, 2] or final is None:
            tally["mixed" if final is None else "silent"] += 1
            continue
        winner, loser = (0, 1) if codes[0] == 0 else (1, 0)
        if samples[winner] not in final:
            tally["silent"] += 1
        message = errs[loser].read_text().strip().splitlines()
        assert len(message) == 1 and message[0].startswith("gonio truth: "), message
        tally["busy" if "another writer" in message[0] else "exists"] += 1
    print(f"gonio truth pairs: {tally}", file=sys.stderr)
    assert tally["silent"] == 0 and tally["mixed"] == 0, tally


def test_a_claim_refuses_another_thread_is_reentrant_in_its_own_and_is_checked_at_the_rename(tmp_path):
    out = tmp_path / "o"
    seen = []
    with claim_output(out):
        with claim_output(out):                     # the CLI claims, then the API claims again
            verify(out / "radiance.csv")
        t = threading.Thread(target=lambda: seen.append(_try_claim(out)))
        t.start()
        t.join()
        assert lock_path(out).exists()
        os.unlink(lock_path(out))                   # someone removed the lock file behind our back
        with pytest.raises(OutputBusy, match="claim on this output was lost"):
            verify(out / "radiance.csv")
    assert seen == ["busy"]
    assert not lock_path(out).exists()
    with claim_output(out):                         # free again
        pass


def _try_claim(out):
    try:
        with claim_output(out):
            return "claimed"
    except OutputBusy:
        return "busy"


def test_write_dataset_refuses_nan_and_never_replaces_a_run_folder(tmp_path):
    ds = _dataset(0.4, "nan")
    table = ds.table.copy()
    table.loc[3, "beta"] = np.nan
    bad = Dataset(table, dict(ds.meta))
    with pytest.raises(fo.InputError, match="beta"):
        fo.write_dataset(bad, tmp_path / "n")
    assert not (tmp_path / "n" / "radiance.csv").exists()
    run = tmp_path / "run"
    fo.write_dataset(ds, run)
    (run / "journal.jsonl").write_text('{"type": "start"}\n')
    before = (run / "radiance.csv").read_bytes()
    with pytest.raises(fo.OutputExistsError, match="run folder"):
        fo.write_dataset(_dataset(0.9, "other"), run, force=True)
    assert (run / "radiance.csv").read_bytes() == before


def test_a_full_disk_in_the_one_atomic_writer_names_the_file(tmp_path, monkeypatch):
    import errno

    from gonio.data import atomic_write

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError) as info:
        atomic_write(tmp_path / "f.json", b"{}")
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(tmp_path / "f.json")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(fo.FileSystemError, match="radiance.csv"):
        fo.write_dataset(_dataset(0.4, "full"), tmp_path / "d")


def test_a_folder_that_cannot_be_written_is_refused_before_any_work(tmp_path):
    # the permission check, or as root (which passes it) the claim, whose lock file cannot be created
    with pytest.raises(fo.InputError, match="path=.*/proc"):
        fo.write_dataset(_dataset(0.4, "x"), Path("/proc/x"))


MEASURED = Path(__file__).resolve().parents[2] / "fixtures" / "analytic" / "measured_red"
SIM = MEASURED.parent / "sim_scaled"
FELT = MEASURED.parents[1] / "real" / "acrylic_felt_green_rgb.bsdf"


@pytest.mark.parametrize("argv", [
    ["simulate", "fabric", "red-cotton", "--method", "classic", "--plan", "quick", "--out", "OUT"],
    ["simulate", "fit", "red-cotton", str(MEASURED), "--free", "rms_slope", "--out", "OUT"],
    ["simulate", "export", "red-cotton", "--method", "classic", "--out", "OUT"],
    ["simulate", "fiber", "red-cotton", "--out", "OUT"],
    ["compare", "report", str(MEASURED), str(SIM), "--out", "OUT"],
    ["gonio", "truth", "lambert:0.5", "--plan", "quick", "--out", "OUT"],
    ["gonio", "import", "rgl-bsdf", str(FELT), "--out", "OUT"],
    ["gonio", "export", str(MEASURED), "--out", "OUT"],
    ["gonio", "demo", "--plan", "quick", "--out", "OUT", "--no-progress"],
    ["gonio", "bench-driver", "--plan", "quick", "--out", "OUT"],
], ids=lambda argv: " ".join(argv[:2]))
def test_every_writer_is_refused_while_another_holds_its_output(tmp_path, capsys, argv):
    from fabric_optics.cli import compare, gonio, simulate

    out = tmp_path / "out"
    taken, done = threading.Event(), threading.Event()

    def hold():
        with claim_output(out):
            taken.set()
            done.wait(60)
    holder = threading.Thread(target=hold)
    holder.start()
    try:
        assert taken.wait(10)
        main = {"simulate": simulate.main, "compare": compare.main, "gonio": gonio.main}[argv[0]]
        assert main([str(out) if a == "OUT" else a for a in argv[1:]]) == 2
    finally:
        done.set()
        holder.join()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another writer is writing this output now" in err[0] and str(out) in err[0], err
    assert not out.exists()
