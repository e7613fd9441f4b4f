"""The plan of an RGL file's own measured incidences and its retro-reflection ring; datasets made from a file
say which incidences it interpolates."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fabric_optics.cli.gonio import main
from gonio.acquisition.plan import RETRO_RING_DEG, PlanError, load_plan, measured_plan, retro_ring
from gonio.data import geometry as G
from gonio.data.formats.rgl_bsdf import read_rgl_bsdf

FELT = Path(__file__).resolve().parents[3] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
#: the felt file's measured incidences below grazing (deg), as the issue lists them
FELT_INCIDENCES = [0.0, 27.76, 40.03, 50.16, 59.52, 68.77, 78.56]


def read_dataset_geometries(path):
    from gonio.data import read_dataset

    return read_dataset(path).geometries()


def _angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def test_measured_plan_follows_the_file_s_incidences():
    plan = measured_plan(FELT)
    file_deg = read_rgl_bsdf(FELT).theta_i_deg
    assert plan.incidence_deg == pytest.approx(FELT_INCIDENCES, abs=0.01)
    assert all(np.min(np.abs(file_deg - t)) < 1e-3 for t in plan.incidence_deg)     # the file's, to the mdeg
    assert plan.check().ok
    assert load_plan(FELT).incidence_deg == plan.incidence_deg                    # a .bsdf path as the plan


@pytest.mark.parametrize("theta_i", [27.755, 59.517, 78.562])
def test_the_retro_ring_is_at_its_distance_from_the_source(theta_i):
    src = G.direction(theta_i, 0.0)
    for radius in RETRO_RING_DEG:
        ring = retro_ring(theta_i, radius, 4)
        assert 2 <= len(ring) <= 4
        for theta_o, dphi in ring:
            assert _angle_deg(src, G.direction(theta_o, dphi)) == pytest.approx(radius, abs=1e-4)
    plan = measured_plan(FELT)
    g = plan.geometries(measurable_only=True)
    rows = g[np.isclose(g["theta_i"], theta_i)]
    dist = [_angle_deg(src, G.direction(r.theta_o, r.phi_o)) for r in rows.itertuples()]
    assert sum(abs(d - 6.0) < 1e-3 for d in dist) >= 3 and sum(abs(d - 30.0) < 1e-3 for d in dist) >= 2


def test_a_file_without_normal_incidence_or_unreadable_is_refused(tmp_path):
    bad = tmp_path / "x.bsdf"
    bad.write_bytes(b"not a tensor file")
    with pytest.raises(PlanError, match="x.bsdf"):
        measured_plan(bad)


def test_datasets_say_which_incidences_are_interpolated(tmp_path, capsys):
    assert main(["truth", str(FELT), "--plan", "measured", "--out", str(tmp_path / "m")]) == 0
    assert main(["truth", str(FELT), "--plan", "green-felt", "--out", str(tmp_path / "g")]) == 0
    inc_m = json.loads((tmp_path / "m" / "meta.json").read_text())["sample"]["incidences"]
    inc_g = json.loads((tmp_path / "g" / "meta.json").read_text())["sample"]["incidences"]
    assert inc_m["interpolated_deg"] == [] and inc_m["source"] == FELT.name
    assert inc_g["interpolated_deg"] == [30.0, 45.0, 60.0] and "interpolated" in inc_g["note"]
    assert main(["import", "rgl-bsdf", str(FELT), "--plan", "measured", "--out", str(tmp_path / "i")]) == 0
    inc_i = json.loads((tmp_path / "i" / "meta.json").read_text())["sample"]["incidences"]
    assert inc_i["interpolated_deg"] == []
    g = read_dataset_geometries(tmp_path / "i")
    assert len(g) == len(measured_plan(FELT).check().ordered)      # what the instrument measures, as the mock


def test_measured_needs_a_bsdf_sample(tmp_path, capsys):
    code = main(["truth", "red-cotton", "--plan", "measured", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and "--plan measured" in err and len(err.strip().splitlines()) == 1, err


def test_rgb_import_and_spectral_view_of_the_file_agree_on_the_same_geometries():
    """docs/notes/fit-trust.md "two verdicts": on the same (measurable) geometries the mock's spectral view of the
    file, converted back to the file's channels, is the file: colour, level and curves (NRMSE < 0.01)."""
    from compare.comparison import compare_datasets
    from gonio.mock.truth import truth_dataset

    plan = measured_plan(FELT)
    rgb = read_rgl_bsdf(FELT).to_dataset(plan.geometries(measurable_only=True))
    spectral = truth_dataset(str(FELT), plan)
    c = compare_datasets(rgb, [spectral])
    name = next(iter(c.simulated))
    colour = c.colour.simulated[name]
    assert abs(colour.dh) < 1e-3 and abs(colour.ds) < 1e-3
    assert c.level(name).ratio < 1.05
    assert c.overall[name].nrmse < 0.01
