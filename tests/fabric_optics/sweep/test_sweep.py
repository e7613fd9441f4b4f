"""simulate sweep: identical results on 1 and 2 workers, resume after SIGKILL, failed tasks, bad input."""

from __future__ import annotations

import collections
import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.sweep import runner as sweep_mod
from fabric_optics.sweep.runner import SWEEP_NAME, prepare_out, run_sweep
from gonio.data.dataset import read_dataset

from .conftest import make_spec, plan_text, write_plan

#: a cluster's scheduler HTTP server moves to a free port when another test's cluster holds 8787
pytestmark = pytest.mark.filterwarnings("ignore:Port .* is already in use")

PARAMS = ["rms_slope=0.2,0.4"]


def _csv_bytes(out: Path) -> dict[str, bytes]:
    return {p.parent.name: p.read_bytes() for p in sorted((out / "points").glob("*/radiance.csv"))}


def _summary(out: Path) -> list[dict]:
    with open(out / "summary.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_one_and_two_workers_give_byte_identical_datasets(tmp_path, inproc_client):
    from distributed import Client, LocalCluster

    spec = make_spec(write_plan(tmp_path), PARAMS)
    one, two = tmp_path / "one", tmp_path / "two"
    prepare_out(one, spec)
    r1 = run_sweep(spec, one, inproc_client)
    assert not r1.failures and r1.computed == 6
    prepare_out(two, spec)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            r2 = run_sweep(spec, two, client)
    assert not r2.failures and r2.computed == 6
    a, b = _csv_bytes(one), _csv_bytes(two)
    assert sorted(a) == ["rms_slope=0.2", "rms_slope=0.4"] and a == b
    ds = read_dataset(one / "points" / "rms_slope=0.4")
    assert len(ds) == 8 * 3 and np.all(np.isfinite(ds.table["beta"]))
    sweep_meta = ds.meta["provenance"]["sweep"]
    assert sweep_meta["parameters"] == {"rms_slope": 0.4} and sweep_meta["paths"] == {"rms_slope": "surface.rms_slope"}
    assert ds.meta["model"]["generator"] == "simulate sweep" and len(ds.meta["provenance"]["task_seeds"]) == 3
    rows = _summary(one)
    assert [r["status"] for r in rows] == ["complete", "complete"] and all(float(r["seconds"]) > 0 for r in rows)
    assert all(0 < float(r["rel_err"]) < 0.2 for r in rows)


def test_killed_sweep_resumes_without_recomputing_finished_tasks(tmp_path, inproc_client):
    """SIGKILL the sweep's process group once two task files exist; the resumed sweep leaves those
    files untouched (inode, mtime), computes only the rest and equals an uninterrupted run."""
    plan = write_plan(tmp_path, plan_text("list_nm = [450, 500, 550, 600, 650, 700]"))
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "fabric_optics.cli.simulate", "sweep", "red-cotton", "--param", PARAMS[0], "--method",
           "classic", "--plan", str(plan), "--target-rel-err", "0.1", "--no-progress", "--out", str(out)]
    proc = subprocess.Popen(cmd + ["--workers", "1"], start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 240
        while len(list((out / "tasks").glob("*.npz"))) < 2:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no task file within 240 s"
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep and its worker processes
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    before = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in (out / "tasks").glob("*.npz")}
    assert 2 <= len(before) < 12, "the sweep must be killed part-way"
    assert not (out / "points").exists()

    done = subprocess.run(cmd + ["--workers", "1", "--resume"], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    assert f"{12 - len(before)} computed, {len(before)} reused, resumed, 0 failed" in done.stdout
    after = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in (out / "tasks").glob("*.npz")}
    assert len(after) == 12 and all(after[name] == before[name] for name in before)

    spec = make_spec(plan, PARAMS, method="classic")
    ref = tmp_path / "uninterrupted"
    prepare_out(ref, spec)
    run_sweep(spec, ref, inproc_client)
    assert _csv_bytes(out) == _csv_bytes(ref) and len(_csv_bytes(ref)) == 2


def test_failed_task_is_retried_reported_and_the_rest_kept(tmp_path, monkeypatch, capsys):
    """A model that raises for one (point, wavelength): retried, one line on stderr, exit 1; the
    other tasks are stored and the complete point assembled; a rerun computes only that task."""
    from distributed import Client, LocalCluster

    monkeypatch.setenv("DASK_LOGGING__DISTRIBUTED", "critical")
    calls: collections.Counter = collections.Counter()
    real = sweep_mod.fabric_dataset
    broken = {"on": True}

    def flaky(config, plan, method, **kw):
        key = (config.rms_slope, float(plan.wavelengths_nm[0]))
        calls[key] += 1
        if broken["on"] and key == (0.4, 550.0):
            raise RuntimeError("test: the model failed")
        return real(config, plan, method, **kw)

    def client(args):
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None)
        return Client(cluster), cluster

    monkeypatch.setattr(sweep_mod, "fabric_dataset", flaky)
    monkeypatch.setattr("fabric_optics.cli.simulate.sweep._sweep_client", client)
    plan = write_plan(tmp_path)
    out = tmp_path / "s"
    argv = ["sweep", "red-cotton", "--param", PARAMS[0], "--method", "classic", "--plan", str(plan),
            "--target-rel-err", "0.1", "--retries", "2", "--no-progress", "--out", str(out)]
    assert main(argv) == 1
    captured = capsys.readouterr()
    failed = [line for line in captured.err.splitlines() if "failed after" in line]
    assert len(failed) == 1
    assert "p001_w0550" in failed[0] and "3 attempt(s): RuntimeError: test: the model failed" in failed[0]
    assert calls[(0.4, 550.0)] == 3 and all(n == 1 for k, n in calls.items() if k != (0.4, 550.0))
    assert "5 computed, 0 reused, 1 failed" in captured.out
    assert [r["status"] for r in _summary(out)] == ["complete", "incomplete"]
    assert (out / "points" / "rms_slope=0.2" / "radiance.csv").is_file()
    assert not (out / "points" / "rms_slope=0.4").exists()
    assert len(list((out / "tasks").glob("*.npz"))) == 5

    broken["on"] = False
    calls.clear()
    assert main(argv) == 2                          # the same command again: continue it with --resume
    assert "--resume" in capsys.readouterr().err
    assert main(argv + ["--resume"]) == 0
    assert dict(calls) == {(0.4, 550.0): 1}
    assert "1 computed, 5 reused, resumed, 0 failed" in capsys.readouterr().out
    assert [r["status"] for r in _summary(out)] == ["complete", "complete"]


@pytest.mark.parametrize("param, message", [
    ("rms_slope=0.2,abc", "--param rms_slope: 'abc' is not a number"),
    ("no_such_field=1,2", "--param no_such_field: unknown parameter"),
    ("surface.rms_slope=0.2,7", "--param surface.rms_slope=7.0: red-cotton.toml: surface.rms_slope must be"),
    ("rms_slope", "expected NAME=v1,v2,..."),
    ("rms_slope=0.2,0.2", "the value 0.2 is given twice"),
    ("seed=1,2", "seed is a run setting"),
    ("method.target_rel_err=0.01,0.02", "method.target_rel_err is a run setting"),   # at its default: not written
    ("dye=1", "a sweep sets one field"),
])
def test_bad_param_is_one_line_exit_2_before_any_work(tmp_path, capsys, param, message):
    out = tmp_path / "never"
    assert main(["sweep", "red-cotton", "--param", param, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("simulate sweep: error: ") and message in err, err
    assert not out.exists()


def test_out_that_is_not_this_sweep_is_refused(tmp_path, capsys):
    plan = write_plan(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    base = ["sweep", "red-cotton", "--param", PARAMS[0], "--method", "classic", "--plan", str(plan), "--out"]
    assert main(base + [str(other)]) == 2
    assert "is not a sweep directory" in capsys.readouterr().err
    assert sorted(p.name for p in other.iterdir()) == ["keep.txt"]

    # a sweep directory of another spec (parameters, seed): refused, naming what differs
    spec = make_spec(plan, ["rms_slope=0.2,0.3"])
    sweep_dir = tmp_path / "sweep"
    prepare_out(sweep_dir, spec)
    doc = (sweep_dir / SWEEP_NAME).read_bytes()
    assert main(base + [str(sweep_dir), "--target-rel-err", "0.1", "--seed", "5"]) == 2
    err = capsys.readouterr().err
    assert "holds a different sweep (parameters, seed differ)" in err and err.count("\n") == 1
    assert (sweep_dir / SWEEP_NAME).read_bytes() == doc
    assert main(base + [str(tmp_path / "fresh"), "--resume"]) == 2
    assert "holds no sweep" in capsys.readouterr().err


def test_same_spec_given_explicitly_is_the_same_sweep(tmp_path):
    """Defaults resolved before hashing: --seed equal to the config's seed is the same sweep."""
    from fabric_optics.sweep.runner import SweepSpec, parse_params
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config

    plan = load_plan(write_plan(tmp_path))
    config = load_config("red-cotton")
    params = parse_params(["radius=0.08,0.12", "weave.spacing_um=250,300.5"], config)
    a = SweepSpec(config, plan, params, method="classic")
    b = SweepSpec(config, plan, params, method="classic", seed=config.seed, target_rel_err=config.target_rel_err,
                  threads=4)
    assert a.digest == b.digest
    assert [p.path for p in params] == ["particles.size.median_radius_um", "weave.spacing_um"]
    assert [p.label for p in a.points] == [
        "radius=0.08,weave.spacing_um=250", "radius=0.08,weave.spacing_um=300.5",
        "radius=0.12,weave.spacing_um=250", "radius=0.12,weave.spacing_um=300.5"]
    assert a.points[3].config.particles.size.median_radius_um == 0.12
    assert a.points[3].config.weave["spacing_um"] == 300.5
    seeds = [t.seed for t in a.tasks()]
    assert len(set(seeds)) == len(seeds) == 12


#: a grey plain weave (a homogeneous medium in the fibers: no Mie walk) small enough for a Monte Carlo sweep
GREY_WEAVE = """
seed = 4
[fiber]
radius_um = 10.0
n_host = 1.5
[medium]
mu_s = 0.8
mu_a = 0.01
g = 0.5
[surface]
rms_slope = 0.35
[weave]
preset = "plain"
spacing_um = 300
width_um = 250
height_um = 100
points_per_span = 6
sides = 12
"""


def test_a_monte_carlo_sweep_runs_one_task_per_point_over_the_whole_spectrum(tmp_path, inproc_client):
    """--method mc: one task per point (its run shares rays, mesh and tables across the spectrum), whose
    dataset is the whole-spectrum simulate fabric run at the task's seed, value for value (another seed differs
    by the Monte Carlo's noise, ~1e-2)."""
    from fabric_optics.sweep.runner import SweepSpec, parse_params
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config
    from simulate.virtual import fabric_dataset

    cfg = tmp_path / "grey.toml"
    cfg.write_text(GREY_WEAVE)
    config = load_config(str(cfg))
    plan = load_plan(write_plan(tmp_path, plan_text("list_nm = [500, 600]")))
    spec = SweepSpec(config, plan, parse_params(PARAMS, config), method="mc", target_rel_err=0.1, threads=1)
    tasks = spec.tasks()
    assert [t.id for t in tasks] == ["p000", "p001"] and all(t.wavelength_nm is None for t in tasks)
    assert spec.document()["tasks"] == 2
    out = tmp_path / "mc"
    prepare_out(out, spec)
    result = run_sweep(spec, out, inproc_client)
    assert not result.failures and result.computed == 2
    ds = read_dataset(out / "points" / "rms_slope=0.4")
    assert sorted(ds.table["wavelength_nm"].unique()) == [500.0, 600.0]
    direct = fabric_dataset(spec.points[1].config, plan, "mc", target_rel_err=0.1, seed=tasks[1].seed, threads=1)
    key = ["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm"]
    a = ds.table.sort_values(key)["beta"].to_numpy()
    b = direct.table.sort_values(key)["beta"].to_numpy()
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=0)      # the dataset's CSV keeps 10 significant digits
    assert ds.meta["provenance"]["task_seeds"] == {"all": tasks[1].seed}
