"""Fiber volume BRDF: the three routes, independent limits, white Monte Carlo, determinism.

Every Monte Carlo comparison is within a few COMPUTED standard errors at a fixed seed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.fiber import Fiber, normal_albedo, range_outputs, volume_brdf
from simulate.media.medium import HGMedium, OpticalProperties
from simulate.montecarlo import run_slab
from simulate.optics.phase import PhaseTable

N_MU, N_PHI = 4, 6
MU_EDGES = np.linspace(0, 1, N_MU + 1)
PHI_EDGES = np.linspace(-math.pi, math.pi, N_PHI + 1)


def _grid_outputs(cells, half_width, psi_c=0.0):
    return range_outputs([MU_EDGES[i] for i, _ in cells], [MU_EDGES[i + 1] for i, _ in cells],
                         [PHI_EDGES[j] for _, j in cells], [PHI_EDGES[j + 1] for _, j in cells], half_width, psi_c)


def _beam(w_t, beta_deg):
    """Unit vector with axial component w_t whose cross-section part points along n(beta)."""
    rho = math.sqrt(1 - w_t * w_t)
    b = math.radians(beta_deg)
    return np.array([w_t, -rho * math.sin(b), rho * math.cos(b)])


FIBER = Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=1.0, mu_a=0.05, g=0.7), roughness=0.3,
              cell_width_deg=20.0)
CELLS = [(3, 3), (2, 1), (1, 4), (3, 0)]


@pytest.mark.parametrize("w_in", [_beam(0.0, 0.0), _beam(0.5, 40.0), _beam(0.3, 160.0)],
                         ids=["normal", "oblique", "from-below"])
def test_three_routes_agree_within_combined_standard_errors(w_in):
    """nee, beam and bssrdf estimate the same cell-and-bin average (aligned azimuths: no interpolation)."""
    out = _grid_outputs(CELLS, FIBER.half_width)
    w = np.tile(w_in, (len(CELLS), 1))
    est = {m: volume_brdf(FIBER, w, None, [500.0], method=m, outputs=out, target_rel_err=0.03, seed=11,
                          bssrdf_bins=(N_MU, N_PHI)) for m in ("nee", "beam", "bssrdf")}
    for e in est.values():
        assert np.all(np.isfinite(e.R)) and np.all(e.u_R > 0)
        assert np.all(e.R > 0)
    for a, b in (("nee", "beam"), ("nee", "bssrdf"), ("beam", "bssrdf")):
        z = (est[a].R - est[b].R) / np.hypot(est[a].u_R, est[b].u_R)
        assert np.all(np.abs(z) < 4.0), (a, b, z)
    # the next-event route reaches the same error with far fewer photons
    assert est["nee"].photons * 5 < est["beam"].photons


class _SpectralHG:
    """A Henyey-Greenstein medium whose absorption depends on the wavelength (test medium)."""

    def __init__(self, mu_s, g, mu_a_by_wl):
        self.mu_s, self.g, self.mu_a = mu_s, g, dict(mu_a_by_wl)
        self._table = PhaseTable.from_hg(g)

    def optical_properties(self, wavelength_nm):
        mu_a = self.mu_a[float(wavelength_nm)]
        mu_t = self.mu_s + mu_a
        return OpticalProperties(float(wavelength_nm), self.mu_s, mu_a, mu_t, self.g, self.mu_s / mu_t, self._table)


def test_white_monte_carlo_equals_per_wavelength_runs():
    wl = [450.0, 550.0, 650.0]
    medium = _SpectralHG(1.0, 0.6, {450.0: 0.5, 550.0: 0.1, 650.0: 0.01})
    fiber = Fiber(radius_um=8.0, n_host=1.557, medium=medium, roughness=0.2, cell_width_deg=20.0)
    w_in = np.array([_beam(0.2, 20.0)] * 2)
    w_out = np.array([[0.0, 0.0, 1.0], [0.5, 0.3, math.sqrt(1 - 0.34)]])
    white = volume_brdf(fiber, w_in, w_out, wl, method="nee", target_rel_err=0.02, seed=3)
    assert len(white.info["groups"]) == 1  # one walk served all three absorption values
    for i, w in enumerate(wl):
        single = volume_brdf(fiber, w_in, w_out, [w], method="nee", target_rel_err=0.02, seed=100 + i, white=False)
        z = (white.R[:, i] - single.R[:, 0]) / np.hypot(white.u_R[:, i], single.u_R[:, 0])
        assert np.all(np.abs(z) < 4.0), (w, z)
    # absorption orders the spectrum: more absorption, less light
    assert np.all(white.R[:, 0] < white.R[:, 1]) and np.all(white.R[:, 1] < white.R[:, 2])


def test_index_matched_thick_fiber_top_cell_is_the_half_space():
    """n = 1, mu_t R = 1000, isotropic, albedo 0.99: the top cell sees a half-space.

    Reference: the slab kernel with a thickness of 10^4 mean free paths, whose reflected
    radiance coefficient per bin is ``reflected cos(theta_i) / Omega_proj``. Curvature: across
    the 6-degree cell the local incidence varies by +-3 degrees and the surface by R(1 - cos 3 deg)
    = 1.4 mean free paths, a second-order effect well below the statistical error here.
    """
    fiber = Fiber(radius_um=1000.0, n_host=1.0, medium=HGMedium(mu_s=0.99, mu_a=0.01, g=0.0), roughness=0.3,
                  cell_width_deg=6.0)
    n_mu, n_phi = 3, 4
    mu_e = np.linspace(0, 1, n_mu + 1)
    phi_e = np.linspace(-math.pi, math.pi, n_phi + 1)
    cells = [(2, 1), (1, 2), (0, 0)]
    out = range_outputs([mu_e[i] for i, _ in cells], [mu_e[i + 1] for i, _ in cells],
                        [phi_e[j] for _, j in cells], [phi_e[j + 1] for _, j in cells], fiber.half_width)
    for theta in (0.0, 40.0):
        t = math.radians(theta)
        w_in = np.tile([math.sin(t), 0.0, math.cos(t)], (len(cells), 1))
        fib = volume_brdf(fiber, w_in, None, [500.0], method="nee", outputs=out, target_rel_err=0.03, seed=5)
        slab = run_slab(0.01, 0.99, g=0.0, n=1.0, thickness=1e4, photons=400_000, seed=6, theta_i_deg=theta,
                        angular_bins=(n_mu, n_phi))
        omega = 0.5 * (mu_e[1:] ** 2 - mu_e[:-1] ** 2)[:, None] * np.diff(phi_e)[None, :]
        ref = np.array([slab.angular.reflected[i, j] * math.cos(t) / omega[i, j] for i, j in cells])
        u_ref = np.array([slab.angular.u_reflected[i, j] * math.cos(t) / omega[i, j] for i, j in cells])
        z = (fib.R[:, 0] - ref) / np.hypot(fib.u_R[:, 0], u_ref)
        assert np.all(np.abs(z) < 4.0), (theta, z, fib.R[:, 0], ref)


def _all_cells_exits(fiber, w_in):
    """Exited fraction per launched photon summed over every cell and direction (binned beam route)."""
    n_cells = int(round(360 / fiber.cell_width_deg))
    psi_c = 2 * math.pi * np.arange(n_cells) / n_cells
    out = range_outputs(np.zeros(n_cells), np.ones(n_cells), -math.pi * np.ones(n_cells), math.pi * np.ones(n_cells),
                        fiber.half_width, psi_c)
    est = volume_brdf(fiber, np.tile(w_in, (n_cells, 1)), None, [500.0], method="beam", outputs=out,
                      target_rel_err=0.05, seed=2)
    d_perp = math.hypot(w_in[1], w_in[2])
    scale = 2 * fiber.half_width / (2 * d_perp)  # R -> exit weight per photon and unit Omega_proj
    return est.R[:, 0].sum() * math.pi * scale, est.info["energy"][0]


@pytest.mark.parametrize("w_in", [_beam(0.0, 0.0), _beam(0.6, 30.0)])
def test_energy_conservation_and_albedo_bound(w_in):
    lossless = Fiber(radius_um=5.0, n_host=1.557, medium=HGMedium(mu_s=2.0, mu_a=0.0, g=0.8), roughness=0.3,
                     cell_width_deg=30.0)
    exited, energy = _all_cells_exits(lossless, w_in)
    assert exited == pytest.approx(energy["entered"], rel=1e-9)  # mu_a = 0: everything that entered leaves
    lossy = Fiber(radius_um=5.0, n_host=1.557, medium=HGMedium(mu_s=2.0, mu_a=0.2, g=0.8), roughness=0.3,
                  cell_width_deg=30.0)
    exited, energy = _all_cells_exits(lossy, w_in)
    assert 0 < exited < energy["entered"] <= 1.0


def test_normal_albedo_is_a_fraction_and_falls_with_absorption():
    fibers = [Fiber(radius_um=10.0, n_host=1.557, medium=HGMedium(mu_s=2.0, mu_a=a, g=0.7), roughness=0.3)
              for a in (0.001, 0.05)]
    (rho_lo, u_lo), (rho_hi, u_hi) = (normal_albedo(f, [550.0], target_rel_err=0.02, seed=4) for f in fibers)
    assert 0 < rho_hi[0] < rho_lo[0] < 1
    assert rho_lo[0] - rho_hi[0] > 4 * math.hypot(u_lo[0], u_hi[0])


def test_fixed_seed_same_numbers_with_one_or_two_threads():
    w_in = np.array([_beam(0.3, 10.0)] * 2)
    w_out = np.array([[0.0, 0.0, 1.0], [0.2, -0.4, math.sqrt(0.8)]])
    a = volume_brdf(FIBER, w_in, w_out, [500.0, 600.0], target_rel_err=0.1, seed=9, threads=1)
    b = volume_brdf(FIBER, w_in, w_out, [500.0, 600.0], target_rel_err=0.1, seed=9, threads=2)
    np.testing.assert_array_equal(a.R, b.R)
    np.testing.assert_array_equal(a.u_R, b.u_R)


@pytest.mark.parametrize("bad, message", [
    (dict(method="magic"), "method"),
    (dict(target_rel_err=0.0), "target_rel_err"),
    (dict(w_out=np.array([[0.0, 0.0, -1.0]])), "w_out"),
    (dict(w_in=np.array([[1.0, 0.0, 0.0]])), "parallel"),
])
def test_bad_arguments_are_named(bad, message):
    args = dict(w_in=np.array([[0.0, 0.0, 1.0]]), w_out=np.array([[0.0, 0.0, 1.0]]), method="nee",
                target_rel_err=0.1)
    args.update(bad)
    with pytest.raises(ValueError, match=message):
        volume_brdf(FIBER, args.pop("w_in"), args.pop("w_out"), [500.0], **args)
