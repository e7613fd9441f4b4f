"""A full disk (ENOSPC) while `compare report`, `compare render` or `simulate export` writes: one line, exit 2,
no traceback, no partial file and no temporary file left; a previous report or render stays as it was."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from compare.comparison import compare_datasets
from compare.errors import CompareError
from compare.report import write_report
from gonio.data import write_files_together


def _everything(folder):
    """Every file under ``folder`` (hidden ones too) with its bytes."""
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _full_after(monkeypatch, n_ok):
    """os.fsync fails with ENOSPC after ``n_ok`` successful calls (the ``n_ok + 1``-th file's write)."""
    real = os.fsync
    calls = []

    def fsync(fd):
        calls.append(fd)
        if len(calls) > n_ok:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)
    monkeypatch.setattr(os, "fsync", fsync)
    return calls


def test_files_written_together_leave_nothing_when_one_fails(tmp_path, monkeypatch):
    out = tmp_path / "new"
    _full_after(monkeypatch, 1)
    with pytest.raises(OSError) as err:
        write_files_together(out, {"a.txt": b"a", "sub/b.txt": b"b", "c.txt": b"c"})
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(out / "sub" / "b.txt")
    assert not out.exists()                                # the folders it created are gone too
    monkeypatch.undo()
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "a.txt").write_bytes(b"previous")
    (tmp_path / "old" / "notes.txt").write_bytes(b"the user's")
    _full_after(monkeypatch, 2)
    with pytest.raises(OSError):
        write_files_together(tmp_path / "old", {"a.txt": b"new", "b.txt": b"b", "c.txt": b"c"})
    assert _everything(tmp_path / "old") == {Path("a.txt"): b"previous",
                                             Path("notes.txt"): b"the user's"}


def _small(h):
    """A small measurement and simulation (two incidences, three wavelengths: five figures, no colour)."""
    wl = np.array([450.0, 550.0, 650.0])
    meas = h.dataset(h.in_plane_table(h.red_lobe, incidence=(0.0, 30.0), wavelengths=wl))
    sim = h.dataset(h.in_plane_table(lambda t, s, w: 0.8 * h.red_lobe(t, s, w), incidence=(0.0, 30.0),
                                     wavelengths=wl), kind="simulated", name="sim")
    return meas, sim


def test_a_report_on_a_full_disk_writes_nothing_and_keeps_the_previous_one(h, tmp_path, monkeypatch):
    comparison = compare_datasets(*_small(h)[:1], [_small(h)[1]])
    out = tmp_path / "r"
    calls = _full_after(monkeypatch, 2)                    # the third file of the report fails
    with pytest.raises(CompareError) as err:
        write_report(comparison, out)
    assert len(calls) == 3
    text = str(err.value)
    assert "No space left on device" in text and str(out) in text and "(None)" not in text and "\n" not in text
    assert not out.exists()                                # no figure, no temporary file, no folder
    monkeypatch.undo()
    write_report(comparison, out)                          # a previous report ...
    before = _everything(out)
    _full_after(monkeypatch, 4)
    with pytest.raises(CompareError):
        write_report(comparison, out, svg=True)            # ... is left exactly as it was
    assert _everything(out) == before


def test_compare_report_on_a_full_disk_is_one_line_exit_2(h, tmp_path, monkeypatch, capsys):
    from gonio.data import write_dataset

    meas, sim = _small(h)
    write_dataset(meas, tmp_path / "m")
    write_dataset(sim, tmp_path / "s")
    _full_after(monkeypatch, 2)
    out = tmp_path / "r"
    status, _, err = h.run_cli(["report", tmp_path / "m", tmp_path / "s", "--out", out], capsys)
    assert status == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert "No space left on device" in err and "figures/" in err and "(None)" not in err
    assert not out.exists()
    status, _, err = h.run_cli(["report", tmp_path / "m", "--out", out], capsys)   # the dataset report
    assert status == 2 and err.count("\n") == 1 and "No space left on device" in err and not out.exists()


def test_a_render_set_on_a_full_disk_writes_nothing(tmp_path, monkeypatch):
    from compare.render import RenderedImage, RenderSettings, write_render_set

    rgb = np.random.default_rng(0).random((12, 16, 3))
    images = [RenderedImage("red", scene, rgb, 0.1, 4) for scene in ("cushion", "swatch, light 0")]
    s = RenderSettings(spp=4, size=(16, 12), swatch_size=12)
    out = tmp_path / "renders"
    _full_after(monkeypatch, 0)
    with pytest.raises(CompareError) as err:
        write_render_set(images, out, s)
    assert "No space left on device" in str(err.value) and "0_0.png" in str(err.value)
    assert not out.exists()
    monkeypatch.undo()
    write_render_set(images, out, s)
    before = _everything(out)
    assert {p.name for p in before} == {"0_0.png", "0_1.png", "render_sheet.png", "render.json"}
    _full_after(monkeypatch, 2)
    with pytest.raises(CompareError):
        write_render_set(images, out, s)
    assert _everything(out) == before


def test_simulate_export_on_a_full_disk_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    from fabric_optics.cli.simulate import main

    out = tmp_path / "c.bsdf"
    _full_after(monkeypatch, 0)
    status = main(["export", "red-cotton", "--method", "classic", "--out", str(out), "--wavelengths", "450:650:100",
                   "--resolution", "8", "--incidences", "3", "--no-progress"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert f"{out}: cannot write (No space left on device)" in err
    assert list(tmp_path.iterdir()) == []                 # no file, no temporary file
