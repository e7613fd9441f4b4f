"""compare.residual.ModelResidual: the figures of compare_datasets, prepared once.

Every case compares ModelResidual.evaluate with compare_datasets run on the dataset holding the
same values, to 1e-12 relative: the fixtures, an RGB and a photometric measurement (the model
converted to channels), a model on a coarser wavelength grid (linear interpolation in
wavelength), and a synthetic measurement with gaps (geometries the model lacks, interpolated or
left out; geometries the measurement lacks).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from compare import ModelResidual
from compare.comparison import compare_datasets
from compare.errors import CompareError
from gonio.data import in_plane_geometry, make_dataset, new_meta, read_dataset

GEO = ["theta_i", "phi_i", "theta_o", "phi_o"]
RTOL = 1e-12


def as_model(ds):
    """(geometries, wavelengths, beta[G, L], u[G, L]) of a complete spectral dataset."""
    t = ds.table
    beta = t.pivot_table(index=GEO, columns="wavelength_nm", values="beta", aggfunc="first")
    u = t.pivot_table(index=GEO, columns="wavelength_nm", values="u_beta", aggfunc="first")
    assert not beta.isna().any().any()
    geometries = beta.index.to_frame(index=False)
    return geometries, beta.columns.to_numpy(float), beta.to_numpy(), u.to_numpy()


def model_dataset(geometries, wavelengths, beta, u, name="model"):
    g = geometries.loc[geometries.index.repeat(wavelengths.size)].reset_index(drop=True)
    table = pd.DataFrame({**{c: g[c].to_numpy() for c in GEO},
                          "wavelength_nm": np.tile(wavelengths, len(geometries)),
                          "beta": beta.ravel(), "u_beta": u.ravel(), "n": 1})
    return make_dataset(table, new_meta("simulated", {"name": name}, {"name": "test"}, {}))


def assert_same(res, beta, u, measured, sim):
    fig = res.evaluate(beta, u)
    c = compare_datasets(measured, [sim])
    name = next(iter(c.simulated))
    frame = c.frames[name]
    np.testing.assert_allclose(fig.beta_simulated, frame["beta_sim"].to_numpy(), rtol=RTOL, atol=0)
    np.testing.assert_allclose(fig.u_simulated, frame["u_sim"].to_numpy(), rtol=1e-10, atol=0)
    np.testing.assert_allclose(fig.factor, c.normalisations[name].factor, rtol=RTOL, atol=0)
    overall = c.overall[name]
    # abs 1e-12: the normal value's quadratic intercept is summed in another order (a sparse product)
    assert fig.nrmse == pytest.approx(overall.nrmse, rel=RTOL, abs=1e-12)
    assert fig.rmse == pytest.approx(overall.rmse, rel=RTOL, abs=1e-12)
    assert math.sqrt(np.sum(fig.residual ** 2)) == pytest.approx(overall.nrmse, rel=1e-10, abs=1e-12)
    meas = frame["beta_meas"].to_numpy()
    expected = (frame["beta_sim"].to_numpy() - meas) / (np.mean(meas) * math.sqrt(meas.size))
    np.testing.assert_allclose(fig.residual, expected, rtol=1e-10, atol=1e-14)
    assert fig.nrmse_per_incidence.keys() == c.curves[name].keys()
    for key, e in c.curves[name].items():
        assert fig.nrmse_per_incidence[key] == pytest.approx(e.nrmse, rel=RTOL, abs=1e-12)
    if c.colour is None:
        assert math.isnan(fig.dh) and math.isnan(fig.ds)
        assert fig.vector(1.0).size == fig.residual.size
    else:
        sc = c.colour.simulated[name]
        for mine, theirs in ((fig.dh, sc.dh), (fig.ds, sc.ds), (fig.dv, sc.dv), (fig.h, sc.colour.h)):
            assert mine == pytest.approx(theirs, rel=1e-10, abs=1e-13)
        v = fig.vector(4.0)
        assert v[-2:] == pytest.approx([2.0 * sc.dh, 2.0 * sc.ds], rel=1e-10, abs=1e-13)
    return fig


@pytest.mark.parametrize("sim_name", ["sim_lambert", "sim_grey", "sim_scaled"])
def test_fixtures_equal_compare_datasets(h, sim_name):
    measured = read_dataset(h.FIXTURES / "measured_red")
    sim = read_dataset(h.FIXTURES / sim_name)
    geometries, wl, beta, u = as_model(sim)
    res = ModelResidual(measured, geometries, wl)
    assert_same(res, beta, u, measured, sim)
    # several evaluations of one prepared object: new values, same answers as a fresh compare
    rng = np.random.default_rng(3)
    for _ in range(2):
        b2 = beta * rng.uniform(0.7, 1.3, size=beta.shape)
        assert_same(res, b2, u, measured, model_dataset(geometries, wl, b2, u))


def test_model_in_shuffled_order_and_coarser_wavelengths(h):
    """Geometries in any order; a 50 nm model against 10 nm data (interpolated in wavelength)."""
    measured = read_dataset(h.FIXTURES / "measured_red")
    geometries = measured.geometries().sample(frac=1.0, random_state=1).reset_index(drop=True)
    wl = np.arange(390.0, 711.0, 40.0)
    ti = geometries["theta_i"].to_numpy()[:, None]
    beta = h.rho(wl)[None, :] * (1.0 + 0.01 * ti) + 0.0 * ti
    u = 0.01 * beta
    res = ModelResidual(measured, geometries, wl)
    assert_same(res, beta, u, measured, model_dataset(geometries, wl, beta, u))


def gappy_measured(h):
    """A measurement on a finer s grid than the model (interpolated points), with s = 65, 70 at
    theta_i = 60 beyond the model's range (left out) and an out-of-plane-free layout."""
    table = h.in_plane_table(h.red_lobe, s_grid=np.arange(-60.0, 71.0, 5.0))
    return h.dataset(table, name="gappy")


@pytest.mark.parametrize("probe_bands", [128, 7])
def test_synthetic_with_gaps_interpolated_and_dropped(h, monkeypatch, probe_bands):
    """probe_bands 7: the geometry weights found in several chunks (bounded memory)."""
    import compare.residual

    monkeypatch.setattr(compare.residual, "_PROBE_BANDS", probe_bands)
    measured = gappy_measured(h)
    model = h.dataset(h.in_plane_table(lambda ti, s, wl: 2.0 * h.red_lobe(ti, s, wl) + 0.01 * s,
                                       s_grid=np.arange(-60.0, 61.0, 10.0)),
                      kind="simulated", name="coarse")
    geometries, wl, beta, u = as_model(model)
    res = ModelResidual(measured, geometries, wl)
    assert res.frame["interpolated"].any()              # the gaps are really exercised
    assert len(res.frame) < len(measured.table)         # and some points are left out
    assert_same(res, beta, u, measured, model)


def test_out_of_plane_model_interpolated_by_triangulation(h):
    """Model with out-of-plane geometries (Delaunay interpolation) against in-plane data."""
    measured = read_dataset(h.FIXTURES / "measured_red")
    rows = []
    for ti in (0.0, 30.0, 45.0, 60.0):
        for s in np.arange(-60.0, 61.0, 15.0):
            to, po = in_plane_geometry(ti, s, 0.0)
            rows.append((ti, 0.0, to, po))
        for to in (20.0, 50.0):
            rows.append((ti, 0.0, to, 90.0))
    geometries = pd.DataFrame(rows, columns=GEO).drop_duplicates().reset_index(drop=True)
    wl = measured.wavelengths_nm
    g = geometries
    beta = (h.rho(wl)[None, :] + 0.002 * g["theta_o"].to_numpy()[:, None]
            + 0.001 * g["theta_i"].to_numpy()[:, None])
    u = 0.02 * beta
    sim = model_dataset(geometries, wl, beta, u)
    res = ModelResidual(measured, sim.geometries(), wl)
    g2, _, b2, u2 = as_model(sim)
    assert res.frame["interpolated"].any()
    assert_same(res, b2, u2, measured, sim)


def to_channels(spectral, channels=("R", "G", "B"), name="rgb"):
    """An RGB (or Y) measurement made from a spectral one with colour-science directly."""
    import colour

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    rows = []
    for g, part in spectral.table.groupby(GEO, sort=True):
        sd = colour.SpectralDistribution(dict(zip(part["wavelength_nm"], part["beta"], strict=True)))
        with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
            xyz = np.asarray(colour.sd_to_XYZ(sd, cmfs, colour.SDS_ILLUMINANTS["D65"])) / 100.0
        values = dict(zip("RGB", np.asarray(colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"])), strict=True))
        values["Y"] = xyz[1]
        rows += [(*g, c, values[c], 0.001, 10) for c in channels]
    table = pd.DataFrame(rows, columns=GEO + ["channel", "beta", "u_beta", "n"])
    return make_dataset(table, new_meta("measured", {"name": name}, {"name": "test"}, {}))


@pytest.mark.parametrize("kind", ["rgb", "y"])
def test_rgb_and_photometric_measurements(h, kind):
    spectral = h.dataset(h.in_plane_table(h.red_lobe), name="red")
    measured = (to_channels(spectral, name="red rgb") if kind == "rgb"
                else to_channels(spectral, ("Y",), name="red Y"))
    model = h.dataset(h.in_plane_table(lambda ti, s, wl: 2.0 * (0.06 + 0.5 / (
        1.0 + np.exp(-(wl - 610.0) / 14.0)) + 0.25 * h.lobe_in_plane(ti, s))),
        kind="simulated", name="other dye")
    geometries, wl, beta, u = as_model(model)
    res = ModelResidual(measured, geometries, wl)
    assert_same(res, beta, u, measured, model)


def test_bad_values_and_bad_normal_are_refused(h):
    measured = read_dataset(h.FIXTURES / "measured_red")
    geometries, wl, beta, _ = as_model(read_dataset(h.FIXTURES / "sim_lambert"))
    res = ModelResidual(measured, geometries, wl)
    with pytest.raises(CompareError, match="shape"):
        res.evaluate(beta[:, :-1])
    bad = beta.copy()
    bad[3, 2] = np.nan
    with pytest.raises(CompareError, match="not all finite"):
        res.evaluate(bad)
    with pytest.raises(CompareError, match="normal/normal value"):
        res.evaluate(-beta)


@pytest.mark.parametrize("kind", ["spectral", "rgb"])
def test_with_measured_noise_draw_equals_a_fresh_comparison(h, kind):
    """The fit's noise draws: same rows, new measured values, only the measured side redone."""
    spectral = h.dataset(h.in_plane_table(h.red_lobe), name="red")
    measured = spectral if kind == "spectral" else to_channels(spectral, name="red rgb")
    model = read_dataset(h.FIXTURES / "sim_lambert")
    geometries, wl, beta, u = as_model(model)
    res = ModelResidual(measured, geometries, wl)
    rng = np.random.default_rng(7)
    t = measured.table.copy()
    t["beta"] = t["beta"] * rng.uniform(0.9, 1.1, len(t))
    noisy = make_dataset(t, measured.meta)
    assert_same(res.with_measured(noisy), beta, u, noisy, model)
    assert_same(res, beta, u, measured, model)          # the original is unchanged
    other = make_dataset(t.iloc[:-3], measured.meta) if kind == "spectral" else None
    if other is not None:
        with pytest.raises(CompareError, match="rows of the prepared one"):
            res.with_measured(other)


def test_a_simulated_normal_spike_the_measurement_cannot_see_does_not_set_the_scale(h):
    """Like for like: a measurement without the normal/normal point (the instrument's blocked cone)
    against a simulation that holds it with a narrow retro-reflection spike (60 % above the smooth
    curve). The simulation's normal value is estimated from the same neighbours as the measurement's,
    so the same smooth curve compares with NRMSE ~0, in compare_datasets and in ModelResidual alike;
    normalising at the spike would scale every value by 1/1.6."""
    measured = h.dataset(h.in_plane_table(h.red_lobe))
    sim_table = h.in_plane_table(lambda ti, s, wl: h.red_lobe(ti, s, wl) * (1.0 + 0.002 * ti), extra_s=(0.0,))
    at_normal = (sim_table["theta_i"] == 0.0) & (sim_table["theta_o"] == 0.0)
    assert at_normal.any()
    sim_table.loc[at_normal, "beta"] *= 1.6
    sim = h.dataset(sim_table, kind="simulated", name="spiky")
    c = compare_datasets(measured, [sim])
    name = next(iter(c.simulated))
    assert 1e-3 < c.overall[name].nrmse < 0.15    # only the 0.2 %/deg shape change away from normal incidence
    np.testing.assert_allclose(c.normalisations[name].factor, 1.0, rtol=1e-3)
    geometries, wl, beta, u = as_model(sim)
    assert_same(ModelResidual(measured, geometries, wl), beta, u, measured, sim)
    # a measurement that holds the normal point is matched at it (the spike then does set the scale)
    measured_exact = h.dataset(h.in_plane_table(h.red_lobe, extra_s=(0.0,)))
    c2 = compare_datasets(measured_exact, [sim])
    np.testing.assert_allclose(c2.normalisations[next(iter(c2.simulated))].factor, 1 / 1.6, rtol=1e-9)
