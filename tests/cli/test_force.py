"""Every command that writes refuses an existing output without --force (one line, exit 2, the
output untouched) and replaces it with --force; a run folder (a journal of measurements) is never
replaced. The expensive work behind a command (a Monte Carlo, a fit's search, a benchmark, a
renderer, the report's figures) is replaced by a stand-in: the command's own output handling is
what is tested."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fabric_optics.cli.compare import main as compare_main
from fabric_optics.cli.gonio import main as gonio_main
from fabric_optics.cli.simulate import main as simulate_main

ROOT = Path(__file__).parents[2]
ANALYTIC = ROOT / "fixtures" / "analytic"
RECORDED = ROOT / "fixtures" / "recorded"
FELT = ROOT / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"


def _stand_in_fabric(monkeypatch):
    from fabric_optics import api
    from gonio.data.dataset import read_dataset
    from simulate.virtual import GENERATOR

    def simulate(config, plan, method, **kwargs):
        ds = read_dataset(ANALYTIC / "sim_scaled")
        ds.meta.update(kind="simulated", model={"generator": GENERATOR, "method": method},
                       provenance={"rel_err": 0.01, "geometries": len(ds.geometries()), "seconds": 0.0})
        return ds

    monkeypatch.setattr(api, "simulate", simulate)


def _stand_in_fiber(monkeypatch):
    from simulate.fiber import BRDFEstimate, tables

    def volume_brdf(fiber, w_in, w_out, wavelengths_nm, **kwargs):
        w_in = np.atleast_2d(w_in)
        R = np.clip(w_in[:, 2], 0, None)[:, None] * np.full(len(wavelengths_nm), 0.3) / np.pi
        return BRDFEstimate(R=R, u_R=0.01 * R, photons=10, seconds=0.0, info={"rel_err": 0.01})

    monkeypatch.setattr(tables, "volume_brdf", volume_brdf)
    monkeypatch.setattr(tables, "surface_brdf", lambda fiber, w_in, w_out: np.zeros(len(np.atleast_2d(w_in))))


def _stand_in_fit(monkeypatch):
    from fabric_optics import api

    def prepare_fit(config, measured, free, out, **kwargs):
        problem = SimpleNamespace(wavelengths_nm=np.array([450.0, 550.0, 650.0]), target_rel_err=0.2)
        summary = {"parameters": [], "start": {"nrmse": 0.2}, "fitted": {"nrmse": 0.1}, "warnings": [],
                   "info": {"evaluations": 1, "walks": 0, "reweighted": 0, "seconds": 0.0}}

        def run(progress=False):
            (Path(out) / "fit.json").write_text(json.dumps(summary))
            return SimpleNamespace(summary=summary, warnings=[], passed=True, result=SimpleNamespace(info=summary["info"]))

        return SimpleNamespace(problem=problem, run=run)

    monkeypatch.setattr(api, "prepare_fit", prepare_fit)


def _stand_in_sweep(monkeypatch):
    import pandas as pd

    from fabric_optics.sweep import runner

    def run_sweep(spec, out, client, **kwargs):
        (out / runner.SUMMARY_NAME).write_text("point\n")
        return SimpleNamespace(summary=pd.DataFrame(), failures={}, computed=0, reused=0)

    monkeypatch.setattr(runner, "run_sweep", run_sweep)
    monkeypatch.setattr(runner, "finished_tasks", lambda out, spec: list(spec.tasks()))   # no cluster


def _stand_in_export(monkeypatch):
    import simulate.export

    def export_model(config, method, out, **kwargs):
        Path(out).write_bytes(b"bsdf stand-in")
        return SimpleNamespace(evaluations=1, error=None)

    monkeypatch.setattr(simulate.export, "export_model", export_model)


def _stand_in_bench(monkeypatch):
    import fabric_optics.bench.suite as suite

    def run_bench(out, quick=False):
        (out / "bench.json").write_text("{}")
        return {}

    monkeypatch.setattr(suite, "run_bench", run_bench)
    monkeypatch.setattr(suite, "markdown_table", lambda report: "| bench |")


def _stand_in_bench_driver(monkeypatch):
    import gonio.bench

    monkeypatch.setattr(gonio.bench, "bench_driver", lambda plan, repeats: {"plan": plan.name})


def _stand_in_render(monkeypatch):
    import compare.render as render

    monkeypatch.setattr(render, "require_mitsuba", lambda: None)
    monkeypatch.setattr(render, "render_materials", lambda items, settings: [object()])

    def write_render_set(images, out, settings):
        out.mkdir(parents=True, exist_ok=True)
        (out / "render.json").write_text("{}")
        return {"seconds_total": 0.0, "sheet": "render_sheet.png"}

    monkeypatch.setattr(render, "write_render_set", write_render_set)


def _stand_in_report(monkeypatch):
    import compare.report

    def write_report(comparison, out, *, force=False, **kwargs):
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "report.html").write_text("<html></html>")
        (Path(out) / "metrics.json").write_text('{"overall": {}}')   # compare report prints its curve errors
        return Path(out) / "report.html"

    monkeypatch.setattr(compare.report, "write_report", write_report)


#: (command, main, argv with OUT for the output, stand-in, whether --force replaces it)
WRITERS = [
    ("gonio truth", gonio_main, ["truth", "lambert:0.5", "--plan", "quick", "--out", "OUT"], None, True),
    ("gonio import", gonio_main, ["import", "rgl-bsdf", str(FELT), "--plan", "quick", "--out", "OUT"], None, True),
    ("gonio export", gonio_main, ["export", str(ANALYTIC / "measured_red"), "--resolution", "4", "--incidences", "2",
                                  "--out", "OUT.bsdf"], None, True),
    ("gonio demo", gonio_main, ["demo", "--plan", "quick", "--no-progress", "--out", "OUT"], None, True),
    ("gonio replay", gonio_main, ["replay", str(RECORDED / "quick-lambert.jsonl"), "--plan", "quick",
                                  "--out", "OUT"], None, False),
    ("gonio bench-driver", gonio_main, ["bench-driver", "--plan", "quick", "--out", "OUT.json"],
     _stand_in_bench_driver, True),
    ("simulate bench", simulate_main, ["bench", "--quick", "--out", "OUT"], _stand_in_bench, True),
    ("simulate fabric", simulate_main, ["fabric", "red-cotton", "--method", "classic", "--plan", "quick",
                                        "--no-progress", "--out", "OUT"], _stand_in_fabric, True),
    ("simulate fiber", simulate_main, ["fiber", "red-cotton", "--step-deg", "45", "--phi-step-deg", "90",
                                       "--target-rel-err", "0.2", "--no-progress", "--out", "OUT"],
     _stand_in_fiber, True),
    ("simulate fit", simulate_main, ["fit", "red-cotton", str(RECORDED / "quick-lambert"), "--free", "rms_slope",
                                     "--no-progress", "--out", "OUT"], _stand_in_fit, True),
    ("simulate weave", simulate_main, ["weave", "red-cotton", "--out", "OUT.ply"], None, True),
    ("simulate sweep", simulate_main, ["sweep", "red-cotton", "--param", "rms_slope=0.2,0.3", "--method", "classic",
                                       "--plan", "quick", "--target-rel-err", "0.2", "--no-progress", "--out", "OUT"],
     _stand_in_sweep, True),
    ("simulate export", simulate_main, ["export", "red-cotton", "--method", "classic", "--no-progress",
                                        "--out", "OUT.bsdf"], _stand_in_export, True),
    ("compare report", compare_main, ["report", str(ANALYTIC / "measured_red"), str(ANALYTIC / "sim_scaled"),
                                      "--out", "OUT"], _stand_in_report, True),
    ("compare render", compare_main, ["render", str(FELT), "--out", "OUT"], _stand_in_render, True),
]


def _snapshot(path: Path) -> dict[str, bytes]:
    if path.is_file():
        return {path.name: path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def _run(main, argv) -> int:
    try:
        return main(argv)
    except SystemExit as exc:       # simulate lets argparse exit
        return int(exc.code or 0)


def test_every_writer_is_here():
    from fabric_optics.cli.inventory import inventory

    # the writers of the inventory (commands with --out) are these and gonio acquire (below)
    assert inventory()["writers"] == len(WRITERS) + 1


@pytest.mark.parametrize("command, main, argv, stand_in, replaced", WRITERS, ids=[w[0] for w in WRITERS])
def test_a_second_run_needs_force(command, main, argv, stand_in, replaced, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    if stand_in is not None:
        stand_in(monkeypatch)
    out = next(a for a in argv if a.startswith("OUT"))
    argv = [str(tmp_path / a) if a == out else a for a in argv]
    assert _run(main, argv) == 0, capsys.readouterr().err
    before = _snapshot(tmp_path / out)
    assert before
    capsys.readouterr()
    assert _run(main, argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(command), err
    assert "--force" in err and "Traceback" not in err
    assert _snapshot(tmp_path / out) == before                     # untouched
    code = _run(main, argv + ["--force"])
    err = capsys.readouterr().err
    if replaced:
        assert code == 0, err
    else:                                                          # a run folder: never replaced
        assert code == 2 and "never replaced" in err, err
        assert _snapshot(tmp_path / out) == before


def test_truth_into_a_folder_holding_a_users_file(tmp_path, capsys):
    """``gonio truth`` into a folder that holds anything (a user's notes) is refused without --force."""
    out = tmp_path / "truth"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    assert gonio_main(["truth", "lambert:0.5", "--plan", "quick", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not empty" in err and "--force" in err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert gonio_main(["truth", "lambert:0.5", "--plan", "quick", "--out", str(out), "--force"]) == 0
    assert (out / "notes.txt").read_text() == "mine\n" and (out / "radiance.csv").is_file()


def test_acquire_refuses_a_folder_holding_anything_before_opening_a_link(tmp_path, capsys):
    """``gonio acquire`` (needs a live instrument to run; its output rule is checked before any
    link opens): a non-empty folder without a journal is refused without --force."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    assert gonio_main(["acquire", "--plan", "quick", "--modbus", "tcp://127.0.0.1:1", "--serial", "/nonexistent",
                       "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not empty" in err and "--force" in err
    # with --force the rule lets it through to the links (here unreachable)
    assert gonio_main(["acquire", "--plan", "quick", "--modbus", "tcp://127.0.0.1:1", "--serial", "/nonexistent",
                       "--out", str(out), "--force"]) == 2
    assert "cannot reach the device" in capsys.readouterr().err
