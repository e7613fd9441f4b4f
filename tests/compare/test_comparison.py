"""Scale invariance, self-comparison, alignment and the metrics document (compare.comparison)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.comparison import compare_datasets, unique_names
from compare.errors import CompareError


def _flatten(doc, prefix=""):
    """{path: value} of every leaf of a JSON-like document."""
    if isinstance(doc, dict):
        out = {}
        for k, v in doc.items():
            out.update(_flatten(v, f"{prefix}/{k}"))
        return out
    return {prefix: doc}


def _noisy_model(h, seed=7):
    rng = np.random.default_rng(seed)
    table = h.in_plane_table(lambda ti, s, wl: h.rho(wl) * (1 + 0.3 * np.cos(np.radians(s)))
                             + 0.05 * h.lobe_in_plane(ti, s))
    table["beta"] *= 1 + 0.05 * rng.standard_normal(len(table))
    table["u_beta"] = 0.01 * table["beta"]
    return table


@pytest.mark.parametrize("scale", [1e-6, 0.37, 42.0, 3.0e5])
def test_scale_invariance(h, scale):
    measured = h.dataset(h.in_plane_table(h.red_lobe, u_fn=lambda b: 0.002 + 0.01 * b))
    table = _noisy_model(h)
    sim = h.dataset(table, kind="simulated", name="model")
    scaled_table = table.copy()
    scaled_table["beta"] *= scale
    scaled_table["u_beta"] *= scale
    scaled = h.dataset(scaled_table, kind="simulated", name="model")
    ref = compare_datasets(measured, [sim])
    cmp = compare_datasets(measured, [scaled])
    np.testing.assert_allclose(cmp.frames["model"]["beta_sim"], ref.frames["model"]["beta_sim"],
                               rtol=1e-12)
    np.testing.assert_allclose(cmp.frames["model"]["u_sim"], ref.frames["model"]["u_sim"],
                               rtol=1e-12)
    a, b = _flatten(ref.metrics()), _flatten(cmp.metrics())
    assert a.keys() == b.keys()
    # The level (Comparison.level) judges the absolute level, so it is not scale-invariant: the factors
    # k, k_min, k_max scale by 1/scale, the ratio max(k, 1/k) follows from the scaled k, and only the
    # spread and CV over the bands (ratios of factors) are invariant.
    level = "/normalisation/level/model/"
    k_scaled = a[level + "k"] / scale
    assert b[level + "ratio"] == pytest.approx(max(k_scaled, 1.0 / k_scaled), rel=1e-12)
    for key, value in a.items():
        if "/factor/" in key and "per_wavelength" in key or key.endswith("/median") \
                or key.endswith("/luminance") or key in (level + "k", level + "k_min", level + "k_max"):
            assert b[key] == pytest.approx(value / scale, rel=1e-12), key
        elif key == level + "ratio":
            continue  # asserted above
        elif key.startswith("/normalisation/normal_value/model/") and "per_wavelength" in key:
            assert b[key] == pytest.approx(value * scale, rel=1e-12), key
        elif isinstance(value, float):
            assert b[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
        else:
            assert b[key] == value, key
    assert ref.overall["model"].nrmse > 0.01  # a real difference, preserved under scaling


def test_self_comparison_is_exactly_zero(h):
    measured = h.dataset(_noisy_model(h, seed=3), name="itself")
    c = compare_datasets(measured, [measured])
    for e in list(c.curves["itself"].values()) + [c.overall["itself"]]:
        assert e.rmse == 0.0 and e.nrmse == 0.0 and e.max_abs == 0.0
    np.testing.assert_array_equal(c.normalisations["itself"].factor, 1.0)
    sc = c.colour.simulated["itself"]
    assert (sc.dh, sc.ds, sc.dv) == (0.0, 0.0, 0.0)


def test_curve_metrics_against_direct_computation(h):
    """RMSE / NRMSE / max of a known residual pattern, computed here without compare."""
    measured = h.dataset(h.in_plane_table(lambda ti, s, wl: 0.4 + 0 * s))
    # simulation = measured + 0.01 * (theta_i / 30) on a shifted scale (x2)
    sim = h.dataset(h.in_plane_table(lambda ti, s, wl: 2 * (0.4 + 0.01 * ti / 30.0)),
                    kind="simulated", name="offset")
    c = compare_datasets(measured, [sim])
    # normal value of the sim is 0.8 at theta_i = 0 -> k = 0.5 -> residual 0.01 * theta_i / 30
    for theta_i in (0.0, 30.0, 45.0, 60.0):
        e = c.curves["offset"][f"{theta_i:g}"]
        d = 0.01 * theta_i / 30.0
        assert e.rmse == pytest.approx(d, abs=1e-15)
        assert e.nrmse == pytest.approx(d / 0.4, abs=1e-14)
        assert e.max_abs == pytest.approx(d, abs=1e-15)
        assert e.max_abs_at["theta_i"] == theta_i
    n = {0.0: 13, 30.0: 13, 45.0: 14, 60.0: 13}  # points per incidence (beam block removes one)
    expected = math.sqrt(sum(n[t] * (0.01 * t / 30) ** 2 for t in n) / sum(n.values()))
    assert c.overall["offset"].rmse == pytest.approx(expected, rel=1e-12)


def test_simulation_on_other_geometries_and_wavelengths_is_interpolated(h):
    measured = h.dataset(h.in_plane_table(h.red_lobe, u_fn=lambda b: 0.002 + 0.01 * b))
    on_grid = h.dataset(h.in_plane_table(lambda ti, s, wl: 2 * h.rho(wl)), kind="simulated",
                        name="lambert")
    # constant in angle, linear in wavelength between the measured wavelengths: interpolation
    # from s = -65..75 step 10 and a 5-nm grid is exact, so the figures must be identical
    shifted = h.dataset(h.in_plane_table(
        lambda ti, s, wl: 2 * np.interp(wl, h.WAVELENGTHS, h.rho(h.WAVELENGTHS)),
        s_grid=np.arange(-65.0, 76.0, 10.0), wavelengths=np.arange(385.0, 716.0, 5.0)),
        kind="simulated", name="lambert")
    a = compare_datasets(measured, [on_grid])
    b = compare_datasets(measured, [shifted])
    assert b.frames["lambert"]["interpolated"].all()
    assert len(b.frames["lambert"]) == len(a.frames["lambert"])
    for angle in a.curves["lambert"]:
        assert b.curves["lambert"][angle].rmse == pytest.approx(a.curves["lambert"][angle].rmse,
                                                                rel=1e-9)
    # the normal value of the shifted simulation is estimated from s = +-5, +-15: constant, exact
    np.testing.assert_allclose(b.normalisations["lambert"].factor,
                               a.normalisations["lambert"].factor, rtol=1e-9)


def test_partial_wavelength_overlap_compares_on_the_shared_grid(h):
    measured = h.dataset(h.in_plane_table(h.red_lobe))
    sim = h.dataset(h.in_plane_table(h.red_lobe, wavelengths=np.arange(400.0, 701.0, 10.0)),
                    kind="simulated", name="narrow")
    c = compare_datasets(measured, [sim])
    np.testing.assert_array_equal(c.wavelength_nm, np.arange(400.0, 701.0, 10.0))
    assert c.overall["narrow"].rmse < 1e-12


def test_unreconcilable_wavelengths_are_refused(h):
    measured = h.dataset(h.in_plane_table(h.red_lobe), name="meas")
    sim = h.dataset(h.in_plane_table(h.red_lobe, wavelengths=np.arange(600.0, 801.0, 10.0)),
                    kind="simulated", name="infrared")
    with pytest.raises(CompareError, match="wavelength grids cannot be reconciled: simulated "
                                           "dataset 'infrared'.*600..800 nm.*'meas'.*390..710 nm"):
        compare_datasets(measured, [sim])


def test_no_shared_geometry_is_refused(h):
    measured = h.dataset(h.in_plane_table(h.red_lobe, incidence=(0.0, 30.0)), name="meas")
    sim = h.dataset(h.in_plane_table(h.red_lobe, incidence=(0.0,), s_grid=[-20, -10, 10, 20]),
                    kind="simulated", name="tiny")
    c = compare_datasets(measured, [sim])   # shares the four normal-incidence geometries
    assert set(c.curves["tiny"]) == {"0"}
    far = h.dataset(h.in_plane_table(h.red_lobe, incidence=(70.0,)).assign(theta_i=70.0),
                    kind="simulated", name="far")
    with pytest.raises(CompareError):
        compare_datasets(measured, [far])   # no normal incidence at all


def test_unique_names_avoid_collisions_and_reserved_keys():
    assert unique_names(["a", "a", "a", "geometry", "measured", "a (2)"]) == \
        ["a", "a (2)", "a (3)", "geometry (2)", "measured (2)", "a (2) (2)"]
