"""The fiber's far-field scattering function (simulate.fiber.farfield) against an independent photon trace.

The brute-force tracer (conftest.py, no code shared with the kernel) tallies the exits of a whole
fiber by direction in bins of ``(w_x, atan2(w_y, w_z))`` (equal solid angles); its per-bin mean
radiant intensity per unit length and unit beam irradiance is the far field averaged over the bin.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from simulate.fiber import Fiber, volume_brdf
from simulate.fiber import farfield as FF
from simulate.media.medium import HGMedium
from simulate.optics.fresnel import OpticsDomainWarning

R_UM, N_HOST, MU_S, MU_A, G = 10.0, 1.5, 0.4, 0.02, 0.5
W_T = 0.3
N_X, N_A = 6, 12


def _fiber() -> Fiber:
    return Fiber(radius_um=R_UM, n_host=N_HOST, medium=HGMedium(mu_s=MU_S, mu_a=MU_A, g=G), roughness=0.3,
                 cell_width_deg=10)


def _w_in(beta_deg: float) -> np.ndarray:
    rho = math.sqrt(1.0 - W_T * W_T)
    b = math.radians(beta_deg)
    return np.array([W_T, -rho * math.sin(b), rho * math.cos(b)])


def _bin_directions(m: int) -> np.ndarray:
    """``[N_X, N_A, m*m, 3]`` midpoints of an m x m sub-grid (equal solid angle) in each tracer bin."""
    sub = (np.arange(m) + 0.5) / m
    x = (np.arange(N_X)[:, None] + sub[None, :]) / N_X * 2.0 - 1.0           # [N_X, m]
    a = (np.arange(N_A)[:, None] + sub[None, :]) / N_A * 2.0 * math.pi - math.pi
    xx = np.broadcast_to(x[:, None, :, None], (N_X, N_A, m, m))
    aa = np.broadcast_to(a[None, :, None, :], (N_X, N_A, m, m))
    s = np.sqrt(1.0 - xx ** 2)
    w = np.stack([xx, s * np.sin(aa), s * np.cos(aa)], axis=-1)
    return w.reshape(N_X, N_A, m * m, 3)


@pytest.fixture(scope="module")
def table():
    return FF.exit_table(_fiber(), [550.0], w_t=[0.0, W_T, 0.6], photons_per_row=20_000, seed=3, threads=2)


@pytest.mark.parametrize("beta_deg", [20.0, 25.0])
def test_far_field_agrees_with_brute_force_trace(table, tracer, beta_deg):
    """Bin averages of the table's far field = the tracer's, within 4 combined standard errors + 3 %.

    beta = 20 deg is a multiple of the cell width (no interpolation); 25 deg is interpolated
    between the neighbouring multiples. The 3 % allowance is the table's own binning of local
    exit directions (9 x 18 bins per cell) seen through the tracer's 6 x 12 bins.
    """
    w_in = _w_in(beta_deg)
    n = 400_000
    sums, sq = tracer(n, 11, *w_in, R_UM, N_HOST, MU_S, MU_A, G, 0.0, N_X, N_A)
    omega = 4.0 * math.pi / (N_X * N_A)
    scale = 2.0 * R_UM * math.hypot(w_in[1], w_in[2]) / omega
    mean = sums / n
    u_trace = np.sqrt(np.maximum(sq / n - mean ** 2, 0.0) / (n - 1)) * scale
    trace = mean * scale
    dirs = _bin_directions(6)
    ff = table.far_field(w_in, dirs.reshape(-1, 3))[:, 0].reshape(N_X, N_A, -1).mean(axis=2)
    # the table's own error: the rows' errors through the same sum (added in quadrature per row, bound)
    assert trace.sum() > 0
    err = np.abs(ff - trace)
    allowed = 4.0 * u_trace + 0.03 * trace.max()
    assert np.all(err <= allowed), (np.max(err / allowed), ff, trace)
    # and the shape is not trivially flat: the far field varies by a factor > 3 over the bins
    assert trace.max() > 3.0 * trace[trace > 0].min()


def test_far_field_total_is_the_albedo(table):
    """int S dOmega over the sphere = a(w_i) 2 R |w_perp|, a from an independent absorbing walk's bookkeeping."""
    w_in = _w_in(20.0)
    fiber = _fiber()
    # independent: the beam route walking the ABSORBING medium; its energy bookkeeping is the albedo
    est = volume_brdf(fiber, w_in[None], np.array([[0.0, 0.0, 1.0]]), [550.0], method="nee", white=False,
                      target_rel_err=0.05, max_photons=200_000, seed=5, threads=2)
    energy = est.info["energy"][0]
    albedo = energy["exited"]  # exit weight per launched photon: the volume albedo of the intercepted light
    n = 200
    x = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    a = (np.arange(2 * n) + 0.5) / (2 * n) * 2.0 * math.pi - math.pi
    xx, aa = np.meshgrid(x, a, indexing="ij")
    s = np.sqrt(1.0 - xx ** 2)
    w = np.stack([xx, s * np.sin(aa), s * np.cos(aa)], axis=-1).reshape(-1, 3)
    total = table.far_field(w_in, w)[:, 0].sum() * 4.0 * math.pi / w.shape[0]
    expected = albedo * 2.0 * R_UM * math.hypot(w_in[1], w_in[2])
    u = 4.0 * 0.01 * expected  # 4 x (the table's ~0.5 % + the walk's ~0.5 % relative errors)
    assert abs(total - expected) <= u, (total, expected)
    # the table's own cell sum gives the same number without the sphere quadrature
    assert table.albedo(w_in)[0] == pytest.approx(total / (2.0 * R_UM * math.hypot(w_in[1], w_in[2])), rel=2e-3)


def test_nee_far_field_matches_the_table_at_points(table):
    """The next-event far field (ONE volume_brdf call over cells x directions) = the table's, within binning."""
    w_in = _w_in(20.0)
    w_out = np.array([[0.1, 0.5, 0.8], [-0.3, -0.6, 0.5], [0.2, 0.3, -0.9]])
    w_out /= np.linalg.norm(w_out, axis=1)[:, None]
    S, u, s_surf, info = FF.far_field_nee(_fiber(), np.repeat(w_in[None], 3, axis=0), w_out, [550.0],
                                          target_rel_err=0.02, seed=2, threads=2)
    ref = table.far_field(w_in, w_out)[:, 0]
    assert np.all(np.abs(S[:, 0] - ref) <= 4.0 * u[:, 0] + 0.04 * ref), (S[:, 0], ref, u[:, 0])
    assert info["outputs"] > 3 * 9   # every pair scored at every cell facing it


def test_surface_far_field_total_matches_cell_sum_of_directional_albedos():
    """int S_surf dOmega = sum over points of R dpsi (w_i . n)_+ A_CT(theta_local) (an independent quadrature)."""
    from simulate.optics import microfacet

    fiber = _fiber()
    w_in = _w_in(20.0)
    n = 120
    x = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    a = (np.arange(2 * n) + 0.5) / (2 * n) * 2.0 * math.pi - math.pi
    xx, aa = np.meshgrid(x, a, indexing="ij")
    s = np.sqrt(1.0 - xx ** 2)
    w = np.stack([xx, s * np.sin(aa), s * np.cos(aa)], axis=-1).reshape(-1, 3)
    total = FF.surface_far_field(fiber, np.broadcast_to(w_in, w.shape), w, n_psi=180).sum() * 4.0 * math.pi / w.shape[0]
    psi = (np.arange(240) + 0.5) / 240 * 2.0 * math.pi
    cos_local = np.clip(FF.cell_frame(w_in[None], psi)[:, 2], 0.0, None)
    lit = cos_local > 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpticsDomainWarning)  # grazing points: finite, vanishing weight
        albedo = microfacet.directional_albedo(np.arccos(cos_local[lit]), fiber.roughness, fiber.n_host, n_grid=128)
    expected = (R_UM * 2.0 * math.pi / 240) * np.sum(cos_local[lit] * albedo)
    assert total == pytest.approx(expected, rel=0.01)
