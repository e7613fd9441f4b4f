"""`simulate fit` run again with nothing changed restores the finished fit from the table cache
(fabric_optics.fitting.reuse); anything changed fits again."""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fabric_optics import api
from fabric_optics.cli.simulate import main
from fabric_optics.fitting import reuse
from gonio.data import write_dataset

from .conftest import measurement

RESTORED = "restored from the table cache"


@pytest.fixture(autouse=True)
def light_report(monkeypatch):
    """The fit's report without its figures (what is restored is the folder, whatever it holds)."""
    import compare.report

    def write_report(comparison, out, *, force=False, **kw):
        from gonio.data import write_files_together

        write_files_together(out, {"report.html": b"<html>" + str(list(comparison.simulated)).encode()})
        return out / "report.html"

    monkeypatch.setattr(compare.report, "write_report", write_report)


@pytest.fixture(autouse=True)
def few_noise_draws(monkeypatch):
    """The uncertainty from 8 noise draws, not 64 (three quarters of a fit here): these tests count fits and
    compare a restored folder with the fitted one, whatever its uncertainty."""
    from fabric_optics.fitting import search

    monkeypatch.setitem(search.run_fit.__kwdefaults__, "noise_draws", 8)


@pytest.fixture
def measured(base_problem, tmp_path):
    """A red-cotton-like measurement of the classic model, written as a dataset folder."""
    beta, _ = base_problem.model(np.array([1.0, 0.35]))
    path = tmp_path / "m"
    write_dataset(measurement(lambda g, wl: beta, 3, geometries=base_problem.geometries), path)
    return path


def _fit(measured, out, *extra):
    return main(["fit", "red-cotton", str(measured), "--method", "classic", "--free",
                 "fiber.dye.bands[0].peak_per_um=0.3:3,rms_slope=0.1:0.8", "--out", str(out), "--seed", "5",
                 "--target-rel-err", "0.1", "--max-evaluations", "4", "--no-progress", "--force", *extra])


class Counting:
    """``api.prepare_fit`` counted: how many fits were prepared (a restored fit prepares none)."""

    def __init__(self, monkeypatch):
        self.calls = 0
        real = api.prepare_fit

        def counted(*args, **kwargs):
            self.calls += 1
            return real(*args, **kwargs)

        monkeypatch.setattr(api, "prepare_fit", counted)


def _files(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_same_fit_again_is_restored_byte_for_byte(measured, tmp_path, cache_dir, monkeypatch, capsys):
    counting = Counting(monkeypatch)
    out = tmp_path / "f"
    first_code = _fit(measured, out)
    first = capsys.readouterr()
    first_files = _files(out)
    (out / "fit.json").write_text("{}")              # the restore must bring the outputs back, not leave them
    second_code = _fit(measured, out)
    second = capsys.readouterr()
    assert counting.calls == 1                        # the second command fitted nothing
    assert second_code == first_code
    assert RESTORED in second.out.splitlines()[0]
    assert second.out.splitlines()[1:] == first.out.splitlines()          # the same lines, in the same order
    assert second.err == first.err
    assert _files(out) == first_files
    assert json.loads((out / "fit.json").read_text())["parameters"]


def test_anything_changed_fits_again(measured, tmp_path, cache_dir, monkeypatch, capsys):
    """Each change in turn (the cache shared, so each one's fit is stored too): it fits, it does not restore."""
    out = tmp_path / "f"
    assert _fit(measured, out) in (0, 3)
    counting = Counting(monkeypatch)
    for n, change in enumerate(["option", "no-cache", "resume", "code", "values"], start=1):
        capsys.readouterr()
        extra: tuple[str, ...] = ()
        if change == "option":
            extra = ("--max-evaluations", "5")
        elif change == "no-cache":
            extra = ("--no-cache",)
        elif change == "resume":
            extra = ("--resume",)
        elif change == "code":
            monkeypatch.setattr(reuse, "_IDENTITY", ["another code"])   # a source file edited
        elif change == "values":
            _rewrite(measured, 1.001)
        _fit(measured, out, *extra)
        os.environ.pop("FABRIC_OPTICS_NO_CACHE", None)   # --no-cache sets it for the process (monkeypatch would put it back)
        assert counting.calls == n, change
        assert RESTORED not in capsys.readouterr().out, change


def _rewrite(path, factor):
    """The measurement at ``path`` with its first value scaled (its meta kept)."""
    csv = path / "radiance.csv"
    lines = csv.read_text().splitlines()
    header = lines[0].split(",")
    first = lines[1].split(",")
    k = header.index("beta")
    first[k] = repr(float(first[k]) * factor)
    lines[1] = ",".join(first)
    csv.write_text("\n".join(lines) + "\n")
    meta = json.loads((path / "meta.json").read_text())
    meta.get("files", {}).pop("radiance.csv", None)                    # the file's recorded hash no longer holds
    (path / "meta.json").write_text(json.dumps(meta))


def test_a_repeated_acquisition_of_the_same_values_restores(measured, tmp_path, cache_dir, monkeypatch, capsys):
    """The measurement counts by its values and what it measured, not by when, through which port or by which
    build of the software it was recorded (a checkout with an edited file records ``+dirty``)."""
    out = tmp_path / "f"
    _fit(measured, out)
    meta = json.loads((measured / "meta.json").read_text())
    meta["created"] = "2030-01-01T00:00:00+00:00"
    meta["instrument"] = {"modbus": "tcp://127.0.0.1:1"}
    meta["software"] = {"package": "fabric-optics", "commit": "0000000+dirty"}
    meta.setdefault("provenance", {})["versions"] = {"commit": "0000000+dirty"}
    (measured / "meta.json").write_text(json.dumps(meta))
    capsys.readouterr()
    counting = Counting(monkeypatch)
    _fit(measured, out)
    assert counting.calls == 0
    assert RESTORED in capsys.readouterr().out


def test_the_key_reads_every_result_option():
    """Each option that changes a result changes the key; the number of threads does not."""
    config = {"a": 1}
    ds = SimpleNamespace(meta={"kind": "measured"}, content_sha256=lambda: "x")
    base = {name: None for name in reuse.RESULT_OPTIONS}
    key = reuse.fit_key(base, config, ds, Path("o"))
    for name in reuse.RESULT_OPTIONS:
        assert reuse.fit_key({**base, name: 1}, config, ds, Path("o")) != key, name
    assert reuse.fit_key({**base, "threads": 2}, config, ds, Path("o")) == key
    assert reuse.fit_key(base, config, ds, Path("p")) != key
