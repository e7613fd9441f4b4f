"""The felt residual decomposition (docs/scripts/felt_residual.py): its arithmetic on made-up curves (no Monte
Carlo), its variant configs and its refusal of bad input."""

from __future__ import annotations

import importlib.util
import math
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from compare.metrics import curve_error

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("felt_residual", ROOT / "docs" / "scripts" / "felt_residual.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["felt_residual"] = module
    spec.loader.exec_module(module)
    return module


def _frame() -> pd.DataFrame:
    """Two incidences, in-plane points at s = -60..70 and two ring points at 30 deg, two bands; the model is the
    file plus a residual that differs by region so that each region's share is known."""
    rows = []
    for theta_i in (0.0, 30.0):
        for s in (-60.0, -30.0, -10.0, 10.0, 30.0, 70.0):
            rows.append((theta_i, 0.0, abs(s), 0.0 if s < 0 else 180.0, s))   # phi_o = phi_i: the source's side
        if theta_i:
            # the source direction turned by 6 and by 30 deg about the normal's azimuth: out of plane
            for dist in (6.0, 30.0):
                rows.append((theta_i, 0.0, theta_i, 2 * math.degrees(math.asin(
                    math.sin(math.radians(dist / 2)) / math.sin(math.radians(theta_i)))), math.nan))
    out = []
    for theta_i, phi_i, theta_o, phi_o, s in rows:
        for band, level in ((500.0, 1.0), (600.0, 2.0)):
            out.append(dict(theta_i=theta_i, phi_i=phi_i, theta_o=theta_o, phi_o=phi_o, s=s, wavelength_nm=band,
                            beta_meas=level, u_sim=0.01))
    f = pd.DataFrame(out)
    s = f["s"].to_numpy()
    resid = np.where(np.isnan(s), -0.2, np.where(s < -20, 0.1, np.where(s > 20, 0.3, 0.0)))
    f["beta_sim"] = f["beta_meas"] + resid
    return f


def test_regions_follow_the_signed_angle_and_the_ring_distance():
    fr = _script()
    f = _frame()
    reg = fr.region(f, near_deg=20.0)
    s = f["s"].to_numpy()
    assert set(reg[s < -20]) == {"back"}
    assert set(reg[np.abs(s) <= 20]) == {"near"}
    assert set(reg[(s > 20) & (s <= 70)]) == {"forward"}
    ring = f[np.isnan(s)]
    assert list(reg[np.isnan(s)]) == ["ring-6", "ring-6", "ring-30", "ring-30"]
    np.testing.assert_allclose(fr.retro_distance_deg(ring), [6, 6, 30, 30], atol=1e-9)
    # grazing: beyond 70 deg in plane
    g = f.iloc[:1].assign(theta_o=75.0, s=-75.0)
    assert list(fr.region(g)) == ["grazing"]


def test_contributions_add_up_to_the_compare_nrmse_squared():
    fr = _script()
    f = _frame()
    res = fr.decompose_frame(f)
    assert res["nrmse"] == pytest.approx(curve_error(f).nrmse, rel=1e-12)
    m = f["beta_meas"].mean()
    n = len(f)
    for part in ("by_incidence", "by_region", "by_band", "by_plane", "by_incidence_region"):
        kept = [v for v in res[part].values() if v["n"]]
        assert sum(v["n"] for v in kept) == n
        assert sum(v["contribution"] for v in kept) == pytest.approx(res["nrmse"] ** 2, rel=1e-12)
        assert sum(v["share"] for v in kept) == pytest.approx(1.0, rel=1e-12)
    fwd = res["by_region"]["forward"]
    n_fwd = int(((f["s"] > 20)).sum())
    assert fwd["n"] == n_fwd
    assert fwd["contribution"] == pytest.approx(n_fwd * 0.09 / (n * m * m))
    assert fwd["bias_rel"] == pytest.approx(0.3 / m)
    assert fwd["rms_rel"] == pytest.approx(0.3 / m)
    assert fwd["nrmse_own"] == pytest.approx(0.3 / 1.5)
    assert res["by_region"]["ring-6"]["bias_rel"] == pytest.approx(-0.2 / m)
    assert res["by_region"]["near"]["contribution"] == 0.0
    assert res["by_region"]["grazing"] == {"n": 0}
    # matched exactly, the forward points leave the rest's error
    rest = f[~(f["s"] > 20)]
    d = (rest["beta_sim"] - rest["beta_meas"]).to_numpy()
    assert fwd["nrmse_without"] == pytest.approx(math.sqrt(np.sum(d * d) / n) / m)
    assert res["nrmse_noise_u"] == pytest.approx(0.01 / m)


def test_best_scale_and_forward_rise_on_made_up_curves():
    fr = _script()
    f = _frame()
    f["beta_sim"] = 3.0 * f["beta_meas"] * (1.0 + 0.5 * (f["wavelength_nm"] == 600.0))
    assert fr.best_scale_nrmse(f) == pytest.approx(0.0, abs=1e-12)
    f.loc[(f["s"] == 70.0), "beta_sim"] *= 2.0
    rise = fr.forward_rise(f)
    assert set(rise) == {"0", "30"}
    assert rise["30"]["measured"] == pytest.approx(1.0)
    assert rise["30"]["simulated"] == pytest.approx(2.0)
    assert fr.best_scale_nrmse(f) > 0.1
    prof = fr.profile(f)
    assert prof["30"]["70"] == pytest.approx(2.0 * (3.0 + 9.0) / 3.0)
    assert prof["30"]["-30"] == pytest.approx((3.0 + 9.0) / 3.0)
    assert set(prof["0"]) == {"-60", "-30", "-10", "10", "30", "70"}


def test_seed_noise_is_the_half_mean_square_difference():
    fr = _script()
    a = _frame()
    b = a.copy()
    b["beta_sim"] = a["beta_sim"] + np.where(np.arange(len(a)) % 2, 0.04, -0.04)
    got = fr.seed_noise(a, b)
    assert got["nrmse_seeds"] == pytest.approx(math.sqrt(0.04 ** 2 / 2) / a["beta_meas"].mean())
    with pytest.raises(fr.InputError, match="same points"):
        fr.seed_noise(a, b.iloc[:-1])


def test_combine_finds_the_minimum_of_additive_quadratic_responses():
    fr = _script()
    r0 = np.array([1.0, -1.0, 0.5, 0.2])
    # field a: r = r0 (1 - h), zero at h = 1 (scanned at -0.5 and 2); field b: r = r0 + (h^2 - 2h) e, with e
    # along the first point only, least at h = 1 (scanned at 0.5 and 3), where it lowers the first point by e
    e = np.array([0.3, 0.0, 0.0, 0.0])
    fields = [("a", 0.0, -0.5, r0 * 1.5, 2.0, -r0),
              ("b", 1.0, 1.5, r0 + (0.25 - 1.0) * e, 4.0, r0 + (9.0 - 6.0) * e)]
    values, predicted = fr.combine(r0, fields)
    assert values[0] == pytest.approx(1.0, abs=1e-4)
    # with a at its zero, b leaves (h^2 - 2h) e: zero at h = 0 or 2 (the values 1.0 and 3.0)
    assert min(abs(values[1] - 1.0), abs(values[1] - 3.0)) < 1e-2
    assert predicted == pytest.approx(0.0, abs=1e-3)
    # alone, b's optimum is its vertex h = 1, within its range
    values_b, predicted_b = fr.combine(r0, fields[1:])
    assert values_b[0] == pytest.approx(2.0, abs=1e-3)
    assert predicted_b == pytest.approx(math.sqrt(np.mean((r0 - e) ** 2)), rel=1e-4)


def test_variants_change_their_fields_only(tmp_path):
    fr = _script()
    paths = fr.write_variants(fr.PRESET, tmp_path)
    base = tomllib.loads(fr.PRESET.read_text())
    assert len(paths) == len(fr.VARIANTS) + len(fr.JOINT_VARIANTS)
    changes = [(name, section, {key: value}) for name, section, key, value in fr.VARIANTS] + list(fr.JOINT_VARIANTS)
    assert any(len(fields) > 1 for _, _, fields in changes)
    for (name, section, fields), path in zip(changes, paths, strict=True):
        got = tomllib.loads(path.read_text())
        assert got["name"] == name
        for key, value in fields.items():
            assert got[section][key] == value
            got[section].pop(key)
        want = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
        want[section] = {k: v for k, v in base[section].items() if k not in fields}
        want["name"] = name
        assert got == want
    with pytest.raises(fr.InputError, match="no \\[weave\\] section"):
        fr.set_field("[fiber]\nradius_um = 1.0\n", "weave", "kind", "plain")


def _lambertian(out: Path, rho: float) -> None:
    """A Lambertian dataset (beta = rho) in plane at incidence 0 and 30 deg, s = -40..40, three wavelengths."""
    from gonio.data import Dataset
    from gonio.data.dataset import write_dataset
    rows = [dict(theta_i=ti, phi_i=0.0, theta_o=float(abs(s)), phi_o=0.0 if s < 0 else 180.0, wavelength_nm=wl,
                 beta=rho, u_beta=0.0, n=1)
            for ti in (0.0, 30.0) for s in range(-40, 41, 10) if s != 0 for wl in (500.0, 550.0, 600.0)]
    meta = {"schema": "radiance-dataset/1", "kind": "measured", "sample": {"name": out.name},
            "wavelengths_nm": [500.0, 550.0, 600.0], "created": "2020-01-01T00:00:00+00:00"}
    write_dataset(Dataset(pd.DataFrame(rows), meta), out)


def _run(capsys, fr, argv):
    code = fr.main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    fr = _script()
    code, _, err = _run(capsys, fr, ["decompose", str(tmp_path / "nothing"), str(tmp_path / "run")])
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "nothing" in err and "not a dataset" in err and "Traceback" not in err
    fr.write_variants(fr.PRESET, tmp_path / "v")
    code, _, err = _run(capsys, fr, ["variants", "--out", str(tmp_path / "v")])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--force" in err

    for name, rho in (("file", 0.5), ("run", 0.4)):
        _lambertian(tmp_path / name, rho)
    capsys.readouterr()
    code, out, err = _run(capsys, fr, ["decompose", str(tmp_path / "file"), str(tmp_path / "run"),
                                       "--max-incidence", "-1"])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--max-incidence -1" in err
    code, out, err = _run(capsys, fr, ["decompose", str(tmp_path / "file"), str(tmp_path / "run"),
                                       "--json", str(tmp_path / "r.json")])
    assert code == 0, err
    # a Lambertian model of another albedo is the file after the normalisation: no error anywhere
    import json
    res = json.loads((tmp_path / "r.json").read_text())["runs"][str(tmp_path / "run")]
    assert res["nrmse"] == pytest.approx(0.0, abs=1e-12)
    assert set(res["by_incidence"]) == {"0", "30"}


def test_wavelength_thirds_split_the_error_and_the_forward_rise():
    fr = _script()
    assert list(fr.band_group(np.array([390.0, 500.0, 510.0, 580.0, 590.0, 710.0, 720.0]))) == [
        "390-500 nm", "390-500 nm", "510-580 nm", "510-580 nm", "590-710 nm", "590-710 nm", "other"]
    f = _frame()
    red = (f["wavelength_nm"] == 600.0).to_numpy()
    # the red band's residual twice the blue one's: four times its part of NRMSE^2
    f.loc[red, "beta_sim"] = f.loc[red, "beta_meas"] + 2.0 * (f.loc[~red, "beta_sim"].to_numpy() - f.loc[~red, "beta_meas"].to_numpy())
    f.loc[red & (f["s"] == 70.0).to_numpy(), "beta_sim"] *= 1.5
    res = fr.decompose_frame(f)
    groups = res["by_band_group"]
    assert list(groups) == ["390-500 nm", "510-580 nm", "590-710 nm"]
    assert groups["510-580 nm"] == {"n": 0}
    assert groups["390-500 nm"]["contribution"] + groups["590-710 nm"]["contribution"] == pytest.approx(res["nrmse"] ** 2)
    cross = [v for v in res["by_band_group_region"].values() if v["n"]]
    assert sum(v["contribution"] for v in cross) == pytest.approx(res["nrmse"] ** 2, rel=1e-12)
    blue_fwd = res["by_band_group_region"]["390-500 nm|forward"]
    assert blue_fwd["bias_rel"] == pytest.approx(0.3 / f["beta_meas"].mean())
    # the red forward residual at s = 70 is larger than four times the blue one's: its part more than four times
    assert res["by_band_group_region"]["590-710 nm|forward"]["contribution"] > 4.0 * blue_fwd["contribution"]
    assert res["by_band_group_region"]["590-710 nm|back"]["contribution"] == pytest.approx(
        4.0 * res["by_band_group_region"]["390-500 nm|back"]["contribution"])
    rise = res["forward_rise_by_band_group"]
    assert rise["590-710 nm"] == fr.forward_rise(f[red])
    # blue: file 1 -> 1 and model 1.3 -> 1.3 (rise 1); red: file 2 -> 2, model (2 + 0.6) -> (2 + 0.6) * 1.5
    assert rise["390-500 nm"]["30"]["simulated"] == pytest.approx(1.0)
    assert rise["590-710 nm"]["30"]["simulated"] == pytest.approx(1.5)
    assert rise["590-710 nm"]["30"]["measured"] == pytest.approx(1.0)


def test_permute_reorders_the_rgb_channels_and_keeps_the_rest(tmp_path, capsys):
    from gonio.data.formats.tensor import parse_tensor_bytes
    fr = _script()
    src = ROOT / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
    out = tmp_path / "felt_gbr.bsdf"
    code, _, err = _run(capsys, fr, ["permute", str(src), "--order", "gbr", "--out", str(out)])
    assert code == 0, err
    old, new = parse_tensor_bytes(src.read_bytes()), parse_tensor_bytes(out.read_bytes())
    assert set(old) == set(new)
    for k in old:
        if k != "rgb":
            np.testing.assert_array_equal(new[k], old[k])
    # new R, G, B = old G, B, R
    for new_c, old_c in ((0, 1), (1, 2), (2, 0)):
        np.testing.assert_array_equal(new["rgb"][:, :, new_c], old["rgb"][:, :, old_c])
    assert not np.array_equal(new["rgb"], old["rgb"])
    for argv, words in ((["permute", str(src), "--order", "gbr", "--out", str(out)], "--force"),
                        (["permute", str(src), "--order", "ggb", "--out", str(tmp_path / "x.bsdf")], "--order ggb"),
                        (["permute", str(tmp_path / "none.bsdf"), "--order", "gbr", "--out", str(tmp_path / "y.bsdf")],
                         "none.bsdf")):
        code, _, err = _run(capsys, fr, argv)
        assert code == 2 and len(err.strip().splitlines()) == 1 and words in err and "Traceback" not in err


def test_top_profile_measures_the_loose_top():
    """Above the compact felt's top lie only the loose fibres, none overlapping: the profile over that layer is
    their volume (capsules of the axis pieces: the tube and its two end caps) over the layer's, within 4 SE."""
    from simulate.fabric import structure as ST
    from simulate.geometry.felt import felt_mesh

    fr = _script()
    R = 10.0
    m = felt_mesh(ST.StructureSpec(kind="nonwoven", layers=4, felt_spread_deg=10.0, felt_fuzz_fraction=0.3,
                                   felt_fuzz_depth_um=400.0), R, seed=5)
    H = -m.info["compact_top_um"]
    n = 20000
    (got,) = fr.top_profile(m, H, H, n=n)
    ell, L = m.info["fiber_length_um"], m.info["cell_um"]
    want = m.info["fuzz_fibers"] * (math.pi * R * R * ell + 4.0 / 3.0 * math.pi * R ** 3) / (L * L * H)
    assert 0.01 < want < 0.2
    assert abs(got - want) < 4.0 * math.sqrt(want * (1.0 - want) / n)
    # and the compact felt below is denser than the loose top
    deep = fr.top_profile(m, 50.0, H + 300.0, n=4000)[-2:]
    assert np.all(deep > 2.0 * want)


def test_lambert_rise_of_a_flat_lambertian_plane_is_one():
    """A flat Lambertian plane scatters once, beta = albedo / pi in every direction: the rise is 1 at every
    incidence, all orders and single, for every albedo."""
    from simulate.geometry.validation import flat_mesh

    fr = _script()
    rise = fr.lambert_rise(flat_mesh(), [0.3, 0.9], target_rel_err=0.02, rotations=2)
    assert set(rise) == {f"{k} {t:g}" for k in ("all", "single") for t in fr.RISE_INCIDENCES}
    for v in rise.values():
        for r, e in zip(v["ratio"], v["se"], strict=True):
            assert 0.0 < e < 0.05 and abs(r - 1.0) < 4.0 * e


@pytest.mark.parametrize("argv,needle", [(["top", "no-such-config"], "no-such-config"),
                                         (["top", "red-cotton"], "not a felt"),
                                         (["lambert", "green-felt-mc", "--albedo", "0,1"], "--albedo"),
                                         (["top", "green-felt-mc", "--seeds", "0"], "--seeds")])
def test_the_geometry_commands_refuse_bad_input_in_one_line(capsys, argv, needle):
    fr = _script()
    assert fr.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]


# ---------------------------------------------------------------------------------------------- the fibre's phase

def _lambert_cell_sum(view_deg: float, alpha: float, n_psi: int = 2000, incidence_deg: float = 0.0) -> float:
    """An opaque Lambertian fibre of radius 1 and albedo 1 lying in the felt's plane, its axis at ``alpha`` from the
    plane of incidence, lit from ``incidence_deg`` on the -x side, seen at ``view_deg`` in that plane: ``S`` by the cell sum of
    ``(1/pi) (w_i . n)_+ (w_o . n)_+ dpsi`` over the fibre's surface normals, in the felt's own frame."""
    t = np.array([math.cos(alpha), math.sin(alpha), 0.0])
    z = np.array([0.0, 0.0, 1.0])
    side = np.cross(z, t)
    psi = (np.arange(n_psi) + 0.5) * 2.0 * math.pi / n_psi
    normals = np.cos(psi)[:, None] * z + np.sin(psi)[:, None] * side
    th = math.radians(view_deg)
    w_o = np.array([math.sin(th), 0.0, math.cos(th)])
    ti = math.radians(incidence_deg)
    w_i = np.array([-math.sin(ti), 0.0, math.cos(ti)])
    lit = np.clip(normals @ w_i, 0.0, None) * np.clip(normals @ w_o, 0.0, None)
    return float(lit.sum() * 2.0 * math.pi / n_psi / math.pi)


def test_lambert_phase_is_the_cell_sum_averaged_over_the_axis_azimuths():
    """The script's frame (felt_views) and closed form (lambert_far_field), averaged over its axis azimuths, against
    the cell sum in the felt's frame averaged by the trapezoid rule on another azimuth grid: the curve and
    p(110)/p(150)."""
    fr = _script()
    lam = fr.lambert_phase(azimuths=144)
    views = list(fr.PHASE_VIEWS_DEG)
    alpha = np.linspace(0.0, 2.0 * math.pi, 241)

    def mean_over_alpha(view: float) -> float:
        return float(np.trapezoid([_lambert_cell_sum(view, a) for a in alpha], alpha) / (2.0 * math.pi))

    want = {v: mean_over_alpha(v) for v in (0.0, 30.0, -50.0, 70.0)}
    for view, w in want.items():
        assert abs(lam["curve"][views.index(view)] - w) < 2e-3 * w
    assert abs(lam["ratio"] - want[70.0] / want[30.0]) < 2e-3
    # all the light an opaque white fibre intercepts leaves it: the sphere integral of S is 2 R
    assert lam["albedo"] == pytest.approx(1.0, abs=2e-3)
    assert 0.5 < lam["upper_share"] < 1.0


def test_extinction_factor_is_the_mean_projected_width():
    fr = _script()
    assert fr.extinction_factor(0.0) == pytest.approx(0.5)
    assert fr.extinction_factor(0.0, plane=False) == pytest.approx(0.5)
    alpha = (np.arange(100_000) + 0.5) * 2.0 * math.pi / 100_000
    for view in (30.0, 70.0):
        th = math.radians(view)
        b = float(np.mean(np.sqrt(1.0 - (math.sin(th) * np.cos(alpha)) ** 2)))
        assert fr.extinction_factor(view) == pytest.approx(1.0 / (math.cos(th) + b), rel=1e-6)
        assert fr.extinction_factor(view, plane=False) == pytest.approx(1.0 / (math.cos(th) + 1.0))


def test_a_clear_fibre_s_phase_conserves_its_light():
    """A non-absorbing, non-scattering smooth fibre: all the light that reaches it leaves it, so its volume albedo
    (the exit tables, light entering through 1 - F) and its surface albedo (the Cook-Torrance term integrated over
    the sphere) add up to 1; the ratio's error comes from the tables' spread, the shares lie in (0, 1)."""
    from simulate.fiber import Fiber
    from simulate.media.medium import HGMedium

    fr = _script()
    fiber = Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=0.0, mu_a=0.0, g=0.0), roughness=0.3,
                  cell_width_deg=20)
    res = fr.fibre_phase(fiber, [550.0], photons_per_row=300, tables=2, azimuths=8, views_deg=(-70, -30, 0, 30, 70),
                         sphere=(40, 80))
    band = res["bands"]["all"]
    assert band["volume_albedo"] + res["surface_albedo"] == pytest.approx(1.0, abs=0.02)
    assert 0.02 < res["surface_albedo"] < 0.08          # Fresnel at n 1.5 over the lit half: about 4-5 %
    assert 0.0 < band["upper_share"] < 1.0 and band["se"] >= 0.0
    assert band["ratio"] == pytest.approx(band["curve"][4] / band["curve"][3], rel=1e-9)


def test_oblique_phase_of_a_clear_fibre_and_its_lambertian_reference():
    """At oblique beams the Lambertian reference is the cell sum averaged over the axis azimuths (trapezoid rule on
    another grid); the clear fibre's ratio is positive with a standard error from its tables, and at a nearly
    normal beam it is the normal-incidence ratio within the tables' errors."""
    from simulate.fiber import Fiber
    from simulate.media.medium import HGMedium

    fr = _script()
    fiber = Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=0.05, mu_a=0.01, g=0.0), roughness=0.3,
                  cell_width_deg=20)
    res = fr.oblique_phase(fiber, [550.0], [0.5, 45.0], photons_per_row=400, tables=3, azimuths=24,
                           w_t_nodes=(0.0, 0.5, 0.9))
    alpha = np.linspace(0.0, 2.0 * math.pi, 181)
    for t, got in zip((0.5, 45.0), res["lambert"], strict=True):
        hi, lo = (np.trapezoid([_lambert_cell_sum(v, a, 1000, t) for a in alpha], alpha) for v in (70.0, 30.0))
        assert got == pytest.approx(hi / lo, rel=3e-3)
    band = res["bands"]["all"]
    assert all(r > 0.0 and e > 0.0 for r, e in zip(band["ratio"], band["se"], strict=True))
    normal = fr.fibre_phase(fiber, [550.0], photons_per_row=400, tables=3, azimuths=24, sphere=(8, 16))["bands"]["all"]
    assert abs(band["ratio"][0] - normal["ratio"]) < 4.0 * math.hypot(band["se"][0], normal["se"]) + 0.01


@pytest.mark.parametrize("argv,needle", [(["phase", "--tables", "1"], "--tables"),
                                         (["phase", "--oblique", "0,30"], "--oblique"),
                                         (["phase", "--felt-target", "0"], "--felt-target"),
                                         (["phase", "--oblique", "30", "--oblique-of", "nope", "--photons", "50",
                                           "--tables", "2", "--azimuths", "4"], "nope"),
                                         (["phase", "no-such-config"], "no-such-config"),
                                         (["phase", "red-cotton", "--felt"], "not a felt")])
def test_phase_refuses_bad_input_in_one_line(capsys, argv, needle):
    fr = _script()
    assert fr.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]


def _blend_screen():
    spec = importlib.util.spec_from_file_location("felt_blend_screen", ROOT / "docs" / "scripts" / "felt_blend_screen.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["felt_blend_screen"] = module
    spec.loader.exec_module(module)
    return module


def test_the_blend_screen_reads_made_up_rings_and_mixes_two_populations_by_share():
    """Rings made up so that each figure is known: ratio = ring_6 / ring_30 per band, the red excess per seed, the
    peak's and the body's R/G; the 50/50 mix of two variants is the mean of their rings seed by seed."""
    m = _blend_screen()

    def run(seed: int, r6: list[float], r30: list[float]) -> dict:
        inc = {"ring_6": r6, "ring_30": r30}
        return {"seed": seed, "orders": {o: {"incidences": {"27.76": inc, "40.03": inc}} for o in ("single", "all")}}

    a = [run(0, [1.0, 1.2, 0.66], [1.0, 1.0, 0.5]), run(1, [1.0, 1.2, 0.63], [1.0, 1.0, 0.5])]
    b = [run(0, [1.0, 1.0, 0.2], [1.0, 0.8, 0.2]), run(1, [1.0, 1.0, 0.2], [1.0, 0.8, 0.2])]
    file = {"ring_6": [1.0, 1.1, 0.6], "ring_30": [1.0, 1.0, 0.5]}
    scan = {"data": {"settings": {}, "file": {"incidences": {"27.76": file, "40.03": file}},
                     "variants": [{"name": "red-clear", "label": "a", "runs": a},
                                  {"name": "red-x10", "label": "b", "runs": b}]}}
    rows = m.screen(scan)["rows"]
    f = rows["the file"]["all"]["27.76"]
    assert f["ratio_550"] == pytest.approx(1.1) and f["ratio_650"] == pytest.approx(1.2)
    assert f["red_excess"] == pytest.approx(0.1) and f["u_red_excess"] is None
    assert f["peak_rg"] == pytest.approx(0.1 / 0.1) and f["body_rg"] == pytest.approx(0.5)
    x = rows["red-clear"]["all"]["40.03"]
    # per seed: 0.66/0.5 - 1.2 = 0.12 and 0.63/0.5 - 1.2 = 0.06
    assert x["red_excess"] == pytest.approx(0.09) and x["u_red_excess"] == pytest.approx(0.03)
    assert x["ratio_650"] == pytest.approx(0.645 / 0.5)
    mix = rows["mix-red-clear-red-x10"]["single"]["27.76"]
    assert mix["ratio_550"] == pytest.approx(1.1 / 0.9) and mix["body_rg"] == pytest.approx(0.35 / 0.9)
    assert rows["mix-red-clear-red-x10"]["seeds"] == 2


def test_retro_reads_the_ring_ratio_of_a_dataset_at_550_and_650_nm(tmp_path):
    """A dataset whose ring at 6 deg is 1.2 (550 nm) and 1.3 (650 nm) times its ring at 30 deg: `retro` gives those."""
    from compare.ratios import ring_directions
    from gonio.data import Dataset
    from gonio.data.dataset import write_dataset

    rows = []
    for rho, scale in ((6.0, {550.0: 1.2, 650.0: 1.3}), (30.0, {550.0: 1.0, 650.0: 1.0})):
        for t, p in ring_directions(40.0, rho, 8):
            for wl, v in scale.items():
                rows.append(dict(theta_i=40.0, phi_i=0.0, theta_o=t, phi_o=p, wavelength_nm=wl, beta=0.1 * v,
                                 u_beta=0.001, n=1))
    out = tmp_path / "run"
    meta = {"schema": "radiance-dataset/1", "kind": "simulated", "sample": {"name": "run"},
            "wavelengths_nm": [550.0, 650.0], "created": "2020-01-01T00:00:00+00:00"}
    write_dataset(Dataset(pd.DataFrame(rows), meta), out)
    r = _script().retro(str(out))
    assert r["40"]["550"]["ratio"] == pytest.approx(1.2) and r["40"]["650"]["ratio"] == pytest.approx(1.3)
    assert r["40"]["550"]["u"] > 0


def test_realisations_reads_time_v_and_refuses_runs_that_are_not_felt_seeds(tmp_path, capsys):
    fr = _script()
    (tmp_path / "run.time").write_text("\tCommand being timed: \"simulate fabric x\"\n\tUser time (seconds): 30.25\n"
                                       "\tSystem time (seconds): 2.50\n\tMaximum resident set size (kbytes): 1048576\n")
    got = fr._time_v(tmp_path / "run.time")
    assert got["cpu_s"] == pytest.approx(32.75) and got["peak_rss_mb"] == pytest.approx(1024.0)
    assert fr._time_v(tmp_path / "none.time") == {}
    for name, rho in (("file", 0.5), ("run", 0.4), ("run2", 0.4)):
        _lambertian(tmp_path / name, rho)
    capsys.readouterr()
    code, _, err = _run(capsys, fr, ["realisations", str(tmp_path / "file"), "--group", "one", str(tmp_path / "run")])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "two or more runs" in err
    code, _, err = _run(capsys, fr, ["realisations", str(tmp_path / "file"), "--group", "g", str(tmp_path / "run"),
                                     str(tmp_path / "run2")])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "not a felt Monte Carlo run" in err
    code, _, err = _run(capsys, fr, ["fixed-felt", "--felt-seed", "-1", "--", "fabric", "x"])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--felt-seed -1" in err
