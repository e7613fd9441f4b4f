"""The felt (nonwoven) Monte Carlo: its random fiber layer, reproducibility, the command line, the summation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from gonio.data.dataset import read_dataset
from simulate import fabric as fab
from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry.felt import felt_mesh
from simulate.media.medium import HGMedium


def test_the_felts_fibers_follow_the_structures_distribution():
    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=20.0, layers=6)
    m = felt_mesh(spec, 10.0, seed=3)
    first = m.vertex_base                      # one tangent per fiber image
    t = m.tangents[first]
    # inclination: |sin eps| of a normal eps (sd 20 deg), mean sqrt(2/pi) sigma to first order
    eps = np.arcsin(np.abs(t[:, 2]))
    assert abs(np.degrees(np.sqrt(np.mean(eps ** 2))) - 20.0) < 3.0
    # in-plane direction uniform over [0, 180): no preferred axis (the mean of exp(2 i az) is ~0)
    az = np.arctan2(t[:, 1], t[:, 0])
    assert abs(np.mean(np.exp(2j * az))) < 0.2
    # every triangle winds outward (its normal agrees with the radial vertex normals)
    v, f = m.vertices, m.faces
    g = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", g, m.normals[f].sum(axis=1)) > 0)
    # the fibers' projected area is the summation's layers of fibers at the packing's spacing
    n, R, ell = m.info["fibers"], 10.0, m.info["fiber_length_um"]
    assert n * 2 * R * ell * 0.8 < 6 * m.Lx * m.Ly / spec.spacing_ratio < n * 2 * R * ell * 1.05
    assert m.info["layers"] == 6


def test_the_felts_fibers_do_not_interpenetrate(monkeypatch):
    """Random points on the fibers' surfaces lie inside no other fiber (an independent check:
    point-in-cylinder, not the placement's segment distance); with the contact rule switched off
    (every fiber dropped to the floor) the same check finds them buried, so it can fail."""
    from fabric_optics.bench.felt import buried_fraction
    from simulate.geometry import felt

    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=20.0, layers=4)
    m = felt_mesh(spec, 10.0, seed=5)
    assert buried_fraction(m) == 0.0
    # the straight fibers' lowest-gap deposition reaches a bulk volume fraction of ~0.11 (spread 20)
    assert 0.06 < m.info["volume_fraction"] < 0.2 and m.info["thickness_um"] > 4 * 20.0
    monkeypatch.setattr(felt, "CONTACT", -1.0)
    assert buried_fraction(felt_mesh(spec, 10.0, seed=5)) > 0.05


def test_the_felt_is_reproducible_at_a_fixed_seed():
    # four of the default's ten layers: the same random placement and deposition, 40 % of the fibers
    spec = ST.StructureSpec(kind="nonwoven", layers=4)
    a, b, c = felt_mesh(spec, 10.0, seed=1), felt_mesh(spec, 10.0, seed=1), felt_mesh(spec, 10.0, seed=2)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)
    w_in, det = fab.directions_deg([10.0], [0.0])[0], fab.directions_deg([0.0, 30.0], [0.0, 90.0])
    r1, r2 = (W.trace(a, W.Lambert(0.8), w_in, det, target_rel_err=1e-9, max_rays=8192, seed=4, chunk=4096)
              for _ in range(2))
    assert np.array_equal(r1.beta, r2.beta) and r1.info["lost_rays"] == 0


@pytest.mark.slow
def test_felt_mc_walks_absorbing_fibers_as_the_summation_does():
    """The felt of non-interpenetrating fibers against the structured summation at its own volume
    fraction (packing 0.11, 29 layers: the fiber amount of 10 touching layers), incidence 0 /
    observation 10 deg, a non-absorbing and an absorbing HG fiber (mu_a 0.01 /um). Each ratio MC /
    summation is within [0.90, 1.02] (measured 0.939 +- 0.010 and 0.937 +- 0.016: the random layer
    and the summation's layers differ by a few % in how deep light goes), and -- what the
    interpenetrating felt failed (0.992 vs 0.848, docs/physics.md 6) -- absorption changes the two
    alike: the ratios agree within 3 combined standard errors."""
    spec = ST.StructureSpec(kind="nonwoven", packing_fraction=0.11, layers=29)
    mesh = felt_mesh(spec, 10.0, seed=0)
    assert abs(mesh.info["volume_fraction"] - 0.11) < 0.03
    w_i, w_o = fab.directions_deg([0.0], [0.0]), fab.directions_deg([10.0], [180.0])
    ratio, u_ratio = [], []
    for mu_a in (0.0, 0.01):
        fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=mu_a, g=0.5), 0.35, 10.0)
        bs, us, _ = ST.structured_beta(spec, fib, None, w_i, w_o, [550.0], target_rel_err=0.02, seed=1, threads=1)
        b, u, info = W.fabric_beta(mesh, fib, w_i, w_o, [550.0], target_rel_err=0.015, seed=0, threads=1)
        assert info["incidences"][0]["lost_rays"] == 0
        r = b[0, 0] / bs[0, 0]
        ratio.append(r)
        u_ratio.append(r * math.hypot(u[0, 0] / b[0, 0], us[0, 0] / bs[0, 0]))
        assert 0.90 - 3 * u_ratio[-1] < r < 1.02 + 3 * u_ratio[-1], (mu_a, b, bs, u, us)
    assert abs(ratio[1] - ratio[0]) < 3 * math.hypot(*u_ratio), (ratio, u_ratio)


FELT = """
seed = 2
[fiber]
radius_um = 10.0
n_host = 1.5
[medium]
mu_s = 0.8
mu_a = 0.01
g = 0.5
[surface]
rms_slope = 0.35
[structure]
kind = "nonwoven"
felt_spread_deg = 15
layers = 4
"""

PLAN = """
[sample]
name = "tiny"
[wavelengths]
list_nm = [550]
[geometry]
incidence_deg = [0]
in_plane_deg = [10, 40]
"""


def test_simulate_fabric_mc_runs_a_felt_config(tmp_path, capsys):
    cfg = tmp_path / "felt.toml"
    cfg.write_text(FELT)
    plan = tmp_path / "tiny.toml"
    plan.write_text(PLAN)
    out = tmp_path / "felt-mc"
    assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(out),
                 "--target-rel-err", "0.1", "--no-progress"]) == 0
    capsys.readouterr()
    ds = read_dataset(out)
    assert len(ds.table) == 2 and np.all(np.isfinite(ds.table["beta"])) and np.all(ds.table["beta"] > 0)
    felt = ds.meta["model"]["felt"]
    assert felt["layers"] == 4 and abs(felt["spread_deg"] - 15.0) < 1e-9 and felt["seed"] == 2 and "weave" not in ds.meta["model"]
    from simulate.config import DEFAULT_FELT_REALISATIONS

    assert ds.meta["provenance"]["fiber_info"]["realisations"] == DEFAULT_FELT_REALISATIONS


def test_a_config_with_two_realisations_traces_the_two_felts_of_its_seed(tmp_path, capsys):
    """``[method] felt_realisations = 2``: the run is ``fabric_beta`` on the felts of the run's seed and of the seed plus
    the stride, one per table half (the estimator of a run with one realisation per half), value for value."""
    from simulate.config import load_config
    from simulate.products import FELT_SEED_STRIDE

    cfg = tmp_path / "felt.toml"
    cfg.write_text(FELT + "[method]\nfelt_realisations = 2\n")
    plan = tmp_path / "tiny.toml"
    plan.write_text(PLAN)
    out = tmp_path / "felt-mc"
    assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(out),
                 "--target-rel-err", "0.2", "--no-progress", "--threads", "1"]) == 0
    capsys.readouterr()
    ds = read_dataset(out)
    c = load_config(cfg)
    wl = np.array([550.0])
    fib = c.fiber(wl)
    meshes = (felt_mesh(c.structure, 10.0, seed=2), felt_mesh(c.structure, 10.0, seed=2 + FELT_SEED_STRIDE))
    t = ds.table.sort_values("theta_o")
    w_i = fab.directions_deg(t["theta_i"].to_numpy(float), t["phi_i"].to_numpy(float))
    w_o = fab.directions_deg(t["theta_o"].to_numpy(float), t["phi_o"].to_numpy(float))
    # the fiber is turbid (2 R mu_s = 16): the run's exit bins are fabric_beta's default, (5, 10)
    beta, u, info = W.fabric_beta(meshes, fib, w_i, w_o, wl, target_rel_err=0.2, seed=2, threads=1, structure=c.structure)
    assert info["realisations"] == 2
    np.testing.assert_allclose(t["beta"].to_numpy(float), beta[:, 0], rtol=1e-9)
    np.testing.assert_allclose(t["u_beta"].to_numpy(float), u[:, 0], rtol=1e-9)


def test_a_bad_realisation_count_is_one_line_and_exit_2(tmp_path, capsys):
    cfg = tmp_path / "felt.toml"
    cfg.write_text(FELT + "[method]\nfelt_realisations = 5\n")
    plan = tmp_path / "tiny.toml"
    plan.write_text(PLAN)
    assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(tmp_path / "o"),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "felt.toml: method.felt_realisations must be an even integer" in err and "\n" not in err
    assert not (tmp_path / "o").exists()


def _tiny_felt_case(target: float):
    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0, layers=4)
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.35, 10.0)
    t_i = np.array([0.0, 0.0, 0.0, 0.0, 45.0, 45.0, 45.0, 45.0])
    t_o = np.array([10.0, 40.0, 25.0, 60.0, 10.0, 40.0, 30.0, 60.0])
    p_o = np.array([0.0, 0.0, 180.0, 180.0, 0.0, 0.0, 180.0, 180.0])
    w_i, w_o = fab.directions_deg(t_i, np.zeros(8)), fab.directions_deg(t_o, p_o)
    wl = np.array([550.0])
    tables = W.table_halves(fib, wl, W.table_photons(target) // 2, 0, 1)
    return spec, fib, w_i, w_o, wl, tables


def test_each_table_half_is_traced_on_its_own_realisation_of_the_felt():
    """``fabric_beta((a, b))`` traces half A on felt ``a`` and half B on ``b`` (same streams), so swapping
    the realisations and adding gives exactly the two single-realisation runs added."""
    spec, fib, w_i, w_o, wl, tables = _tiny_felt_case(0.2)
    a, b = felt_mesh(spec, 10.0, seed=0), felt_mesh(spec, 10.0, seed=1)

    def run(meshes):
        beta, _, info = W.fabric_beta(meshes, fib, w_i[:2], w_o[:2], wl, target_rel_err=0.2, seed=0, threads=1,
                                      tables=tables, structure=spec)
        return beta, info

    ab, info = run((a, b))
    ba, _ = run((b, a))
    aa, _ = run(a)
    bb, _ = run((b, b))
    assert info["rotations"] == W.FELT_ROTATIONS and info["realisations"] == 2
    np.testing.assert_allclose(ab + ba, aa + bb, rtol=1e-12)
    assert not np.allclose(ab, aa, rtol=1e-3)        # the second half did see the other felt


def _per_realisation(record: dict, tables) -> list[list]:
    """Each incidence's result on each realisation, from the run's record: realisation ``j``'s rays replayed with
    table half ``j mod 2`` (the traced table gives the traced result to rounding), its rotations averaged."""
    from simulate.raytrace.reweight import replay

    rows = [t.T.reshape(-1, t.T.shape[-1]) for t in tables]
    return [[W.estimate.mean_of(replay(log, rows[j % 2])) for j, log in enumerate(inc["realisations"])]
            for inc in record["incidences"]]


def test_four_realisations_report_the_batch_means_error():
    """K = 4 felts: ``beta`` is the realisations' mean and ``u_beta`` the batch means' error, computed here from
    each realisation's own result: the spread of the realisations about their table half's mean over
    ``K (K - 2)``, plus the table's part the halves' means differ by beyond it."""
    spec, fib, w_i, w_o, wl, tables = _tiny_felt_case(0.2)
    w_i, w_o = w_i[:4], w_o[:4]
    wl2 = np.array([500.0, 600.0])
    tables = W.table_halves(fib, wl2, W.table_photons(0.2) // 2, 0, 1)
    meshes = tuple(felt_mesh(spec, 10.0, seed=s) for s in range(4))
    record: dict = {}
    beta, u, info = W.fabric_beta(meshes, fib, w_i, w_o, wl2, target_rel_err=0.2, seed=0, threads=1, tables=tables,
                                  structure=spec, record=record)
    assert info["realisations"] == 4
    for inc, res in zip(record["incidences"], _per_realisation(record, tables), strict=True):
        x = np.array([r.beta for r in res])                         # [K, D, L]
        a, b = x[[0, 2]].mean(axis=0), x[[1, 3]].mean(axis=0)
        s2 = (np.sum((x[[0, 2]] - a) ** 2, axis=0) + np.sum((x[[1, 3]] - b) ** 2, axis=0)) / 2.0
        table2 = np.maximum(np.mean((a - b) ** 2 / 4.0 - s2 / 4.0, axis=1, keepdims=True), 0.0)
        expect_u = np.sqrt(s2 / 4.0 + table2)
        rows, det_inv = inc["rows"], inc["det_inv"]
        np.testing.assert_allclose(beta[rows], x.mean(axis=0)[det_inv], rtol=1e-12)
        np.testing.assert_allclose(u[rows], expect_u[det_inv], rtol=1e-9)
        assert np.all(s2 > 0.0)       # the realisations differ: the error is their spread, not zero


def test_two_realisations_keep_the_halves_estimator():
    """K = 2 (the default): ``u_beta^2`` is the two traces' ray errors over 4 plus the halves' difference pooled over
    the wavelengths, the estimator of a run with one realisation per table half, from each one's own result."""
    spec, fib, w_i, w_o, wl, _ = _tiny_felt_case(0.2)
    wl2 = np.array([500.0, 600.0])
    tables = W.table_halves(fib, wl2, W.table_photons(0.2) // 2, 0, 1)
    meshes = (felt_mesh(spec, 10.0, seed=0), felt_mesh(spec, 10.0, seed=1))
    record: dict = {}
    beta, u, _ = W.fabric_beta(meshes, fib, w_i[:2], w_o[:2], wl2, target_rel_err=0.2, seed=0, threads=1,
                               tables=tables, structure=spec, record=record)
    for inc, (ra, rb) in zip(record["incidences"], _per_realisation(record, tables), strict=True):
        u_table2 = np.mean(((ra.beta - rb.beta) / 2.0) ** 2, axis=1, keepdims=True)
        expect_u = np.sqrt((ra.u_beta ** 2 + rb.u_beta ** 2) / 4.0 + u_table2)
        rows, det_inv = inc["rows"], inc["det_inv"]
        np.testing.assert_allclose(beta[rows], ((ra.beta + rb.beta) / 2.0)[det_inv], rtol=1e-12)
        np.testing.assert_allclose(u[rows], expect_u[det_inv], rtol=1e-9)


def test_an_odd_number_of_realisations_is_refused():
    spec, fib, w_i, w_o, wl, tables = _tiny_felt_case(0.2)
    meshes = tuple(felt_mesh(spec, 10.0, seed=s) for s in range(3))
    with pytest.raises(ValueError, match="even number"):
        W.fabric_beta(meshes, fib, w_i[:1], w_o[:1], wl, target_rel_err=0.2, seed=0, threads=1, tables=tables,
                      structure=spec)


@pytest.mark.slow
def test_the_felts_u_beta_holds_the_spread_between_realisations():
    """Four felts (seeds) at fixed tables: the variance of beta between them is what u_beta says, not
    ~12 times it (one realisation traced at one azimuth, with
    the rays' and the table's error only)."""
    spec, fib, w_i, w_o, wl, tables = _tiny_felt_case(0.015)
    runs = []
    for s in range(4):
        meshes = (felt_mesh(spec, 10.0, seed=s), felt_mesh(spec, 10.0, seed=s + 1000))
        beta, u, _ = W.fabric_beta(meshes, fib, w_i, w_o, wl, target_rel_err=0.015, seed=0, threads=1,
                                   tables=tables, structure=spec)
        runs.append((beta[:, 0], u[:, 0]))
    b = np.array([r[0] for r in runs])
    u = np.array([r[1] for r in runs])
    ratio = float(np.mean(b.var(axis=0, ddof=1)) / np.mean(u ** 2))
    # 8 points x 3 degrees of freedom: the ratio's sampling spread is ~+-0.5 around 1
    assert 0.3 < ratio < 3.5, ratio


def test_a_weave_is_traced_once_per_half_at_its_own_azimuth():
    """Turning the directions is for the in-plane isotropic felt only: a weave's ``fabric_beta`` is the
    mean of its two halves' plain traces (not turned, same streams)."""
    from simulate.geometry.mesh import mesh as weave_mesh
    from simulate.geometry.weave import preset
    from simulate.raytrace.materials import FiberSurface

    _, fib, w_i, w_o, wl, tables = _tiny_felt_case(0.2)
    wv = preset("plain", spacing_um=300.0, width_um=250.0, height_um=100.0, points_per_span=6, sides=12)
    m = weave_mesh(wv)
    beta, _, info = W.fabric_beta(m, fib, w_i[:2], w_o[:2], wl, target_rel_err=0.2, seed=5, threads=1, tables=tables)
    assert info["rotations"] == 1 and info["realisations"] == 1
    target = W.estimate.ray_target(0.2)
    halves = [W.trace(m, FiberSurface(t, float(fib.roughness), float(fib.n_host), "tube", 1.0), w_i[0], w_o[:2],
                      target_rel_err=target, seed=5, threads=1) for t in tables]
    # (to the rounding of the directions, which fabric_beta keys to 9 digits)
    np.testing.assert_allclose(beta, 0.5 * (halves[0].beta + halves[1].beta), rtol=1e-8)
