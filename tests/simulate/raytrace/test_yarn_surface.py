"""The yarn surface made of fibers (FiberSurface(surface="fibers"), docs/physics.md 6 "Yarn surface").

References from outside the tracer: the fiber layer's surface term by quadrature over the
cross-section (:func:`simulate.fabric.fiberlayer.surface_Q`, the summation's), the lit part of a
layer from :func:`simulate.fabric.fiberlayer.visibility`, energy conservation, reciprocity.
"""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numba
import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import fiberlayer as FL
from simulate.geometry import weave
from simulate.geometry.mesh import mesh as weave_mesh
from simulate.geometry.validation import flat_mesh
from simulate.media.medium import HGMedium
from simulate.raytrace.shading import _layer_point


def _dirs(theta_deg, phi_deg=0.0):
    t = np.radians(np.atleast_1d(theta_deg))
    p = np.radians(np.broadcast_to(phi_deg, t.shape))
    return np.column_stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@pytest.fixture(scope="module")
def white_table():
    """A non-absorbing HG fiber's table, rows scaled to conserve energy exactly (as in test_woven)."""
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.0, g=0.5), 0.3, 10.0)
    tab = W.yarn_table(fib, [550.0], photons_per_row=4000, seed=11, threads=1)
    exact = tab.tau * tab.c_bar / tab.T.sum(axis=2)[..., 0]
    return dataclasses.replace(tab, T=tab.T * exact[:, :, None, None])


@pytest.fixture(scope="module")
def plain():
    return weave.Weave(np.array([[1, 0], [0, 1]]), spacing_um=300.0, width_um=250.0, height_um=100.0,
                       points_per_span=6, sides=12)


def test_surface_must_be_tube_or_fibers_and_spacing_at_least_touching(white_table):
    with pytest.raises(ValueError, match="surface must be"):
        W.FiberSurface(white_table, 0.3, 1.5, surface="fuzz")
    with pytest.raises(ValueError, match="spacing_ratio"):
        W.FiberSurface(white_table, 0.3, 1.5, surface="fibers", spacing_ratio=0.8)
    assert W.FiberSurface(white_table, 0.3, 1.5).layer_d == 0.0
    assert W.FiberSurface(white_table, 0.3, 1.5, "fibers", 1.25).layer_d == 2.5


@numba.njit(cache=False)
def _lit_points(uy, uz, d, n, seed):
    np.random.seed(seed)
    out = np.zeros((n, 3))
    for i in range(n):
        a, b, c = _layer_point(uy, uz, d)
        out[i, 0], out[i, 1], out[i, 2] = a, b, 1.0 if c else 0.0
    return out


@pytest.mark.parametrize("theta, spacing", [(0.0, 1.0), (55.0, 1.0), (30.0, 1.5), (75.0, 1.2)])
def test_lit_points_are_the_layers_shadowed_cross_section(theta, spacing):
    """The beam's points on the fibers: distributed as the lit projected width ``vis_i (w.n)_+``
    (fiberlayer's visibility, an independent 2-D test) -- chi-square over 24 azimuth bins -- and
    the fraction falling through the gaps is ``1 - 2R / d`` at normal incidence."""
    w = _dirs(theta, 90.0)[0]               # in the cross-section plane (b = y, n = z)
    n = 200_000
    pts = _lit_points(-w[1], -w[2], 2.0 * spacing, n, 7)
    hit = pts[:, 2] > 0
    psi = np.arctan2(-pts[hit, 0], pts[hit, 1])          # n(psi) = (-sin psi, cos psi)
    edges = np.linspace(-math.pi, math.pi, 25)
    counts = np.histogram(psi, edges)[0]
    fine = np.linspace(-math.pi, math.pi, 24 * 400 + 1)
    mid = 0.5 * (fine[1:] + fine[:-1])
    lit = FL.visibility(w[None], mid, 2.0 * spacing)[0] * np.clip(-np.sin(mid) * w[1] + np.cos(mid) * w[2], 0, None)
    p = lit.reshape(24, 400).sum(axis=1)
    p = p / p.sum()
    expect = p * hit.sum()
    ok = expect > 5
    chi2 = float(np.sum((counts[ok] - expect[ok]) ** 2 / expect[ok]))
    dof = int(ok.sum()) - 1
    assert chi2 < dof + 5 * math.sqrt(2 * dof), (chi2, dof)
    assert counts[~ok].sum() < 20
    # every ray of the beam meets a fiber or a gap: the fibers take the lit width per period
    width = lit.sum() * (fine[1] - fine[0])                 # int vis (w.n)+ dpsi, radius 1
    frac = width / (2.0 * spacing * w[2])
    assert abs(hit.mean() - frac) < 4 * math.sqrt(max(frac * (1 - frac), 0.0) / n) + 1e-3
    if theta == 0.0:
        assert abs(frac - 1.0 / spacing) < 1e-3


@pytest.mark.parametrize("spacing", [1.0, 1.4])
def test_flat_fiber_layer_surface_equals_the_summations_quadrature(spacing, white_table):
    """On a flat plane of fibers along x whose volume returns nothing, the traced fabric is the
    fiber layer's surface term alone: ``beta = pi Q_surf / (d cos_i cos_o)`` with shadowing and
    masking (fiberlayer.surface_Q: a quadrature over the cross-section). Escaping rays carry the
    layer's surface albedo, the same quadrature integrated over the hemisphere."""
    dark = dataclasses.replace(white_table, T=np.zeros_like(white_table.T))
    mat = W.FiberSurface(dark, 0.35, 1.5, surface="fibers", spacing_ratio=spacing)
    fib = SimpleNamespace(radius_um=1.0, roughness=0.35, n_host=1.5)
    w_in = _dirs(40.0, 60.0)[0]
    det = _dirs([0, 10, 30, 45, 60, 40], [0, 200, 90, 240, 20, 60 + 180])
    res = W.trace(flat_mesh(), mat, w_in, det, target_rel_err=0.004, max_rays=2_000_000, seed=3, chunk=8192)
    d = 2.0 * spacing
    q = FL.surface_Q(fib, w_in, det, d, d, 720)
    ref = math.pi * q / (d * w_in[2] * det[:, 2])
    z = (res.beta[:, 0] - ref) / res.u_beta[:, 0]
    assert np.all(np.abs(z) < 4.0), (res.beta[:, 0], ref, z)
    # the escaping rays: the unmasked surface albedo by quadrature over the hemisphere
    mu = (np.arange(30) + 0.5) / 30
    ph = (np.arange(72) + 0.5) * 2 * math.pi / 72
    M, P = np.meshgrid(mu, ph, indexing="ij")
    s = np.sqrt(1 - M ** 2)
    wo = np.column_stack([(s * np.cos(P)).ravel(), (s * np.sin(P)).ravel(), M.ravel()])
    albedo = float(FL.surface_Q(fib, w_in, wo, d, d, 360).sum()) * (1 / 30) * (2 * math.pi / 72) / (d * w_in[2])
    # (dOmega = dmu dphi; the quadrature's own error is well below the tolerance)
    u = float(res.info["u_reflected_plus_transmitted"][0])
    assert abs(res.reflected[0] - albedo) < 4 * u + 0.01 * albedo, (res.reflected[0], albedo, u)


@pytest.mark.parametrize("spacing", [1.0, 1.3])
def test_smooth_non_absorbing_fiber_surface_conserves_energy(spacing, plain, white_table):
    """Smooth fibers, non-absorbing volume, faceted tube: every ray keeps weight 1 -- reflected
    from a fiber (F), transmitted into it (1 - F), reflected towards a neighbour or fallen through
    a gap (into the volume): ``R + T = 1`` exactly."""
    mesh = weave_mesh(plain)
    mat = W.FiberSurface(white_table, 0.0, 1.5, surface="fibers", spacing_ratio=spacing)
    for theta in (0.0, 50.0):
        res = W.trace(mesh, mat, _dirs(theta, 20.0)[0], _dirs([0, 30]), target_rel_err=0.02, max_rays=16384,
                      seed=2, chunk=1024, normals="face")
        total = res.reflected + res.transmitted
        u = np.asarray(res.info["u_reflected_plus_transmitted"])
        assert res.info["lost_rays"] == 0 and res.info["killed_at_max_bounces"] == 0
        assert abs(total[0] - 1.0) < 4 * u[0] + 1e-9, (theta, total, u)
        assert u[0] < 0.02


def test_fiber_surface_is_reciprocal_on_the_weave(plain):
    """Helmholtz reciprocity of the traced weave with the fibers' surface (rough, absorbing):
    ``beta(i -> o) = pi f(i, o)`` equals ``beta(o -> i)`` within the errors (faceted tube: the
    shading-normal rule is not reciprocal by construction). Without the volume (a dark table) the
    surface alone, a sharper test of its shadowing/masking pair."""
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.35, 10.0)
    tab = W.yarn_table(fib, [550.0], photons_per_row=4000, seed=12, threads=1)
    mesh = weave_mesh(plain)
    a, b = _dirs(20.0, 30.0)[0], _dirs(55.0, 200.0)[0]
    for t in (tab, dataclasses.replace(tab, T=np.zeros_like(tab.T))):
        mat = W.FiberSurface(t, 0.35, 1.5, surface="fibers")
        ab = W.trace(mesh, mat, a, b[None], target_rel_err=0.008, max_rays=400_000, seed=21, chunk=4096,
                     normals="face")
        ba = W.trace(mesh, mat, b, a[None], target_rel_err=0.008, max_rays=400_000, seed=22, chunk=4096,
                     normals="face")
        u = math.hypot(ab.u_beta[0, 0], ba.u_beta[0, 0])
        assert abs(ab.beta[0, 0] - ba.beta[0, 0]) < 4 * u, (ab.beta[0, 0], ba.beta[0, 0], u)


def test_the_pile_dilutes_the_fibers_scatterers_and_dye_to_the_packing_fraction():
    """simulate.raytrace.pile: phi times the scatterers and the host absorption, everything else the fiber's."""
    from simulate.media.medium import MieMedium, Spectrum
    from simulate.raytrace.pile import pile_fiber, pile_medium

    hg = HGMedium(mu_s=0.8, mu_a=0.01, g=0.5)
    p = pile_medium(hg, 0.6)
    assert (p.mu_s, p.mu_a, p.g) == (pytest.approx(0.48), pytest.approx(0.006), 0.5)
    dye = Spectrum(np.array([400.0, 700.0]), np.array([0.5, 1e-4]), "dye")
    mie = MieMedium(n_host=1.557, particle_n=2.7, radius_um=0.1, volume_fraction=0.05, mu_a_host_per_um=dye)
    pm = pile_medium(mie, 0.9)
    assert pm.volume_fraction == pytest.approx(0.045) and pm.number_density == pytest.approx(0.9 * mie.number_density)
    np.testing.assert_allclose(pm.mu_a_host_per_um(np.array([400.0, 550.0])), 0.9 * dye(np.array([400.0, 550.0])))
    assert pm.n_host == mie.n_host and pm.particle_n == mie.particle_n
    fib = F.Fiber(10.0, 1.557, mie, 0.35, 10.0)
    yarn = pile_fiber(fib, 79.0, 0.9)
    assert (yarn.radius_um, yarn.n_host, yarn.roughness, yarn.cell_width_deg) == (79.0, 1.557, 0.35, 10.0)
    with pytest.raises(ValueError, match="packing_fraction"):
        pile_medium(hg, 0.0)


def test_yarns_are_made_of_fibers_with_a_woven_structure_only(plain):
    """Without [structure] (as the summation's carpet) and for a felt's tubes (each one fiber) the yarn
    stays the tube with the fiber's table; a woven [structure] makes it of fibers, at its packing."""
    from simulate.fabric import structure as ST
    from simulate.raytrace.estimate import yarn_model

    mesh = weave_mesh(plain)
    assert yarn_model(mesh, None) == ("tube", "fiber", 1.0, ST.CLOSE_PACKING)
    assert yarn_model(mesh, ST.StructureSpec(kind="nonwoven")) == ("tube", "fiber", 1.0, ST.CLOSE_PACKING)
    spec = ST.StructureSpec(packing_fraction=0.6)
    surf, vol, spacing, packing = yarn_model(mesh, spec)
    assert (surf, vol, packing) == ("fibers", "pile", 0.6) and spacing == pytest.approx(spec.spacing_ratio)
    assert yarn_model(mesh, spec, surface="tube", volume="fiber")[:2] == ("tube", "fiber")
    with pytest.raises(ValueError, match="volume must be"):
        yarn_model(mesh, spec, volume="felt")


def test_held_scattering_groups_stay_within_their_bound_and_keep_old_table_keys():
    """The pile's table walks wavelengths together only within ``held_log_mu_s`` of the walked one
    (consecutive, covering all); the held table has its own cache key, the re-weighted keys are unchanged."""
    from simulate.raytrace.yarn import held_groups, table_key

    mu_s = 0.8 * (np.arange(390.0, 711.0, 10.0) / 550.0) ** -1.3
    g = np.full(mu_s.size, 0.55)
    optics = SimpleNamespace(mu_s=mu_s, g=g)
    groups = held_groups(optics, 0.05)  # type: ignore[arg-type]
    assert np.array_equal(np.concatenate(groups), np.arange(mu_s.size))
    for gr in groups:
        ref = gr[len(gr) // 2]
        assert np.all(np.abs(np.log(mu_s[gr] / mu_s[ref])) <= 0.05)
    assert len(groups) > 3 and max(len(gr) for gr in groups) > 1
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.35, 10.0)
    plain_key = table_key(fib, [550.0])
    assert table_key(fib, [550.0], held_log_mu_s=0.0) == plain_key
    assert table_key(fib, [550.0], held_log_mu_s=0.05) != plain_key
