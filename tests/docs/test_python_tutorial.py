"""The Python tutorial (docs/tutorials/python.md) runs: its ```python blocks, in the page's order, in one
namespace, in a temporary folder holding a link to the project's ``fixtures/``, on a reduced budget (its
settings block's ``PLAN`` and ``REL_ERR`` replaced by a small plan of :data:`SMALL_PLAN` and a 30 % Monte Carlo
error);
then what each step wrote is checked."""

from __future__ import annotations

import json
import re
from pathlib import Path

import matplotlib
import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "tutorials" / "python.md"
#: the settings block's lines -> what the test runs instead
REDUCED = {r'^PLAN = "red-cotton"': 'PLAN = "small-plan.toml"', r"^REL_ERR = 0\.03": "REL_ERR = 0.3"}
#: two of the red-cotton plan's incidences, the normal's neighbours on both sides (the normalisation) and the
#: colour geometry, a 20 nm grid (the colour match): about 2 s on the mock
SMALL_PLAN = """\
name = "small"
description = "two incidences of the red-cotton plan, 20 nm"
[sample]
name = "red cotton"
[wavelengths]
start_nm = 400
stop_nm = 700
step_nm = 20
[geometry]
incidence_deg = [0, 45]
in_plane_deg = [-20, -10, 10, 20, 60]
skip_blocked = true
[calibration]
white_standard = "spectralon"
reference_deg = [0, 45]
"""


def blocks() -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", PAGE.read_text(encoding="utf-8"), flags=re.M | re.S)


def test_the_page_has_its_steps():
    code = "\n".join(blocks())
    for call in ("fo.measure_on_mock(", "fo.simulate(", "fo.compare(", "fo.check(", "savefig(", "fo.write_report(",
                 "fo.import_measurement("):
        assert call in code, call


@pytest.mark.timeout(600)
def test_the_python_tutorial_runs_and_writes_what_it_says(tmp_path, monkeypatch, capsys):
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "fixtures").symlink_to(ROOT / "fixtures")
    (tmp_path / "small-plan.toml").write_text(SMALL_PLAN)
    code = blocks()
    for pattern, reduced in REDUCED.items():
        code[0], n = re.subn(pattern, reduced, code[0], flags=re.M)
        assert n == 1, f"the settings block has no line {pattern!r}"
    namespace: dict = {"__name__": "tutorial"}
    for i, block in enumerate(code):
        exec(compile(block, f"{PAGE.name} block {i + 1}", "exec"), namespace)
    out = capsys.readouterr().out

    import fabric_optics as fo

    measured = fo.read_dataset(tmp_path / "py-tutorial" / "measured")
    simulated = fo.read_dataset(tmp_path / "py-tutorial" / "simulated")
    assert measured.kind == "measured" and simulated.kind == "simulated"
    assert set(measured.table["theta_i"]) == {0.0, 45.0}              # the small plan's incidences
    verdict = fo.check(fo.compare(measured, simulated))
    assert verdict.summary() in out
    assert not namespace["at"].empty                                   # the plotted curve has points
    png = tmp_path / "py-tutorial" / "inplane-45deg.png"
    assert png.read_bytes().startswith(b"\x89PNG")
    report = tmp_path / "py-tutorial" / "report"
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["overall"][verdict.name]["nrmse"] == pytest.approx(verdict.figures[0][1])
    assert (report / "report.html").is_file()
    felt = fo.read_dataset(tmp_path / "py-tutorial" / "felt")
    assert felt.is_rgb and f"{felt.name} RGB {len(felt)} values" in out
