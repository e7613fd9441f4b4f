"""Scatterers where they sit: a fiber whose scatterers fill only a skin (or a core), the rest clear, against an
independent analog Monte Carlo that marches each free path's optical depth across the circles exactly (the kernel
takes null collisions instead); with a ring dye at the same time and with re-weighted targets; the limits and the
uniform profile's bit-for-bit identity."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import run_cylinder
from simulate.montecarlo import tallies as T
from simulate.montecarlo.transport import (
    ParameterError,
    SpectralTargets,
    execute,
    make_control,
    make_inputs,
    medium_row,
)


def _hg_turn(u: np.ndarray, g: float, rng: np.random.Generator) -> np.ndarray:
    """New unit directions after Henyey-Greenstein scattering (the textbook inverse CDF, a uniform azimuth)."""
    m = u.shape[0]
    xi = rng.random(m)
    if g == 0.0:
        ct = 2.0 * xi - 1.0
    else:
        ct = (1.0 + g * g - ((1.0 - g * g) / (1.0 - g + 2.0 * g * xi)) ** 2) / (2.0 * g)
    ct = np.clip(ct, -1.0, 1.0)
    st = np.sqrt(1.0 - ct * ct)
    phi = 2.0 * math.pi * rng.random(m)
    helper = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(u, e1)
    v = ct[:, None] * u + st[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    return v / np.linalg.norm(v, axis=1)[:, None]


def _roots(p: np.ndarray, u: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """The two distances along ``u`` from ``p`` to the circle of radius ``r`` in the cross-section (NaN: none)."""
    q = u[:, 1] ** 2 + u[:, 2] ** 2
    h = p[:, 1] * u[:, 1] + p[:, 2] * u[:, 2]
    c = p[:, 1] ** 2 + p[:, 2] ** 2 - r * r
    disc = h * h - q * c
    root = np.sqrt(np.where(disc > 0.0, disc, np.nan))
    return (-h - root) / q, (-h + root) / q


def _reference(w_i, n: float, radius: float, circles: list[float], mu_a: list[float], mu_s: list[float], g: float,
               photons: int, seed: int, fresnel, refract) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Analog Monte Carlo of a parallel beam on a cylinder of shells (numpy, written for this test).

    ``circles``: the radii between shells, increasing; shell ``k`` (``k`` circles inside it) has ``mu_a[k]`` and
    ``mu_s[k]``. Each free path's optical depth ``tau ~ Exp(1)`` is spent segment by segment up to the next
    circle or the surface (the exact chord lengths); a collision absorbs with probability ``mu_a / mu_t`` or
    scatters (Henyey-Greenstein); the surface reflects with the Fresnel probability. Returns the fractions of
    the launched photons that exit on the lit side (``z > 0``) and on the far side, their binomial standard
    errors, and the absorbed fraction and its standard error.
    """
    rng = np.random.default_rng(seed)
    d = -np.asarray(w_i, float) / np.linalg.norm(w_i)
    e = np.cross([1.0, 0.0, 0.0], d)
    e /= np.linalg.norm(e)
    b = radius * (2.0 * rng.random(photons) - 1.0)
    p = b[:, None] * e[None, :] - 10.0 * radius * d[None, :]
    u = np.repeat(d[None, :], photons, axis=0)
    t0, _ = _roots(p, u, radius)
    p = p + t0[:, None] * u
    normal = np.zeros_like(p)
    normal[:, 1:] = p[:, 1:] / radius
    entered = rng.random(photons) >= fresnel(-np.sum(u * normal, axis=1), 1.0, n)
    p, u = p[entered], refract(u[entered], normal[entered], 1.0 / n)[0]
    tau = rng.exponential(size=p.shape[0])
    mu_a_k, mu_s_k = np.asarray(mu_a, float), np.asarray(mu_s, float)
    edges = np.asarray(circles, float)
    exited = np.zeros(2, dtype=np.int64)
    absorbed = 0
    eps = 1e-9 * radius
    for _ in range(100_000):
        if p.shape[0] == 0:
            break
        _, s_b = _roots(p, u, radius)
        s_b = np.nan_to_num(s_b, nan=0.0)
        seg = s_b.copy()
        for r in edges:
            for t in _roots(p, u, r):
                seg = np.where((t > eps) & (t < seg), t, seg)
        mid = p + 0.5 * seg[:, None] * u
        shell = np.searchsorted(edges, np.hypot(mid[:, 1], mid[:, 2]))
        mu_t = mu_a_k[shell] + mu_s_k[shell]
        with np.errstate(divide="ignore"):
            need = np.where(mu_t > 0.0, tau / np.where(mu_t > 0.0, mu_t, 1.0), np.inf)
        collide = need < seg
        step = np.where(collide, need, seg)
        p = p + step[:, None] * u
        tau = np.where(collide, rng.exponential(size=tau.size), tau - mu_t * seg)
        keep = np.ones(p.shape[0], dtype=bool)
        # collisions: absorbed or scattered
        xi = rng.random(p.shape[0])
        dead = collide & (xi * mu_t < mu_a_k[shell])
        absorbed += int(dead.sum())
        keep &= ~dead
        turn = collide & ~dead
        if turn.any():
            u[turn] = _hg_turn(u[turn], g, rng)
        # the surface: Fresnel reflection or exit
        hit = ~collide & (seg >= s_b)
        if hit.any():
            nrm = np.zeros((int(hit.sum()), 3))
            nrm[:, 1:] = p[hit, 1:] / np.hypot(p[hit, 1], p[hit, 2])[:, None]
            p[hit, 1:] = nrm[:, 1:] * radius
            cos_h = np.sum(u[hit] * nrm, axis=1)
            reflect = rng.random(nrm.shape[0]) < fresnel(cos_h, n, 1.0)
            u_hit = u[hit]
            u_hit[reflect] = u_hit[reflect] - 2.0 * cos_h[reflect, None] * nrm[reflect]
            u[hit] = u_hit
            out = np.flatnonzero(hit)[~reflect]
            exited += [int(np.sum(p[out, 2] > 0.0)), int(np.sum(p[out, 2] <= 0.0))]
            keep[out] = False
        p, u, tau = p[keep], u[keep], tau[keep]
    else:
        raise AssertionError("reference walk did not end")
    fe, fa = exited / photons, absorbed / photons
    return fe, np.sqrt(fe * (1 - fe) / photons), fa, math.sqrt(fa * (1 - fa) / photons)


KW = dict(n=1.5, radius=1.0, g=0.6, direction=(0.4, 0.2, math.sqrt(1.0 - 0.16 - 0.04)))


@pytest.mark.parametrize("kind, a", [("skin", 0.7), ("core", 0.5)])
def test_scatterers_in_a_skin_or_core_are_the_independent_marching_reference(kind, a, fresnel_ref, refract_ref):
    """The light leaving on the lit side and on the far side, and the absorbed part, of a fiber with scatterers in
    a skin (a clear core) or a core (a clear skin), absorbing everywhere, against the reference that spends each
    optical depth across the circle exactly."""
    mu_a, mu_s = 0.4, 6.0
    r = run_cylinder(mu_a, mu_s, photons=60_000, seed=5, scatterer_profile=(kind, a), angular_bins=(2, 1, 1), **KW)
    assert r.angular is not None
    got, u_got = r.angular.exits.ravel(), r.angular.u_exits.ravel()      # psi bins about the lit top and the bottom
    shells = [0.0, mu_s] if kind == "skin" else [mu_s, 0.0]
    fe, u_fe, fa, u_fa = _reference(KW["direction"], KW["n"], 1.0, [a], [mu_a, mu_a], shells, KW["g"], 60_000, 17,
                                    fresnel_ref, refract_ref)
    assert np.all(np.abs(got - fe) < 4.0 * np.hypot(u_got, u_fe)), (got, fe)
    # the kernel's absorbed part (implicit capture) varies less than its exited part: that error bounds it
    assert abs(r.absorbed - fa) < 4.0 * math.hypot(r.u_exited, u_fa), (r.absorbed, fa)
    # the profile matters: the same scatterers everywhere send far less light through to the far side
    uniform = run_cylinder(mu_a, mu_s, photons=60_000, seed=5, angular_bins=(2, 1, 1), **KW)
    assert uniform.angular is not None
    assert fe[1] - uniform.angular.exits.ravel()[1] > 20.0 * math.hypot(u_fe[1], uniform.angular.u_exits.ravel()[1])


def _white_run(mu_s_walk: float, mu_s_target: float, mu_a_dye: float, dye: tuple[int, float],
               scat: tuple[int, float], photons: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The fiber walk as the fiber models run it: white (``mu_a = 0``) at ``mu_s_walk``, re-weighted to a target
    of ``mu_s_target`` whose dye ``mu_a_dye`` sits in ``dye``; the fractions exiting on the lit and the far side
    and their standard errors."""
    medium, phase = medium_row(0.0, mu_s_walk, KW["g"], None, KW["n"])
    medium[K.M_DYE_PROFILE], medium[K.M_DYE_RADIUS] = dye
    medium[K.M_SCAT_PROFILE], medium[K.M_SCAT_RADIUS] = scat
    w = np.asarray(KW["direction"], float)
    src = np.array([float(G.BEAM), *w])
    targets = SpectralTargets(mu_a=np.array([mu_a_dye]), mu_s=np.array([mu_s_target]), phases=[phase],
                              same_phase=np.array([True]), mu_a_dye=np.array([mu_a_dye]))
    inp = make_inputs(G.CYLINDER, np.array([1.0]), src, medium, phase, make_control(), T.CYLINDER_DIRECTIONS,
                      np.array([2.0, 1.0, 1.0, 1.0, 1.0]), targets=targets)
    _, bins, _ = execute(inp, photons, seed, None, 10_000)
    s, s2 = bins[:, 0], bins[:, 1]
    return s / photons, np.sqrt(np.clip(s2 / photons - (s / photons) ** 2, 0.0, None) / (photons - 1))


def test_a_skin_with_a_ring_dye_and_reweighted_scattering_is_the_reference(fresnel_ref, refract_ref):
    """Scatterers in a skin beyond 0.6 R and the dye in a ring beyond 0.8 R (three shells), walked white at a
    ``mu_s`` 20 % below the target's and re-weighted: the clear core's free-path factor takes back the
    scattering difference (``catch_up_placed``); against the marching reference at the target's own medium."""
    mu_s, dye = 5.0, 1.5
    got, u_got = _white_run(0.8 * mu_s, mu_s, dye, (K.DYE_RING, 0.8), (K.SCAT_SKIN, 0.6), 60_000, 9)
    fe, u_fe, _, _ = _reference(KW["direction"], KW["n"], 1.0, [0.6, 0.8], [0.0, 0.0, dye], [0.0, mu_s, mu_s],
                                KW["g"], 60_000, 23, fresnel_ref, refract_ref)
    assert np.all(np.abs(got - fe) < 4.0 * np.hypot(u_got, u_fe)), (got, fe)
    # and a core of scatterers under a dyed ring (the dye in the clear skin)
    got, u_got = _white_run(1.2 * mu_s, mu_s, dye, (K.DYE_RING, 0.8), (K.SCAT_CORE, 0.8), 60_000, 9)
    fe, u_fe, _, _ = _reference(KW["direction"], KW["n"], 1.0, [0.8], [0.0, dye], [mu_s, 0.0],
                                KW["g"], 60_000, 29, fresnel_ref, refract_ref)
    assert np.all(np.abs(got - fe) < 4.0 * np.hypot(u_got, u_fe)), (got, fe)


def test_the_limits_are_the_uniform_fiber_and_the_clear_fiber():
    """A skin as deep as the fiber (a tiny clear core) or a core under a vanishing skin is the uniform fiber;
    a vanishing skin is the clear fiber (same absorption, no scatterers)."""
    kw = dict(photons=40_000, seed=13, **KW)
    uniform = run_cylinder(0.3, 4.0, **kw)
    clear = run_cylinder(0.3, 0.0, **kw)
    for profile in (("skin", 0.01), ("core", 0.999)):
        r = run_cylinder(0.3, 4.0, scatterer_profile=profile, **kw)
        assert abs(r.exited - uniform.exited) < 4.0 * math.hypot(r.u_exited, uniform.u_exited), profile
    thin = run_cylinder(0.3, 4.0, scatterer_profile=("skin", 0.9999), **kw)
    assert abs(thin.exited - clear.exited) < 4.0 * math.hypot(thin.u_exited, clear.u_exited)


def test_the_uniform_walk_is_unchanged_bit_for_bit():
    """Without a scatterer profile a run walks the loops it walked before, number for number: the same run with
    the profile's slots left at their uniform values, and the profiled flavour itself when its skin reaches the
    axis (no null collision can happen, every random number is drawn as before)."""
    kw = dict(photons=20_000, seed=3, angular_bins=(4, 2, 3), **KW)
    a = run_cylinder(0.3, 4.0, **kw)
    b = run_cylinder(0.3, 4.0, scatterer_profile=("skin", 1e-300), **kw)
    assert a.exited == b.exited and a.absorbed == b.absorbed and a.events_per_photon == b.events_per_photon
    assert a.angular is not None and b.angular is not None
    np.testing.assert_array_equal(a.angular.exits, b.angular.exits)


@pytest.mark.parametrize("bad", [("skin", 1.0), ("skin", 0.0), ("ring", 0.5), ("core",), "skin"])
def test_a_bad_scatterer_profile_is_named(bad):
    with pytest.raises(ParameterError, match="scatterer_profile"):
        run_cylinder(1.0, 1.0, n=1.5, photons=10, scatterer_profile=bad)


def test_next_event_estimators_and_slabs_refuse_the_profile():
    medium, phase = medium_row(0.1, 1.0, 0.5, None, 1.5)
    medium[K.M_SCAT_PROFILE], medium[K.M_SCAT_RADIUS] = K.SCAT_SKIN, 0.5
    src = np.array([float(G.BEAM), 0.0, 0.0, 1.0])
    with pytest.raises(ParameterError, match="scatterer profile"):
        make_inputs(G.SLAB, np.array([1.0]), src, medium, phase, make_control())
    with pytest.raises(ParameterError, match="exit tallies only"):
        make_inputs(G.CYLINDER, np.array([1.0]), src, medium, phase, make_control(), T.NONE, None,
                    T.V_CYLINDER_NEE, np.zeros((1, 8)))
