"""``simulate fabric --method mc``: the woven Monte Carlo as a dataset, through the command line."""

from __future__ import annotations

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from gonio.data.dataset import read_dataset

CONFIG = """
seed = 4
[fiber]
radius_um = 10.0
n_host = 1.5
[medium]
mu_s = 0.8
mu_a = 0.01
g = 0.5
[surface]
rms_slope = 0.35
[weave]
preset = "plain"
spacing_um = 300
width_um = 250
height_um = 100
points_per_span = 6
sides = 12
"""

PLAN = """
[sample]
name = "tiny"
[wavelengths]
list_nm = [550]
[geometry]
incidence_deg = [0, 45]
in_plane_deg = [-30, 0, 30, 60]
"""


@pytest.fixture
def inputs(tmp_path):
    """The grey plain-weave config and the tiny plan, written as files."""
    cfg = tmp_path / "grey.toml"
    cfg.write_text(CONFIG)
    plan = tmp_path / "tiny.toml"
    plan.write_text(PLAN)
    return cfg, plan


def test_fabric_mc_writes_a_dataset_with_its_errors_and_stop(inputs, tmp_path, capsys):
    cfg, plan = inputs
    out = tmp_path / "mc"
    assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(out),
                 "--target-rel-err", "0.05", "--no-progress"]) == 0
    assert "mc" in capsys.readouterr().out
    ds = read_dataset(out)
    t = ds.table
    assert len(t) == 8 and np.all(np.isfinite(t["beta"])) and np.all(t["beta"] > 0)
    assert np.all(t["u_beta"] > 0) and np.all(t["u_beta"] < 0.2 * t["beta"])
    prov = ds.meta["provenance"]
    info = prov["fiber_info"]
    assert info["stop"] == "target" and len(info["incidences"]) == 2
    assert all(r["rel_err"] <= 0.05 for r in info["incidences"])
    assert ds.meta["model"]["method"] == "mc" and ds.meta["model"]["weave"]["matrix"] == [[1, 0], [0, 1]]
    # the same seed gives the same dataset (fixed streams per chunk and incidence)
    out2 = tmp_path / "mc2"
    assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(out2),
                 "--target-rel-err", "0.05", "--no-progress", "--threads", "1"]) == 0
    np.testing.assert_array_equal(read_dataset(out2).table["beta"].to_numpy(), t["beta"].to_numpy())


def test_fabric_mc_ray_budget_is_reported(inputs, tmp_path, capsys):
    cfg, plan = inputs
    out = tmp_path / "mc"
    assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(out),
                 "--target-rel-err", "0.01", "--max-photons", "1024", "--no-progress"]) == 0
    info = read_dataset(out).meta["provenance"]["fiber_info"]
    # two traces per incidence, one per half of the BSSRDF table
    assert info["stop"] == "max_rays" and all(r["rays"] == 2048 for r in info["incidences"])


def test_fabric_auto_records_the_method_of_every_geometry(inputs, tmp_path, capsys):
    cfg, plan = inputs
    # a woven [structure]: auto reads the woven fabric's study (simulate.fabric.auto.table_for)
    cfg.write_text(CONFIG + '[structure]\nkind = "woven"\n')
    out = tmp_path / "auto"
    # at 5 % the shipped red-cotton study (the summation within 3-9 % of the MC) allows the
    # summation at some of these geometries only, the MC at the others
    assert main(["fabric", str(cfg), "--method", "auto", "--plan", str(plan), "--out", str(out),
                 "--target-rel-err", "0.05", "--no-progress"]) == 0
    ds = read_dataset(out)
    chosen = ds.meta["model"]["method_per_geometry"]
    assert len(chosen) == 8 and len(set(chosen)) >= 2
    assert set(chosen) <= {"classic", "summation", "mc"}
    assert sum(ds.meta["model"]["methods_used"].values()) == 8
    assert np.all(np.isfinite(ds.table["beta"])) and np.all(ds.table["beta"] > 0)


def test_the_tables_own_noise_is_in_u_beta():
    """Runs with different seeds build different BSSRDF tables: they must agree within the
    reported errors, which therefore have to include the table's noise (not only the rays')."""
    from simulate import fiber as F
    from simulate import raytrace as W
    from simulate.geometry import weave
    from simulate.geometry.mesh import mesh as weave_mesh
    from simulate.media.medium import HGMedium

    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.35, 10.0)
    mesh = weave_mesh(weave.preset("plain", points_per_span=6, sides=12))
    t = np.radians([0.0, 30.0, 60.0])
    w_in = np.tile([np.sin(0.5), 0.0, np.cos(0.5)], (3, 1))
    w_out = np.column_stack([np.sin(t), 0 * t, np.cos(t)])
    runs = [W.fabric_beta(mesh, fib, w_in, w_out, [550.0], target_rel_err=0.03, seed=s) for s in (1, 2)]
    (b1, u1, i1), (b2, u2, i2) = runs
    assert all(r["table_rel_err"] > 0 for r in i1["incidences"] + i2["incidences"])
    z = (b1 - b2) / np.hypot(u1, u2)
    assert np.max(np.abs(z)) < 4.0, z


@pytest.fixture(scope="module")
def red_cotton_mc_colour(tmp_path_factory):
    """The red-cotton preset's colour by ``simulate fabric --method mc`` at 2 % (one run for both tests)."""
    from gonio.data.colour import spectrum_colour

    tmp_path = tmp_path_factory.mktemp("rc_mc")
    plan = tmp_path / "colour.toml"
    plan.write_text('name = "colour"\n[sample]\nname = "red cotton"\n[wavelengths]\nstart_nm = 390\n'
                    'stop_nm = 710\nstep_nm = 10\n[geometry]\nincidence_deg = [0]\nin_plane_deg = [10]\n')
    assert main(["fabric", "red-cotton", "--method", "mc", "--plan", str(plan), "--target-rel-err", "0.02",
                 "--no-progress", "--out", str(tmp_path / "mc")]) == 0
    ds = read_dataset(tmp_path / "mc")
    info = ds.meta["provenance"]["fiber_info"]
    assert info["yarn_surface"] == "fibers" and info["yarn_volume"] == "pile"
    t = ds.table.sort_values("wavelength_nm")
    return spectrum_colour(t["wavelength_nm"].to_numpy(), t["beta"].to_numpy())


@pytest.mark.slow
def test_red_cotton_mc_colour_in_the_published_range(red_cotton_mc_colour):
    """The shipped preset through ``simulate fabric --method mc`` at the report's colour geometry
    (incidence 0, observation 10 deg): in the published ranges (H 0.97-0.99, S >= 0.97,
    BLUE/RED 0.05-0.25, GREEN/RED 0.005-0.03) with the yarns made of fibers (docs/physics.md 6).
    The yarn as a tube of the fiber's own table gave S 0.944, GREEN/RED 0.056 (fails here); the
    fibers' surface alone S 0.965, GREEN/RED 0.035 (fails); the run's noise is ~0.002 in S."""
    c = red_cotton_mc_colour
    assert 0.97 <= c.h <= 0.99 and c.s >= 0.97, c
    assert 0.05 <= c.blue_red <= 0.25 and 0.005 <= c.green_red <= 0.03, c
