"""Cylinder (fiber) transport: geometric optics of the bare dielectric cylinder, bookkeeping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.montecarlo import run_cylinder


def _trace_bare_cylinder(w_i, n, radius, mu_a, fresnel_ref, refract_ref, n_rays=100_000, max_chords=400):
    """Deterministic ray tracing through a bare cylinder (axis x), Fresnel-split at every hit.

    Rays of a parallel beam travelling along -w_i, impact parameters on a midpoint grid over
    the projected width. Returns exit records (weight per launched ray, exit point, direction).
    """
    d = -np.asarray(w_i, float) / np.linalg.norm(w_i)
    e = np.cross([1.0, 0.0, 0.0], d)
    e /= np.linalg.norm(e)
    b = (np.arange(n_rays) + 0.5) / n_rays * 2 * radius - radius
    start = b[:, None] * e[None, :] - 10 * radius * d[None, :]
    dirs = np.repeat(d[None, :], n_rays, axis=0)

    def hit(p, u, inside):
        # roots of |p_perp + s u_perp|^2 = R^2; outside: smaller root, inside: larger root
        a = u[:, 1] ** 2 + u[:, 2] ** 2
        bb = p[:, 1] * u[:, 1] + p[:, 2] * u[:, 2]
        c = p[:, 1] ** 2 + p[:, 2] ** 2 - radius**2
        disc = np.sqrt(np.clip(bb * bb - a * c, 0.0, None))
        s = (-bb + disc) / a if inside else (-bb - disc) / a
        q = p + s[:, None] * u
        normal = np.zeros_like(q)
        normal[:, 1:] = q[:, 1:] / np.linalg.norm(q[:, 1:], axis=1)[:, None]
        return q, s, normal

    p, _, normal = hit(start, dirs, inside=False)
    cos_i = -np.sum(dirs * normal, axis=1)
    weight = (1.0 - fresnel_ref(cos_i, 1.0, n)) / n_rays
    u, _ = refract_ref(dirs, normal, 1.0 / n)
    out_w, out_p, out_u = [], [], []
    for _ in range(max_chords):
        p, s, normal = hit(p, u, inside=True)
        weight = weight * np.exp(-mu_a * s)
        cos_h = np.sum(u * normal, axis=1)
        f = fresnel_ref(cos_h, n, 1.0)
        t, tir = refract_ref(u, -normal, n)
        leave = weight * (1.0 - f)
        keep = ~tir & (leave > 0)
        out_w.append(leave[keep])
        out_p.append(p[keep])
        out_u.append(t[keep])
        weight = weight * f
        u = u - 2 * cos_h[:, None] * normal
        active = weight > 1e-13 / n_rays  # rays still carrying weight (grazing ones bounce long)
        if not active.any():
            break
        weight, p, u = weight[active], p[active], u[active]
    return np.concatenate(out_w), np.concatenate(out_p), np.concatenate(out_u), weight.sum()


def _bin_like_mc(weights, points, dirs, shape):
    n_psi, n_mu, n_phi = shape
    y, z = points[:, 1], points[:, 2]
    psi = np.arctan2(-y, z)
    cell = np.mod(np.floor(psi / (2 * np.pi) * n_psi + 0.5), n_psi)  # cells centred on 2 pi k / n_psi
    normal = np.stack([np.zeros_like(y), y, z], axis=1) / np.hypot(y, z)[:, None]
    t = np.array([1.0, 0.0, 0.0])
    bvec = np.cross(normal, t)
    mu = np.sum(dirs * normal, axis=1)
    phi = np.arctan2(np.sum(dirs * bvec, axis=1), dirs @ t)
    hist, _ = np.histogramdd(
        np.stack([cell, mu, phi], axis=1),
        bins=[np.arange(n_psi + 1) - 0.5, np.linspace(0, 1, n_mu + 1), np.linspace(-np.pi, np.pi, n_phi + 1)],
        weights=weights,
    )
    return hist


@pytest.mark.parametrize(
    "w_i, mu_a",
    [((0.0, 0.0, 1.0), 0.0), ((0.0, 0.0, 1.0), 1.5), ((0.6, 0.0, 0.8), 0.0), ((0.3, 0.5, 0.812404), 1.0)],
)
def test_bare_cylinder_exit_directions_match_ray_tracing(w_i, mu_a, fresnel_ref, refract_ref):
    n, radius, shape = 1.55, 1.0, (12, 5, 3)
    r = run_cylinder(mu_a, 0.0, n=n, radius=radius, photons=200_000, seed=21, direction=w_i, angular_bins=shape)
    w, p, u, lost = _trace_bare_cylinder(w_i, n, radius, mu_a, fresnel_ref, refract_ref)
    assert lost < 1e-6  # the series has converged
    ref = _bin_like_mc(w, p, u, shape)
    assert r.exited == pytest.approx(ref.sum(), abs=4 * r.u_exited + 1e-4)
    mc, u_mc = r.angular.exits, r.angular.u_exits
    # every bin within 4.5 computed standard errors (+ a small quadrature allowance)
    assert np.all(np.abs(mc - ref) <= 4.5 * u_mc + 2e-4)
    used = u_mc > 0
    chi2 = np.sum(((mc - ref)[used] / u_mc[used]) ** 2) / used.sum()
    assert chi2 < 2.0
    assert ref[~used].sum() < 1e-3  # no reference weight where the MC found nothing


def test_bare_cylinder_exit_fraction_analytic(fresnel_ref):
    """Perpendicular incidence: every internal hit has the entry angle; series in closed form.

    For impact parameter b (unit radius): sin(theta_i) = b, chord L = 2 cos(theta_t), and the
    exit fraction is (1 - F)^2 a / (1 - F a) with a = exp(-mu_a L), averaged over b.
    """
    n, mu_a = 1.4, 0.7
    r = run_cylinder(mu_a, 0.0, n=n, radius=1.0, photons=300_000, seed=4, direction=(0, 0, 1))
    b = (np.arange(400_000) + 0.5) / 400_000 * 2 - 1
    cos_i = np.sqrt(1 - b * b)
    f = fresnel_ref(cos_i, 1.0, n)
    a = np.exp(-mu_a * 2 * np.sqrt(1 - (b / n) ** 2))
    expected = np.mean((1 - f) ** 2 * a / (1 - f * a))
    assert abs(r.exited - expected) < 4 * r.u_exited
    assert abs(r.specular - np.mean(f)) < 4 * np.std(f) / math.sqrt(r.photons)
    assert abs(r.energy.entered - r.exited - r.absorbed) < 1e-10  # no roulette, no cap here


def test_cylinder_bookkeeping_and_point_source():
    r = run_cylinder(0.0, 30.0, g=0.8, n=1.557, radius=1.0, photons=50_000, seed=8, source="point",
                     direction=(0.0, 0.5, 0.8660254))
    assert r.absorbed == 0.0 and r.capped == 0
    assert r.exited == pytest.approx(r.energy.entered, rel=1e-12)
    r2 = run_cylinder(3.0, 30.0, g=0.8, n=1.557, radius=1.0, photons=50_000, seed=8, weight_threshold=0.05,
                      angular_bins=(8, 4, 4))
    e = r2.energy
    assert abs(e.residual) < 1e-10
    assert e.roulette_killed > 0
    assert e.u_roulette_balance > 0 and abs(e.roulette_balance) < 4 * e.u_roulette_balance
    assert r2.angular.exits.sum() == pytest.approx(r2.exited, rel=1e-12)


def test_cylinder_symmetry_of_exit_azimuth():
    """Beam from +z: exits are mirror-symmetric in psi (psi -> -psi); the lit half dominates."""
    r = run_cylinder(1.0, 10.0, g=0.5, n=1.5, radius=1.0, photons=200_000, seed=2, angular_bins=(8, 1, 1))
    per_psi = r.angular.exits[:, 0, 0]
    u = r.angular.u_exits[:, 0, 0]
    mirrored = np.roll(per_psi[::-1], 1)  # cell k (centre 45k deg) <-> cell -k
    assert np.all(np.abs(per_psi - mirrored) < 4 * np.hypot(u, mirrored * 0 + np.roll(u[::-1], 1)))
    # two cells of 180 deg: cell 0 is exactly the lit half |psi| < 90 deg. For this optically
    # thick fiber (mu_t R = 11, albedo 0.91) more than 90 % of the exiting light must leave
    # there (a sign error in psi or in the exit normal would put it below 10 %).
    half = run_cylinder(1.0, 10.0, g=0.5, n=1.5, radius=1.0, photons=200_000, seed=3, angular_bins=(2, 1, 1))
    lit = half.angular.exits[0, 0, 0] / half.exited
    u_lit = half.angular.u_exits[0, 0, 0] / half.exited
    assert lit - 4 * u_lit > 0.90


@pytest.mark.parametrize("w_i", [(0.0, 0.0, 1.0), (0.3, -0.4, 0.866025)], ids=["normal", "oblique"])
def test_fiber_routes_without_scatterers_give_the_bare_cylinder(w_i, fresnel_ref, refract_ref):
    """No scatterers: the fiber's volume term at its top cell is the bare dielectric cylinder's
    refracted light (all internal-reflection orders), here traced deterministically; both the
    binned beam route and the next-event route (whose ranged outputs bin unscattered exits)
    must reproduce it with the normalisation R = (exit fraction) 2 |w_perp| / (dpsi Omega_proj)."""
    from simulate.fiber import Fiber, range_outputs, volume_brdf
    from simulate.media.medium import HGMedium

    n, radius, mu_a, shape = 1.55, 1.0, 0.3, (6, 4, 4)
    w = np.asarray(w_i) / np.linalg.norm(w_i)
    wts, pts, dirs, lost = _trace_bare_cylinder(w, n, radius, mu_a, fresnel_ref, refract_ref)
    assert lost < 1e-6
    ref = _bin_like_mc(wts, pts, dirs, shape)[0]  # cell 0: the top cell, |psi| < 30 deg
    mu_e = np.linspace(0, 1, shape[1] + 1)
    phi_e = np.linspace(-np.pi, np.pi, shape[2] + 1)
    cells = [(i, j) for i in range(shape[1]) for j in range(shape[2]) if ref[i, j] > 2e-4]
    assert len(cells) >= 1  # the bare cylinder sends light back through its top cell
    fiber = Fiber(radius_um=radius, n_host=n, medium=HGMedium(mu_s=0.0, mu_a=mu_a, g=0.0), roughness=0.2,
                  cell_width_deg=60.0)
    out = range_outputs([mu_e[i] for i, _ in cells], [mu_e[i + 1] for i, _ in cells],
                        [phi_e[j] for _, j in cells], [phi_e[j + 1] for _, j in cells], fiber.half_width)
    omega = 0.5 * (out[:, 4] ** 2 - out[:, 3] ** 2) * (out[:, 6] - out[:, 5])
    scale = 2 * math.hypot(w[1], w[2]) / (2 * fiber.half_width) / omega
    expected = np.array([ref[i, j] for i, j in cells]) * scale
    for method in ("beam", "nee"):
        est = volume_brdf(fiber, np.tile(w, (len(cells), 1)), None, [500.0], method=method, outputs=out,
                          target_rel_err=0.01, seed=4)
        z = (est.R[:, 0] - expected) / est.u_R[:, 0]
        assert np.all(np.abs(z) < 4.5), (method, z)
