"""``simulate fabric`` writes its dataset as one folder (:mod:`simulate.outdir`): a full disk or a
kill at any step leaves the previous output whole, and the next run cleans up and succeeds."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from fabric_optics.cli.simulate import main
from gonio.data import dataset as dataset_mod
from gonio.data.dataset import read_dataset
from simulate.outdir import recover, side_folders

GOOD_CONFIG = """
[fiber]
radius_um = 8.0
n_host = 1.557
[medium]
mu_s = 1.0
mu_a = 0.01
g = 0.8
[surface]
rms_slope = 0.3
"""


@pytest.fixture
def cfg(tmp_path):
    path = tmp_path / "good.toml"
    path.write_text(GOOD_CONFIG)
    return path


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def _fabric(cfg: Path, out: Path, method: str = "classic") -> int:
    return main(["fabric", str(cfg), "--method", method, "--out", str(out), "--plan", "quick", "--force"])


def test_disk_full_leaves_the_previous_output_and_no_temporary_folder(fake_fiber, tmp_path, cfg, capsys,
                                                                       monkeypatch):
    out = tmp_path / "sim"
    assert _fabric(cfg, out) == 0
    before = _snapshot(out)
    capsys.readouterr()
    real = dataset_mod.atomic_write
    calls = []

    def full_after_the_csv(path, data):
        calls.append(Path(path).name)
        if len(calls) == 2:                    # radiance.csv written, meta.json hits ENOSPC
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        real(path, data)

    monkeypatch.setattr(dataset_mod, "atomic_write", full_after_the_csv)
    assert _fabric(cfg, out, "summation") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"{out}: cannot write the dataset (No space left on device)" in err
    assert calls == ["radiance.csv", "meta.json"]
    assert _snapshot(out) == before            # the classic output, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.toml", "sim"]


def test_disk_full_on_a_new_directory_leaves_nothing(fake_fiber, tmp_path, cfg, capsys, monkeypatch):
    def full(path, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(dataset_mod, "atomic_write", full)
    out = tmp_path / "new"
    assert _fabric(cfg, out) == 2
    assert "No space left on device" in capsys.readouterr().err
    # _prepare_out made the (empty) directory; nothing else is left
    assert [p.name for p in tmp_path.iterdir() if p.name != "good.toml"] in (["new"], [])
    assert not out.exists() or list(out.iterdir()) == []


_KILL = textwrap.dedent("""
    import os, sys
    from gonio.data.dataset import read_dataset
    from simulate import outdir
    out, at = sys.argv[1], int(sys.argv[2])
    ds = read_dataset(out)
    ds.table["beta"] = ds.table["beta"] * 2.0
    real, calls = os.rename, []
    def rename(src, dst):
        calls.append(1)
        if len(calls) == at:
            os._exit(9)                        # killed: no finally, no cleanup
        real(src, dst)
    outdir.os.rename = rename
    outdir.write_dataset_dir(ds, out)
""")


@pytest.mark.parametrize("at", [1, 2])     # 1: before the old folder is moved aside; 2: before the new one moves in
def test_killed_between_the_steps_then_rerun(fake_fiber, tmp_path, cfg, capsys, at):
    out = tmp_path / "sim"
    assert _fabric(cfg, out) == 0
    before = _snapshot(out)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-c", _KILL, str(out), str(at)], env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 9, proc.stderr
    kinds = sorted(kind for _, _, kind in side_folders(out))
    assert kinds == ["old", "partial"]         # at 1 the .old folder is still the empty placeholder
    assert out.exists() == (at == 1)           # between the two renames the name is briefly absent
    # the dead run's folders are recognised: the previous output comes back whole
    recover(out)
    assert side_folders(out) == [] and _snapshot(out) == before
    # and the same command runs again, replacing it
    assert _fabric(cfg, out, "summation") == 0
    assert read_dataset(out).meta["model"]["method"] == "summation"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.toml", "sim"]


def test_rerun_after_a_kill_cleans_up_by_itself(fake_fiber, tmp_path, cfg):
    out = tmp_path / "sim"
    assert _fabric(cfg, out) == 0
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    assert subprocess.run([sys.executable, "-c", _KILL, str(out), "2"], env=env, timeout=900).returncode == 9
    assert _fabric(cfg, out, "summation") == 0       # no manual recover()
    assert side_folders(out) == [] and read_dataset(out).meta["model"]["method"] == "summation"


def test_a_live_run_s_folders_are_left_alone(tmp_path):
    out = tmp_path / "sim"
    live = tmp_path / f".sim.{os.getppid()}.abcdefgh.partial"      # the parent process (pytest's) is alive
    dead_pid = 2**22 + 12345                                          # above the kernel's pid_max default
    dead = tmp_path / f".sim.{dead_pid}.abcdefgh.partial"
    live.mkdir()
    dead.mkdir()
    (tmp_path / ".other.1.abcdefgh.partial").mkdir()                  # another output's: not ours
    assert recover(out) == [dead]
    assert live.is_dir() and not dead.exists() and (tmp_path / ".other.1.abcdefgh.partial").is_dir()


def test_previous_output_with_user_files_is_not_swallowed(fake_fiber, tmp_path, cfg, capsys):
    out = tmp_path / "sim"
    assert _fabric(cfg, out) == 0
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert _fabric(cfg, out) == 2
    err = capsys.readouterr().err
    assert "'notes.txt'" in err and err.count("\n") == 1
    assert (out / "notes.txt").read_text() == "mine"


def test_recover_all_handles_every_output_of_a_folder(tmp_path):
    from simulate.outdir import recover_all

    dead = 2**22 + 4321
    (tmp_path / "a=1").mkdir()
    (tmp_path / f".a=1.{dead}.abcdefgh.partial").mkdir()          # a's new output, half written
    old_b = tmp_path / f".b=0.5.{dead}.zyxw_123.old"                # b's previous output, moved aside
    old_b.mkdir()
    (old_b / "meta.json").write_text("{}")
    recover_all(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a=1", "b=0.5"]
    assert (tmp_path / "b=0.5" / "meta.json").read_text() == "{}"   # restored, not deleted


def test_the_state_an_older_version_left_is_recognised_and_replaced(fake_fiber, tmp_path, cfg, capsys):
    """Killed between its two renames, the per-file writer left radiance.csv alone with
    its temporary files, and the rerun was refused. Now it is recognised, replaced and cleaned."""
    out = tmp_path / "sim"
    assert _fabric(cfg, out) == 0
    meta = (out / "meta.json").read_bytes()
    (out / "meta.json").unlink()
    (out / ".meta.json.ab12cd34.tmp").write_bytes(meta)          # written, never renamed
    (out / ".radiance.csv.zz99yy88.tmp").write_bytes(b"partial")
    assert _fabric(cfg, out, "summation") == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["meta.json", "radiance.csv"]
    assert read_dataset(out).meta["model"]["method"] == "summation"
    # a lone radiance.csv without such a temporary file is still not taken for an output
    (out / "meta.json").unlink()
    assert _fabric(cfg, out) == 2


def test_fiber_table_on_a_full_disk_is_one_line(fake_fiber, tmp_path, cfg, capsys, monkeypatch):
    from simulate.fiber import tables

    def full(path, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(tables, "atomic_write", full)
    out = tmp_path / "table"
    assert main(["fiber", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert str(out) in err and "cannot write (No space left on device)" in err
