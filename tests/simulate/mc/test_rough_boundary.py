"""The kernel's rough boundary (simulate.montecarlo.rough) against Walter et al.'s (2007) rough dielectric.

The sampled crossings -- one microfacet drawn with density D(h)(h.n), the weight (u.h) G1(u) / ((u.n)
(h.n)), Fresnel's choice, refraction or reflection about h, the masking G1(o) -- are binned by their
outgoing direction and compared, bin by bin, with a quadrature of the closed-form BSDF of the same
surface (Walter, Marschner, Li & Torrance 2007, eqs. 20-21 with the separable Smith G of eq. 23),
written here from the paper's formulas alone: the BTDF
``|i.h||o.h| / (|i.n||o.n|) n_o^2 (1 - F(i.h)) D G / (n_i (i.h) + n_o (o.h))^2`` and the BRDF
``F D G / (4 |i.n||o.n|)``. The comparison is within a few of each bin's computed standard errors.
Then the whole kernel: a clear slab with a rough boundary keeps its light (reflected + transmitted +
masking loss = 1) and tends to the smooth slab's Fresnel result as the slope goes to 0.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from scipy.special import erf

from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.rough import rough_cross, rough_entry
from simulate.montecarlo.scatter import phase_arrays
from simulate.montecarlo.transport import ParameterError, execute, make_control, make_inputs


@numba.njit(cache=False)
def _sample(ux, uy, uz, n1, n2, m_a, m_b, u):
    out = np.zeros((u.shape[0], 5))
    for k in range(u.shape[0]):
        ox, oy, oz, f, crossed = rough_cross(ux, uy, uz, 0.0, 0.0, 1.0, n1, n2, m_a, m_b, u[k, 0], u[k, 1], u[k, 2])
        out[k, 0] = ox
        out[k, 1] = oy
        out[k, 2] = oz
        out[k, 3] = f
        out[k, 4] = 1.0 if crossed else 0.0
    return out


def _fresnel(c, n1, n2):
    """Unpolarised Fresnel reflectance at incidence cosine ``c`` from index n1 into n2 (1 beyond TIR)."""
    s2 = (n1 / n2) ** 2 * (1.0 - c * c)
    ct = np.sqrt(np.clip(1.0 - s2, 0.0, None))
    rs = ((n1 * c - n2 * ct) / (n1 * c + n2 * ct)) ** 2
    rp = ((n1 * ct - n2 * c) / (n1 * ct + n2 * c)) ** 2
    return np.where(s2 >= 1.0, 1.0, 0.5 * (rs + rp))


def _beckmann(h, m_a, m_b):
    """Anisotropic Beckmann D(h) (slopes m_a along x, the fiber axis, and m_b along y), h [..., 3], n = z."""
    c = np.clip(np.abs(h[..., 2]), 1e-12, 1.0)
    sx = h[..., 0] / c
    sy = h[..., 1] / c
    return np.exp(-(sx * sx / (m_a * m_a) + sy * sy / (m_b * m_b))) / (math.pi * m_a * m_b * c ** 4)


def _g1(v, m_a, m_b):
    """Smith G1 of the anisotropic Beckmann surface for directions v [..., 3] (Heitz 2014, sec. 5.3)."""
    c = np.clip(np.abs(v[..., 2]), 1e-12, 1.0)
    p2 = np.clip(v[..., 0] ** 2 + v[..., 1] ** 2, 1e-30, None)
    m = np.sqrt((v[..., 0] ** 2 * m_a ** 2 + v[..., 1] ** 2 * m_b ** 2) / p2)
    a = c / (m * np.sqrt(np.clip(1 - c * c, 1e-30, None)))
    lam = 0.5 * (erf(a) - 1) + np.exp(-a * a) / (2 * a * math.sqrt(math.pi))
    return 1.0 / (1.0 + lam)


def _walter_density(i, o, n1, n2, m_a, m_b):
    """Outgoing power per unit solid angle ``f |o.n|`` for light arriving from direction ``i`` (both away
    from the surface, ``n = (0, 0, 1)`` on the incident side, ``i.n > 0``); ``o`` [..., 3]."""
    ci = i[2]
    co = o[..., 2]
    gi = _g1(i, m_a, m_b)
    go = _g1(o, m_a, m_b)
    refl = co > 0
    # reflection
    hr = o + i
    hr = hr / np.linalg.norm(hr, axis=-1, keepdims=True)
    ih_r = hr @ i
    fr = _fresnel(np.abs(ih_r), n1, n2) * _beckmann(hr, m_a, m_b) * gi * go / (4 * ci * np.abs(co))
    # refraction: h_t = -(n1 i + n2 o), turned to the incident side
    ht = -(n1 * i + n2 * o)
    ht = ht / np.linalg.norm(ht, axis=-1, keepdims=True)
    ht = np.where(ht[..., 2:3] < 0, -ht, ht)
    ih = ht @ i
    oh = np.sum(o * ht, axis=-1)
    denom = (n1 * ih + n2 * oh) ** 2
    ok = (ih > 0) & (oh < 0)
    ft = (np.abs(ih) * np.abs(oh) / (ci * np.abs(co)) * n2 ** 2 * (1 - _fresnel(np.clip(ih, 0, 1), n1, n2))
          * _beckmann(ht, m_a, m_b) * gi * go / np.where(ok, denom, 1.0))
    ft = np.where(ok, ft, 0.0)
    return np.where(refl, fr, ft) * np.abs(co)


N_MU, N_PHI = 10, 6


def _bins(o):
    """(cos theta_o from the macro normal, |phi| from the plane of incidence): 2 sides x N_MU x N_PHI."""
    side = (o[:, 2] < 0).astype(int)  # 0 reflected side (the incident side), 1 transmitted
    mu = np.minimum((np.abs(o[:, 2]) * N_MU).astype(int), N_MU - 1)
    phi = np.minimum((np.abs(np.arctan2(o[:, 1], o[:, 0])) / math.pi * N_PHI).astype(int), N_PHI - 1)
    return (side * N_MU + mu) * N_PHI + phi


def _quadrature(i, n1, n2, m_a, m_b, sub=60):
    out = np.zeros(2 * N_MU * N_PHI)
    for side in (0, 1):
        for a in range(N_MU):
            mu = (a + (np.arange(sub) + 0.5) / sub) / N_MU
            for b in range(N_PHI):
                ph = (b + (np.arange(sub) + 0.5) / sub) / N_PHI * math.pi
                MU, PH = np.meshgrid(mu, ph, indexing="ij")
                s = np.sqrt(1 - MU * MU)
                dens = 0.0
                for sign in (1.0, -1.0):        # the bin covers |phi|: both signs of phi
                    o = np.stack([s * np.cos(PH), sign * s * np.sin(PH), MU if side == 0 else -MU], axis=-1)
                    dens = dens + _walter_density(i, o, n1, n2, m_a, m_b).mean()
                out[(side * N_MU + a) * N_PHI + b] = dens * (1.0 / N_MU) * (math.pi / N_PHI)
    return out


@pytest.mark.parametrize("n1,n2,theta_deg,m_a,m_b,plane_deg", [
    (1.5, 1.0, 20.0, 0.25, 0.25, 0.0),    # leaving a fiber, below the critical angle
    (1.5, 1.0, 38.0, 0.25, 0.25, 0.0),    # near the critical angle (41.8 deg): rough facets let part out
    (1.0, 1.5, 60.0, 0.35, 0.35, 0.0),    # entering at 60 deg
    (1.5, 1.0, 30.0, 0.08, 0.35, 0.0),    # anisotropic, in the plane of the axis
    (1.5, 1.0, 30.0, 0.35, 0.08, 90.0),   # anisotropic, across the axis
    (1.5, 1.0, 35.0, 0.1, 0.4, 40.0),     # anisotropic, oblique
])
def test_rough_crossings_follow_walters_rough_dielectric_bin_by_bin(n1, n2, theta_deg, m_a, m_b, plane_deg):
    th = math.radians(theta_deg)
    ph = math.radians(plane_deg)
    # the light travels along u towards the n2 side; the macro normal of the crossing points there (+z)
    u = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    rng = np.random.default_rng(7)
    n = 400_000
    s = _sample(u[0], u[1], u[2], n1, n2, m_a, m_b, rng.random((n, 3)))
    # in the frame of the formulas the normal is on the incident side: flip z
    o = s[:, :3] * np.array([1.0, 1.0, -1.0])
    w = s[:, 3]
    k = _bins(o)
    nb = 2 * N_MU * N_PHI
    mean = np.bincount(k, weights=w, minlength=nb) / n
    se = np.sqrt(np.maximum(np.bincount(k, weights=w * w, minlength=nb) / n - mean ** 2, 0.0) / n)
    i = -u * np.array([1.0, 1.0, -1.0])  # towards where the light came from, in the flipped frame
    ref = _quadrature(i, n1, n2, m_a, m_b)
    big = ref > 1e-3 * ref.max()
    z = (mean[big] - ref[big]) / np.maximum(se[big], 1e-3 * ref[big])
    assert np.max(np.abs(z)) < 5.0, (np.max(np.abs(z)), np.sum(big))
    # what the formulas give is what is kept in all: the masking loss alone is missing from 1
    assert abs(mean.sum() - ref.sum()) < 4 * math.sqrt(np.sum(se ** 2)) + 1e-3
    assert 0.9 < ref.sum() < 1.0


def test_rough_entry_keeps_both_parts_as_the_expected_values_of_one_facet():
    th = math.radians(45.0)
    d = np.array([math.sin(th), 0.0, -math.cos(th)])  # travelling down onto the outward normal +z
    rng = np.random.default_rng(3)
    t = np.empty(100_000)
    r = np.empty(100_000)
    for k in range(t.size):
        u1, u2 = rng.random(2)
        _, _, uz, t[k], r[k] = rough_entry(d[0], d[1], d[2], 0.0, 0.0, 1.0, 1.5, 0.3, 0.3, u1, u2)
        assert t[k] == 0.0 or uz < 0.0
    i = -d
    ref_t = _quadrature(i, 1.0, 1.5, 0.3, 0.3)[N_MU * N_PHI:].sum()
    ref_r = _quadrature(i, 1.0, 1.5, 0.3, 0.3)[: N_MU * N_PHI].sum()
    assert abs(t.mean() - ref_t) < 4 * t.std() / math.sqrt(t.size)
    assert abs(r.mean() - ref_r) < 4 * r.std() / math.sqrt(r.size)


def _slab(m_t: float, photons: int = 200_000):
    medium = np.zeros(K.N_MEDIUM)
    medium[[K.M_MU_A, K.M_MU_S, K.M_G, K.M_N, K.M_ROUGH, K.M_ROUGH_B]] = 0.0, 0.0, 0.0, 1.5, m_t, m_t
    medium[K.M_PHASE] = K.PHASE_HG
    inp = make_inputs(G.SLAB, np.array([1.0]), np.array([0.0, 0.0, 0.0, 1.0]), medium, phase_arrays(g=0.0),
                      make_control(), T.SLAB_DIRECTIONS, np.array([1.0, 1.0]))
    scal, bins, _ = execute(inp, photons, 5, 1, 10_000)
    return scal, bins, photons


def test_a_clear_slab_with_a_rough_boundary_keeps_its_light_and_tends_to_the_smooth_slab():
    # smooth, normal incidence, clear slab: T = (1-F)^2 / (1 - F^2), the rest reflected
    f = ((1.5 - 1.0) / 2.5) ** 2
    t_smooth = (1 - f) ** 2 / (1 - f * f)
    for m_t in (0.02, 0.3):
        scal, _, n = _slab(m_t)
        launch = scal[T.S_LAUNCHED]
        out = (scal[T.S_SPECULAR] + scal[T.S_EXIT0] + scal[T.S_EXIT1] + scal[T.S_ABSORBED]) / launch
        # each crossing's weight is 1 on average less the masking loss; its difference from 1 is booked
        # as absorbed, so the balance is exact photon by photon
        assert abs(out - 1.0) < 1e-9
        lost = scal[T.S_ABSORBED] / launch
        transmitted = scal[T.S_EXIT1] / launch
        if m_t == 0.02:
            assert abs(lost) < 1e-3
            assert abs(transmitted - t_smooth) < 5 * math.sqrt(scal[T.S_EXIT1_SQ] / n - transmitted ** 2) / math.sqrt(n) + 1e-3
        else:
            # the rough boundary loses a little to masking (booked with each draw's imbalance, so noisy:
            # the loss per crossing is tested against the closed form above), and its internal
            # reflections leave the slab more often through the bottom than the smooth ones
            assert abs(lost) < 0.03
            assert scal[T.S_EXIT0] / launch < (1 - t_smooth - f) - 0.003


def test_the_next_event_routes_refuse_a_rough_boundary():
    medium = np.zeros(K.N_MEDIUM)
    medium[[K.M_MU_S, K.M_N, K.M_ROUGH]] = 1.0, 1.5, 0.2
    with pytest.raises(ParameterError, match="transmission_rms_slope"):
        make_inputs(G.CYLINDER, np.array([1.0]), np.array([0.0, 0.0, 0.0, 1.0]), medium, phase_arrays(g=0.0),
                    make_control(), T.NONE, None, T.V_CYLINDER_NEE, np.zeros((1, 8)))


def test_a_clear_fibers_yarn_table_spreads_its_exits_off_the_refraction_plane_when_rough():
    """Config to kernel: a nearly clear fiber lit at normal incidence to its axis (row w_t = 0) sends
    its exits into the plane across the axis (exit azimuth +-90 deg from the axis in the local frame);
    through a rough boundary a share of them leaves that plane, and the table says so."""
    import dataclasses

    from simulate import fiber as F
    from simulate import raytrace as W
    from simulate.media.medium import HGMedium

    smooth = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.001, mu_a=0.0, g=0.0), 0.3, 30.0)
    rough = dataclasses.replace(smooth, transmission_roughness=0.3)
    grid = dict(w_t_nodes=(0.0, 0.5), n_v=1, n_mu=3, n_phi=6, photons_per_row=4000, seed=2, threads=1,
                cache=False)
    off_plane = []
    for fib in (smooth, rough):
        t = W.yarn_table(fib, [550.0], **grid)
        # T[j, k, cell, l], cell = (offset, v, mu, phi): azimuth bins of 60 deg from -180; +-90 lie in bins 1 and 4
        T6 = t.T[0, :, :, 0].reshape(t.T.shape[1], -1, 6).sum(axis=(0, 1))
        off_plane.append(1.0 - (T6[1] + T6[4]) / T6.sum())
    assert off_plane[0] < 0.03          # smooth: only the scattered photons (~2 %) leave the plane
    assert off_plane[1] > 0.2           # rough facets tilt the refracted light out of it (0.35 at m 0.3)
