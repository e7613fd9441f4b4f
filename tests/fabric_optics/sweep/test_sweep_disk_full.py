"""simulate sweep on a full disk: one line naming the file, nothing half-written, the finished tasks kept."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from fabric_optics.cli.simulate import main
from fabric_optics.sweep import runner as sweep_mod
from fabric_optics.sweep.runner import SweepError, finished_tasks, prepare_out, run_sweep
from gonio.data import dataset as dataset_mod

from .conftest import make_spec, write_plan

pytestmark = pytest.mark.filterwarnings("ignore:Port .* is already in use")


def _enospc(path, data=None):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def test_sweep_json_on_a_full_disk_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sweep_mod, "atomic_write", _enospc)
    plan = write_plan(tmp_path)
    out = tmp_path / "s"
    assert main(["sweep", "red-cotton", "--param", "rms_slope=0.2,0.4", "--method", "classic", "--plan",
                 str(plan), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"{out / 'sweep.json'}: cannot write (No space left on device)" in err
    assert not (out / "sweep.json").exists()


def test_full_disk_while_assembling_keeps_tasks_and_leaves_no_partial_point(tmp_path, monkeypatch, inproc_client):
    spec = make_spec(write_plan(tmp_path), ["rms_slope=0.2,0.4"])
    out = tmp_path / "s"
    prepare_out(out, spec)
    real = dataset_mod.atomic_write
    writes: list[str] = []

    def full_on_the_second_point(path, data):
        writes.append(Path(path).name)
        if writes.count("radiance.csv") == 2 and Path(path).name == "meta.json":
            _enospc(path)
        real(path, data)

    monkeypatch.setattr(dataset_mod, "atomic_write", full_on_the_second_point)
    with pytest.raises(SweepError) as info:
        run_sweep(spec, out, inproc_client)
    message = str(info.value)
    assert "points/rms_slope=0.4: cannot write the dataset (No space left on device)" in message
    assert "finished tasks are kept" in message
    points = out / "points"
    assert sorted(p.name for p in points.iterdir()) == ["rms_slope=0.2"]     # no half point, no temp folder
    assert len(finished_tasks(out, spec)) == len(spec.tasks())
    monkeypatch.setattr(dataset_mod, "atomic_write", real)
    result = run_sweep(spec, out, None)                 # every task stored: nothing to compute
    assert result.computed == 0 and list(result.summary["status"]) == ["complete", "complete"]
