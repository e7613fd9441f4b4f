"""A sweep with a measurement: compare figures in summary.csv, and ``compare report MEASURED SWEEP_DIR``."""

from __future__ import annotations

import csv
import html.parser
import math

import numpy as np
import pytest

from fabric_optics.cli.compare import main as compare_main
from fabric_optics.sweep.runner import prepare_out, run_sweep
from gonio.acquisition.plan import load_plan
from gonio.data.dataset import write_dataset
from gonio.mock.truth import truth_dataset

from .conftest import make_spec, plan_text, write_plan

#: a cluster's scheduler HTTP server moves to a free port when another test's cluster holds 8787
pytestmark = pytest.mark.filterwarnings("ignore:Port .* is already in use")

# colour needs a regular 20 nm grid (ASTM E308); three in-plane angles on each side of the normal (the normal value is estimated)
PLAN = plan_text("start_nm = 420\nstop_nm = 700\nstep_nm = 20", in_plane="[-30, -20, -10, 10, 20, 40]")


class _Images(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.sources: list[str] = []

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.sources.append(dict(attrs).get("src", ""))


def test_sweep_with_measurement_and_its_report(tmp_path, inproc_client, capsys):
    plan_path = write_plan(tmp_path, PLAN)
    measured = tmp_path / "measured"
    write_dataset(truth_dataset("red-cotton", load_plan(plan_path)), measured)
    spec = make_spec(plan_path, ["rms_slope=0.2,0.35,0.5"])
    out = tmp_path / "sweep"
    prepare_out(out, spec)
    from gonio.data.dataset import read_dataset

    result = run_sweep(spec, out, inproc_client, measured=read_dataset(measured))
    assert not result.failures and result.computed == 3 * 15
    with open(out / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["rms_slope"]) for r in rows] == [0.2, 0.35, 0.5]
    for r in rows:
        assert all(math.isfinite(float(r[k])) for k in ("nrmse", "dh", "ds", "seconds", "rel_err"))
        assert 0 < float(r["nrmse"]) < 1

    report_dir = tmp_path / "report"
    assert compare_main(["report", str(measured), str(out), "--out", str(report_dir)]) == 0
    text = (report_dir / "report.html").read_text(encoding="utf-8")
    parser = _Images()
    parser.feed(text)
    parser.close()
    assert len(parser.sources) >= 4 and all(s.startswith("data:image/png;base64,") for s in parser.sources)
    assert "<h2>Parameter sweep</h2>" in text and text.index("Parameter sweep") < text.index("<h2>Datasets")
    assert "figures/sweep_metrics.png" in text and (report_dir / "figures" / "sweep_metrics.png").is_file()
    for label in ("rms_slope=0.2", "rms_slope=0.35", "rms_slope=0.5"):
        assert label in text
    with open(report_dir / "sweep_metrics.csv", newline="") as fh:
        charted = list(csv.DictReader(fh))
    np.testing.assert_allclose([float(r["nrmse"]) for r in charted], [float(r["nrmse"]) for r in rows], rtol=1e-9)

    # a previous sweep report is replaced in place with --force; a sweep directory must be the only SIMULATED
    assert compare_main(["report", str(measured), str(out), "--out", str(report_dir), "--force"]) == 0
    capsys.readouterr()
    assert compare_main(["report", str(measured), str(out), str(out / "points" / "rms_slope=0.2"),
                         "--out", str(tmp_path / "r2")]) == 2
    assert "must be the only SIMULATED" in capsys.readouterr().err
