"""The analytic fixtures: reproducible from their script, and their metrics equal the values
computed here by hand from the formulas in fixtures/analytic/README.md."""

from __future__ import annotations

import importlib.util

import colour
import numpy as np
import pytest

from compare.comparison import compare_datasets
from gonio.data import read_dataset

C = 0.2
CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
D65 = colour.SDS_ILLUMINANTS["D65"]


def _hsv(wl, beta):
    sd = colour.SpectralDistribution(dict(zip(wl, beta, strict=True)))
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        xyz = colour.sd_to_XYZ(sd, CMFS, D65) / 100.0
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"])
    h, s, v = colour.RGB_to_HSV(rgb)
    return dict(h=h, s=s, v=v, blue_red=rgb[2] / rgb[0], green_red=rgb[1] / rgb[0]), xyz[1]


@pytest.fixture(scope="module")
def metrics(h):
    measured = read_dataset(h.FIXTURES / "measured_red")
    sims = [read_dataset(h.FIXTURES / n) for n in ("sim_scaled", "sim_lambert", "sim_grey")]
    return compare_datasets(measured, sims).metrics()


def test_script_reproduces_the_committed_fixtures(h, tmp_path):
    spec = importlib.util.spec_from_file_location("make_fixtures",
                                                  h.FIXTURES / "make_fixtures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--out", str(tmp_path)]) == 0
    for name in ("measured_red", "sim_scaled", "sim_lambert", "sim_grey"):
        assert (tmp_path / name / "radiance.csv").read_bytes() == \
            (h.FIXTURES / name / "radiance.csv").read_bytes(), name


def _expected_lambert(h):
    """Per incidence: residual C (1 - L) at every wavelength; mean measured rho + C L."""
    wl = h.WAVELENGTHS
    rho = h.rho(wl)
    out, d2, n, total = {}, 0.0, 0, 0.0
    for ti in (0.0, 30.0, 45.0, 60.0):
        s = h.S_GRID[np.abs(h.S_GRID + ti) >= 5.0]
        one_minus_l = 1.0 - h.lobe_in_plane(ti, s)
        rmse = C * np.sqrt(np.mean(one_minus_l ** 2))
        mean = rho.mean() + C * h.lobe_in_plane(ti, s).mean()
        out[f"{ti:g}"] = (rmse, rmse / mean)
        d2 += wl.size * np.sum((C * one_minus_l) ** 2)
        n += wl.size * s.size
        total += s.size * rho.sum() + wl.size * C * h.lobe_in_plane(ti, s).sum()
    return out, np.sqrt(d2 / n), np.sqrt(d2 / n) / (total / n)


def test_lambert_and_grey_curve_metrics_equal_hand_computed(h, metrics):
    per_angle, rmse, nrmse = _expected_lambert(h)
    # spot-check the hand arithmetic at normal incidence: sum (1-L)^2 over the 13 angles
    # = 7 * 1 + 2 * (0.5625^2 + 0.25^2 + 0.0625^2) = 7.765625
    assert per_angle["0"][0] == pytest.approx(C * np.sqrt(7.765625 / 13), rel=1e-12)
    for name in ("lambertian model", "grey model"):
        for angle, (e_rmse, e_nrmse) in per_angle.items():
            got = metrics["curves"][name][angle]
            assert got["rmse"] == pytest.approx(e_rmse, rel=1e-8), (name, angle)
            assert got["nrmse"] == pytest.approx(e_nrmse, rel=1e-8), (name, angle)
            assert got["max_abs"] == pytest.approx(C, rel=1e-8)
            at = got["max_abs_at"]
            assert abs(at["s"] - at["theta_i"]) >= 40.0  # where the lobe is zero
            assert at["measured"] == pytest.approx(h.rho(at["wavelength_nm"]), rel=1e-8)
        assert metrics["overall"][name]["rmse"] == pytest.approx(rmse, rel=1e-8)
        assert metrics["overall"][name]["nrmse"] == pytest.approx(nrmse, rel=1e-8)
    assert metrics["overall"]["lambertian model"]["nrmse"] == pytest.approx(0.499089, abs=1e-6)


def test_normalisation_factors_equal_hand_computed(h, metrics):
    wl = h.WAVELENGTHS
    rho = h.rho(wl)
    factor = metrics["normalisation"]["factor"]
    normal = metrics["normalisation"]["normal_value"]
    expected = {"scaled model": np.full(wl.size, 1 / 3.7), "lambertian model": (rho + C) / (2 * rho),
                "grey model": (rho + C) / 0.5}
    for name, k in expected.items():
        got = np.array([factor[name]["per_wavelength"][f"{w:g}"] for w in wl])
        np.testing.assert_allclose(got, k, rtol=1e-8)
        assert factor[name]["median"] == pytest.approx(np.median(k), rel=1e-8)
    # measured beta(0,0) = rho + C, estimated exactly (quadratic lobe); model term = C (10/40)^2
    m = normal["measured"]
    assert m["how"] == "estimated"
    np.testing.assert_allclose([m["per_wavelength"][f"{w:g}"] for w in wl], rho + C, rtol=1e-8)
    u = np.array([m["u_per_wavelength"][f"{w:g}"] for w in wl])
    assert np.all(u >= C * (10 / 40) ** 2) and np.all(u < C * (10 / 40) ** 2 + 0.01)
    # the scaled model holds the normal point, but the measurement does not: estimated like for like
    assert normal["scaled model"]["how"] == "estimated"
    assert normal["lambertian model"]["how"] == "estimated"


def test_scaled_model_has_zero_error(metrics):
    for e in metrics["curves"]["scaled model"].values():
        assert e["rmse"] < 1e-9 and e["max_abs"] < 1e-9  # CSV keeps 10 significant digits
    colour_ = metrics["colour"]["scaled model"]
    assert abs(colour_["dh"]) < 1e-9 and abs(colour_["ds"]) < 1e-9 and abs(colour_["dv"]) < 1e-9


def test_colour_match_equals_hand_computed(h, metrics):
    wl = h.WAVELENGTHS
    rho = h.rho(wl)
    col = metrics["colour"]
    assert col["geometry"] == {"theta_i": 0.0, "phi_i": 0.0, "theta_o": 10.0, "phi_o": 0.0,
                               "s": -10.0}
    meas, _ = _hsv(wl, rho + C * (1 - (10 / 40) ** 2))
    _, y_normal = _hsv(wl, rho + C)
    # lambert: 2 rho scaled by k_Y = Y[rho + C] / Y[2 rho]
    _, y_rho = _hsv(wl, rho)
    lam, _ = _hsv(wl, rho * y_normal / y_rho)
    grey, _ = _hsv(wl, np.full(wl.size, y_normal))  # 0.5 scaled by Y[rho + C] / 0.5
    for key in ("h", "s", "v", "blue_red", "green_red"):
        assert col["measured"][key] == pytest.approx(meas[key], rel=1e-8, abs=1e-12), key
        assert col["lambertian model"][key] == pytest.approx(lam[key], rel=1e-8, abs=1e-12), key
        assert col["grey model"][key] == pytest.approx(grey[key], rel=1e-8, abs=1e-12), key
    for name, ref in (("lambertian model", lam), ("grey model", grey)):
        d = col[name]
        assert d["dh"] == pytest.approx((ref["h"] - meas["h"] + 0.5) % 1.0 - 0.5, abs=1e-10)
        assert d["ds"] == pytest.approx(ref["s"] - meas["s"], abs=1e-10)
        assert d["dv"] == pytest.approx(ref["v"] - meas["v"], abs=1e-10)
    # the grey model is achromatic and, scaled to the measured luminance, has v = Y[rho + C]
    assert col["grey model"]["s"] < 1e-3
    assert col["grey model"]["v"] == pytest.approx(y_normal, rel=1e-3)
