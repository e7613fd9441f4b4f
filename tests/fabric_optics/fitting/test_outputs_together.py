"""The fit's outputs are put in place together (fabric_optics.fitting.outputs.write_outputs): an interrupt (or a
full disk) at any write leaves the previous outputs exactly as they were and no hidden folder; fitted.toml never
exists without fit.json; a SIGINT while they are moved into place is held until they are complete; the command
says what is there and how to resume."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

import compare.report
from fabric_optics.fitting import outputs, state
from fabric_optics.fitting.outputs import OUTPUT_NAMES, FitResult, write_outputs


def _result(problem, x) -> FitResult:
    n = len(problem.free)
    return FitResult(method=problem.method, names=tuple(p.name for p in problem.free), x=np.asarray(x, float),
                     start=problem.start.copy(), objective=0.5, objective_start=1.0, u=np.full(n, 0.01),
                     u_data=np.full(n, 0.01), u_mc=np.zeros(n), correlation=np.eye(n), warnings=[],
                     info={"evaluations": 1})


def _light_report(comparison, out, *, force=False, **kw):
    """A stand-in for compare.report.write_report that writes two files together (no figure drawn)."""
    from gonio.data import write_files_together

    write_files_together(out, {"report.html": b"<html>" + str(list(comparison.simulated)).encode(),
                               "figures/factor.png": b"png"})
    return out / "report.html"


def _snapshot(out):
    return {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()
            and p.name != "fit-state.json"}


@pytest.fixture
def first(base_problem, tmp_path, monkeypatch):
    """A complete first output in DIR (result A), and the file sequence a second write fsyncs."""
    monkeypatch.setattr(compare.report, "write_report", _light_report)
    out = tmp_path / "fit"
    out.mkdir()
    write_outputs(base_problem, _result(base_problem, [0.9, 0.35]), out)
    assert {p.name for p in out.iterdir()} == set(OUTPUT_NAMES)
    return out


def _interrupt_at(monkeypatch, k):
    """os.fsync raises KeyboardInterrupt at its ``k``-th call (0-based) and records the files it syncs."""
    real, seen = os.fsync, []

    def fsync(fd):
        seen.append(os.readlink(f"/proc/self/fd/{fd}"))
        if len(seen) - 1 == k:
            raise KeyboardInterrupt
        return real(fd)
    monkeypatch.setattr(os, "fsync", fsync)
    return seen


def test_an_interrupt_at_any_write_leaves_the_previous_outputs(base_problem, first, monkeypatch):
    before = _snapshot(first)
    seen = _interrupt_at(monkeypatch, 10**6)                  # no interrupt: record what a write syncs
    write_outputs(base_problem, _result(base_problem, [1.2, 0.4]), first)
    after_b = _snapshot(first)
    assert after_b != before and json.loads(after_b[type(first)("fit.json")])["parameters"][0]["value"] == 1.2
    files = [os.path.basename(p) for p in seen]
    # every kind of write is among the interrupt points: the datasets' files, fitted.toml, the report, fit.json
    points = sorted({next(k for k, f in enumerate(files) if n in f)
                     for n in ("radiance.csv", "meta.json", "fitted.toml", "report.html", "fit.json")}
                    | {len(files) - 1})
    assert len(points) >= 5
    monkeypatch.undo()
    monkeypatch.setattr(compare.report, "write_report", _light_report)
    for k in points:
        _interrupt_at(monkeypatch, k)
        with pytest.raises(KeyboardInterrupt):
            write_outputs(base_problem, _result(base_problem, [2.0, 0.5]), first)
        assert _snapshot(first) == after_b, f"interrupt at write {k} ({files[k]}) changed the outputs"
        assert [p.name for p in first.iterdir() if p.name.startswith(".")] == []   # no hidden folder left


def test_a_sigint_while_the_outputs_are_put_in_place_is_held_until_they_are_complete(base_problem, first,
                                                                                     monkeypatch, caplog):
    real = os.replace
    calls = []

    def replace(src, dst):
        calls.append(str(dst))
        if os.path.basename(str(dst)) == "fitted.toml" and ".outputs-" not in str(dst):   # between two moves
            os.kill(os.getpid(), signal.SIGINT)
        return real(src, dst)
    monkeypatch.setattr(os, "replace", replace)
    with caplog.at_level("WARNING"):
        write_outputs(base_problem, _result(base_problem, [1.5, 0.3]), first)   # no KeyboardInterrupt
    doc = json.loads((first / "fit.json").read_text())
    assert doc["parameters"][0]["value"] == 1.5 and "1.5" in (first / "fitted.toml").read_text()
    assert {p.name for p in first.iterdir()} == set(OUTPUT_NAMES)
    assert any("they were completed first" in r.getMessage() for r in caplog.records)


def test_fit_json_is_put_in_place_before_fitted_toml():
    assert OUTPUT_NAMES.index("fit.json") < OUTPUT_NAMES.index("fitted.toml")


def test_simulate_fit_interrupted_while_writing_says_what_is_there(base_problem, tmp_path, monkeypatch, capsys):
    from dataclasses import replace

    from fabric_optics.cli.simulate import main
    from fabric_optics.fitting import methods
    from gonio.data import write_dataset

    write_dataset(base_problem.measured, tmp_path / "m")
    out = tmp_path / "f"

    def fake_run(problem, *, out, **kw):           # the search: its state file, then a result
        (out / state.STATE_NAME).write_text("{}")
        return _result(problem, problem.start)

    def interrupted(problem, result, out):
        raise KeyboardInterrupt
    monkeypatch.setitem(methods.METHODS, "classic", replace(methods.METHODS["classic"], run=fake_run))
    monkeypatch.setattr(outputs, "write_outputs", interrupted)
    status = main(["fit", "red-cotton", str(tmp_path / "m"), "--method", "classic", "--free", "rms_slope",
                   "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert status == 130 and err.count("\n") == 1
    assert f"interrupted while writing the outputs, which are unchanged in {out}" in err
    assert f"the last accepted point is in {out / state.STATE_NAME} (continue with --resume)" in err
