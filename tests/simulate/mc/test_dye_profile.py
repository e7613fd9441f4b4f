"""A dye where it sits: a clear cylinder whose dye absorbs only in a ring (or a core), against the closed form of
straight chords through an annulus and an independent ray trace; the uniform profile is the walk without one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.montecarlo import run_cylinder
from simulate.montecarlo.transport import ParameterError


def _annulus_closed_form(n: float, mu_a: float, a: float, kind: str, fresnel, m: int = 400_000) -> float:
    """Perpendicular incidence on a unit cylinder: a ray of impact parameter ``b`` refracts to ``sin t = b / n``
    and every chord inside keeps the distance ``d = |b| / n`` from the axis, so each crosses the core circle of
    radius ``a`` over ``2 sqrt(a^2 - d^2)`` and the ring over the rest of ``2 sqrt(1 - d^2)``; the exit fraction
    is ``(1 - F)^2 A / (1 - F A)`` with ``A = exp(-mu_a L_dyed)``, averaged over ``b``."""
    b = (np.arange(m) + 0.5) / m * 2.0 - 1.0
    f = fresnel(np.sqrt(1.0 - b * b), 1.0, n)
    d = np.abs(b) / n
    chord = 2.0 * np.sqrt(1.0 - d * d)
    core = 2.0 * np.sqrt(np.clip(a * a - d * d, 0.0, None))
    dyed = chord - core if kind == "ring" else core
    A = np.exp(-mu_a * dyed)
    return float(np.mean((1.0 - f) ** 2 * A / (1.0 - f * A)))


def _traced(w_i, n: float, mu_a: float, a: float, kind: str, fresnel, refract, n_rays: int = 200_000) -> float:
    """An independent ray trace of the parallel beam (any incidence) through the unit cylinder, Fresnel-split at
    every hit, each chord attenuated over the part of its length in the dyed region (the chord's roots with the
    circle of radius ``a`` in the cross-section, clipped to the chord)."""
    d = -np.asarray(w_i, float) / np.linalg.norm(w_i)
    e = np.cross([1.0, 0.0, 0.0], d)
    e /= np.linalg.norm(e)
    b = (np.arange(n_rays) + 0.5) / n_rays * 2.0 - 1.0
    p = b[:, None] * e[None, :] - 10.0 * d[None, :]
    u = np.repeat(d[None, :], n_rays, axis=0)

    def roots(p, u, r):
        q = u[:, 1] ** 2 + u[:, 2] ** 2
        h = p[:, 1] * u[:, 1] + p[:, 2] * u[:, 2]
        c = p[:, 1] ** 2 + p[:, 2] ** 2 - r * r
        disc = h * h - q * c
        root = np.sqrt(np.clip(disc, 0.0, None))
        return (-h - root) / q, (-h + root) / q, disc > 0

    t0, _, _ = roots(p, u, 1.0)
    p = p + t0[:, None] * u
    normal = np.zeros_like(p)
    normal[:, 1:] = p[:, 1:]
    cos_i = -np.sum(u * normal, axis=1)
    weight = (1.0 - fresnel(cos_i, 1.0, n)) / n_rays
    u, _ = refract(u, normal, 1.0 / n)
    out = 0.0
    for _ in range(300):
        _, s, _ = roots(p, u, 1.0)
        lo, hi, hit = roots(p, u, a)
        core = np.where(hit, np.clip(np.minimum(hi, s) - np.maximum(lo, 0.0), 0.0, None), 0.0)
        weight = weight * np.exp(-mu_a * (s - core if kind == "ring" else core))
        p = p + s[:, None] * u
        normal = np.zeros_like(p)
        normal[:, 1:] = p[:, 1:] / np.linalg.norm(p[:, 1:], axis=1)[:, None]
        cos_h = np.sum(u * normal, axis=1)
        f = fresnel(cos_h, n, 1.0)
        out += float(np.sum(weight * (1.0 - f)))
        weight = weight * f
        u = u - 2.0 * cos_h[:, None] * normal
        if weight.sum() < 1e-12:
            break
    return out


@pytest.mark.parametrize("kind, a", [("ring", 0.8), ("core", 0.6)])
def test_a_clear_fiber_with_a_dyed_ring_or_core_is_the_annulus_closed_form(kind, a, fresnel_ref):
    n, mu_a = 1.5, 2.0
    r = run_cylinder(mu_a, 0.0, n=n, radius=1.0, photons=200_000, seed=7, direction=(0, 0, 1),
                     dye_profile=(kind, a))
    expected = _annulus_closed_form(n, mu_a, a, kind, fresnel_ref)
    assert abs(r.exited - expected) < 4.0 * r.u_exited + 1e-4, (r.exited, expected, r.u_exited)
    # the profile matters: the uniform dye of the same mu_a absorbs visibly more
    uniform = _annulus_closed_form(n, mu_a, 1e-9, "ring", fresnel_ref)
    assert r.exited > uniform + 10.0 * r.u_exited


def test_a_ring_dye_at_oblique_incidence_is_the_independent_ray_trace(fresnel_ref, refract_ref):
    n, mu_a, a = 1.51, 1.2, 0.75
    w_i = (0.5, 0.3, math.sqrt(1.0 - 0.25 - 0.09))
    r = run_cylinder(mu_a, 0.0, n=n, radius=1.0, photons=200_000, seed=3, direction=w_i, dye_profile=("ring", a))
    expected = _traced(w_i, n, mu_a, a, "ring", fresnel_ref, refract_ref)
    assert abs(r.exited - expected) < 4.0 * r.u_exited + 1e-4, (r.exited, expected, r.u_exited)


def test_a_ring_as_deep_as_the_fiber_is_the_uniform_dye_and_scatterers_see_the_profile():
    """A ring reaching (almost) the axis absorbs as the uniform dye (here with scatterers, so the walk collides);
    a thin ring in a scattering fiber absorbs less than the uniform dye."""
    kw = dict(n=1.5, radius=1.0, photons=100_000, seed=11, direction=(0, 0, 1), g=0.5)
    uniform = run_cylinder(0.8, 1.5, **kw)
    deep = run_cylinder(0.8, 1.5, dye_profile=("ring", 1e-9), **kw)
    thin = run_cylinder(0.8, 1.5, dye_profile=("ring", 0.9), **kw)
    assert abs(deep.exited - uniform.exited) < 4.0 * math.hypot(deep.u_exited, uniform.u_exited)
    assert thin.exited > uniform.exited + 10.0 * math.hypot(thin.u_exited, uniform.u_exited)


@pytest.mark.parametrize("bad", [("ring", 1.0), ("ring", 0.0), ("skin", 0.5), ("ring",)])
def test_a_bad_profile_is_named(bad):
    with pytest.raises(ParameterError, match="dye_profile"):
        run_cylinder(1.0, 0.0, n=1.5, photons=10, dye_profile=bad)


def test_the_felts_yarn_table_walks_the_profile():
    """The yarn table (the felt's exit rows, the rows runner): the same white walk with the dye in a ring reaching
    almost to the axis, or in a core under an almost vanishing skin, is the uniform dye's table to rounding of
    the tiny undyed part; a thin ring lets more light out of every row."""
    from simulate.fiber import Fiber
    from simulate.media.medium import HGMedium
    from simulate.raytrace.yarn import yarn_table

    def table(**profile):
        fiber = Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=0.05, mu_a=0.3, g=0.5), roughness=0.3,
                      **profile)
        t = yarn_table(fiber, [550.0], photons_per_row=2000, seed=3, threads=1, cache=False,
                       w_t_nodes=(0.0, 0.5), n_mu=2, n_phi=4)
        return t.T.sum(axis=2)[..., 0]          # each row's exit weight per photon

    uniform = table()
    np.testing.assert_allclose(table(dye_profile="ring", dye_depth_um=5.0 - 1e-6), uniform, rtol=1e-4)
    np.testing.assert_allclose(table(dye_profile="core", dye_depth_um=1e-6), uniform, rtol=1e-4)
    thin = table(dye_profile="ring", dye_depth_um=0.5)
    lit = uniform > 0
    assert np.all(thin[lit] > 1.5 * uniform[lit])
