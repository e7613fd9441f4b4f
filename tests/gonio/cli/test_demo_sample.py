"""`gonio demo --sample`: the mock's virtual sample chosen like `gonio mock --sample`
(the demo measures the real RGL felt through the mock), bad samples refused in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fabric_optics.cli.gonio import main
from gonio.data import read_dataset

FELT = Path(__file__).parents[3] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"

TINY_PLAN = """name = "tiny-felt"
[sample]
name = "tiny felt check"
[wavelengths]
list_nm = [450, 550, 650]
[geometry]
incidence_deg = [0, 45]
in_plane_deg = [-30, 10, 40]
[acquisition]
itime_ms = 100
gain = 0
readings = 8
[calibration]
white_standard = "spectralon"
reference_deg = [0, 45]
"""


@pytest.mark.parametrize("sample,needle", [
    ("no-such-sample", "unknown sample 'no-such-sample'"),
    ("lambert:3", "lambert:3: the reflectance must be in 0..1"),
    ("missing.bsdf", "unknown sample 'missing.bsdf'"),
    ("{bad_bsdf}", "bad.bsdf"),
])
def test_a_bad_sample_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, sample, needle):
    bad = tmp_path / "bad.bsdf"
    bad.write_bytes(b"not a tensor file at all")
    out = tmp_path / "out"
    assert main(["demo", "--sample", sample.replace("{bad_bsdf}", str(bad)), "--plan", "quick",
                 "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio demo: --sample:") and needle in err[0], err
    assert not out.exists()


def test_the_felt_measured_through_the_mock_recovers_the_file(tmp_path, capsys):
    """The real felt in the mock, a 6-geometry x 3-wavelength plan: every measured value within
    4 of its standard uncertainties of the spectrum colour-science's Mallett-Yuksel decomposition
    gives the file's RGB at that wavelength (the mock's view of an RGB file, gonio.mock.upsample),
    green at every geometry, and the dataset says what the mock held (the file, its SHA-256, its
    source and licence)."""
    from colour.recovery import RGB_to_sd_Mallett2019

    from gonio.data.formats.rgl_bsdf import read_rgl_bsdf

    plan = tmp_path / "tiny.toml"
    plan.write_text(TINY_PLAN)
    out = tmp_path / "felt"
    assert main(["demo", "--sample", str(FELT), "--plan", str(plan), "--out", str(out),
                 "--no-progress"]) == 0
    assert f"holding {FELT}" in capsys.readouterr().out
    ds = read_dataset(out)
    t = ds.table.sort_values(["theta_i", "theta_o", "phi_o", "wavelength_nm"])
    assert len(t) == 18
    rgb = read_rgl_bsdf(FELT).beta(t["theta_i"].to_numpy(), t["phi_i"].to_numpy(),
                                   t["theta_o"].to_numpy(), t["phi_o"].to_numpy())   # R, G, B
    truth = np.array([RGB_to_sd_Mallett2019(c[:3])[w] for c, w in zip(rgb, t["wavelength_nm"], strict=True)])
    z = (t["beta"].to_numpy() - truth) / t["u_beta"].to_numpy()
    assert np.all(np.abs(z) < 4), z
    b, g, r = (t["beta"].to_numpy().reshape(-1, 3)[:, k] for k in range(3))
    assert np.all(g > r) and np.all(r > b)
    sample = ds.meta["sample"]
    assert sample["name"] == "tiny felt check"            # --plan given: the plan names it
    mock = sample["mock_sample"]
    assert mock["path"] == str(FELT) and mock["description"] == "Green acrylic felt (Edukit A4)"
    assert mock["sha256"] == "3429e2bdbe2045dca11582479fa251866ffe056b909b47e3fbf1c3c776fcb72b"
    assert "CC0" in mock["source"] and "RGL" in mock["source"]


def test_without_a_plan_the_dataset_is_named_after_the_sample():
    from gonio.demo import demo_sample_meta
    from gonio.mock.samples import BSDFSample

    felt = BSDFSample(FELT)
    named = demo_sample_meta({"name": "red cotton", "material": "woven cotton"}, felt,
                             name_from_sample=True)
    assert named["name"] == "Green acrylic felt (Edukit A4)" and "cotton" not in named["material"]
    kept = demo_sample_meta({"name": "red cotton"}, felt)
    assert kept["name"] == "red cotton" and kept["mock_sample"]["name"] == "acrylic_felt_green_rgb"
