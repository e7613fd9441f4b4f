"""Versions you can trace: ``--version`` of the three commands, ``fabric_optics.__version__``, a dataset's
``meta.json`` and a report name the same version (pyproject.toml's) and, in a git checkout, the same commit
(git's own answer)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import fabric_optics
from fabric_optics.cli import compare as compare_cli
from fabric_optics.cli import gonio as gonio_cli
from fabric_optics.cli import simulate as simulate_cli

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT_VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def _git_commit() -> str | None:
    """The checkout's commit as git says it (``+dirty`` with modified tracked files), None outside one."""
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        return None
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short=7", "HEAD"], capture_output=True,
                          text=True, check=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True, check=True).stdout.strip()
    return head + ("+dirty" if dirty else "")


def _version_line(main, capsys) -> str:
    try:
        status = main(["--version"])
    except SystemExit as exc:       # argparse's version action, outside a main that catches it
        status = exc.code
    assert status in (0, None)
    return capsys.readouterr().out.strip()


def test_the_three_commands_the_package_and_a_dataset_name_one_version_and_commit(capsys, tmp_path):
    commit = _git_commit()
    expected = PYPROJECT_VERSION + (f" (git {commit})" if commit else "")
    lines = {name: _version_line(main, capsys) for name, main in
             (("gonio", gonio_cli.main), ("simulate", simulate_cli.main), ("compare", compare_cli.main))}
    assert lines == {name: f"{name} {expected}" for name in lines}
    assert fabric_optics.__version__ == PYPROJECT_VERSION

    # a dataset written by the API: its meta.json's software, and the instrument's provenance
    import fabric_optics as fo

    fo.write_dataset(fo.truth("lambert:0.5", plan="red-cotton"), tmp_path / "truth")
    meta = json.loads((tmp_path / "truth" / "meta.json").read_text())
    assert meta["software"]["package"] == "fabric-optics"
    assert (meta["software"]["version"], meta["software"]["commit"]) == (PYPROJECT_VERSION, commit)
    # a simulation's provenance (simulate.provenance: fits, sweeps, fiber tables, simulated datasets)
    from simulate.provenance import software_versions

    versions = software_versions()
    assert (versions["fabric-optics"], versions["commit"]) == (PYPROJECT_VERSION, commit)


def test_a_report_names_the_version_and_commit_that_wrote_it(capsys, tmp_path):
    commit = _git_commit()
    out = tmp_path / "report"
    assert compare_cli.main(["report", str(ROOT / "fixtures" / "analytic" / "measured_red"), "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert (metrics["software"]["version"], metrics["software"]["commit"]) == (PYPROJECT_VERSION, commit)
    page = (out / "report.html").read_text()
    footer = re.search(r"<footer>.*?Written by (fabric-optics [^<]+)\.</p></footer>", page)
    assert footer and footer.group(1) == f"fabric-optics {PYPROJECT_VERSION}" + (f" (git {commit})" if commit else "")


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_the_commit_is_marked_dirty_when_a_tracked_file_changes(tmp_path):
    """The version module in a small checkout of its own: the commit git names, then ``+dirty`` once a
    tracked file is edited (an untracked file does not count)."""
    repo = tmp_path / "repo"
    (repo / "gonio").mkdir(parents=True)
    shutil.copy(ROOT / "gonio" / "version.py", repo / "gonio" / "version.py")
    (repo / "gonio" / "__init__.py").write_text("")
    (repo / "notes.txt").write_text("one\n")

    def git(*args):
        return subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@example.org", *args],
                              capture_output=True, text=True, check=True).stdout.strip()

    git("init", "-q")
    git("add", ".")
    git("commit", "-qm", "start")
    head = git("rev-parse", "--short=7", "HEAD")
    # -S: no site-packages, so the installed gonio cannot shadow the copy
    probe = [sys.executable, "-S", "-c", "import sys; sys.path.insert(0, '.'); from gonio import version; "
             "print(version.commit())"]

    def commit():
        return subprocess.run(probe, cwd=repo, capture_output=True, text=True, check=True).stdout.strip()

    (repo / "untracked.txt").write_text("new\n")
    clean = commit()
    (repo / "notes.txt").write_text("two\n")
    assert (clean, commit()) == (head, f"{head}+dirty")
