"""The woven Monte Carlo's local fiber direction (twist) and its shading-normal rule.

References come from outside the tracer: the summation's twist convention, a mirror symmetry, a
quadrature of the camera-tracer (adjoint) formula over the mesh's own triangles, the faceted tube.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry import weave
from simulate.geometry.mesh import mesh as weave_mesh
from simulate.geometry.validation import straight_yarn_mesh
from simulate.media.medium import HGMedium
from simulate.raytrace import shading


def _dirs(theta_deg, phi_deg=0.0):
    t = np.radians(np.atleast_1d(theta_deg))
    p = np.radians(np.broadcast_to(phi_deg, t.shape))
    return np.column_stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@pytest.fixture(scope="module")
def grey_fiber():
    return F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.35, 10.0)


@pytest.fixture(scope="module")
def grey_tables(grey_fiber):
    return tuple(W.yarn_table(grey_fiber, [550.0], photons_per_row=3000, seed=s, threads=1) for s in (21, 22))


@pytest.fixture(scope="module")
def plain_mesh():
    return weave_mesh(weave.Weave(np.array([[1, 0], [0, 1]]), spacing_um=300.0, width_um=250.0, height_um=100.0,
                                  points_per_span=6, sides=12))


# ---------------------------------------------------------------------------------- twist
@pytest.mark.parametrize("hand", ["Z", "S"])
@pytest.mark.parametrize("alpha", [0.0, 24.0, 60.0])
def test_the_fiber_frame_follows_the_summations_twist_convention(hand, alpha):
    """The kernel's fiber direction is simulate.fabric.structure's ``cos a T + s sin a (T x n)``."""
    rng = np.random.default_rng(1)
    for _ in range(5):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        t = np.cross(n, rng.normal(size=3))
        t /= np.linalg.norm(t)
        b = np.cross(n, t)
        sign = 1.0 if hand == "Z" else -1.0
        tf = np.array(shading._twist(*t, *b, math.cos(math.radians(alpha)), sign * math.sin(math.radians(alpha))))
        expect_t = ST._twisted(t[None, :], n[None, :], alpha, hand)[0]
        np.testing.assert_allclose(tf[:3], expect_t, atol=1e-12)
        np.testing.assert_allclose(tf[3:], np.cross(n, expect_t), atol=1e-12)   # b_f = n x t_f


def test_a_structure_with_twist_zero_is_bit_identical_and_twist_changes_the_result(plain_mesh, grey_fiber,
                                                                                  grey_tables):
    wl = [550.0]
    w_in = _dirs([30.0, 30.0], [20.0, 20.0])
    w_out = _dirs([0.0, 40.0], [0.0, 200.0])
    # the same yarn surface for all three (without [structure] a weave's yarn is the tube of old)
    kw = dict(target_rel_err=1e-9, max_rays=8192, seed=3, tables=grey_tables, surface="fibers")
    b0, u0, _ = W.fabric_beta(plain_mesh, grey_fiber, w_in, w_out, wl, **kw)
    flat = ST.StructureSpec(warp_twist_deg=0.0, weft_twist_deg=0.0, weft_twist="S")
    b1, u1, i1 = W.fabric_beta(plain_mesh, grey_fiber, w_in, w_out, wl, structure=flat, **kw)
    assert np.array_equal(b0, b1) and np.array_equal(u0, u1)
    assert i1["twist_deg"] == [0.0, 0.0]
    b2, u2, i2 = W.fabric_beta(plain_mesh, grey_fiber, w_in, w_out, wl, structure=ST.StructureSpec(), **kw)
    assert i2["twist_deg"] == [24.0, 24.0]
    assert not np.array_equal(b0, b2)
    # a felt has no yarn twist
    assert W.twist_of(ST.StructureSpec(kind="nonwoven")) == (0.0, 0.0)


def test_twist_is_a_handedness(plain_mesh):
    """The plain weave is its own mirror image in y (up to a shift): Z yarns lit and seen from
    ``(x, y, z)`` are S yarns lit and seen from ``(x, -y, z)``. Without the mirror the Z and S
    runs differ (so the check has something to see: a nearly clear fiber, whose light comes out
    on the cone about its axis)."""
    clear = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.02, mu_a=0.002, g=0.9), 0.1, 10.0)
    mat = W.FiberSurface(W.yarn_table(clear, [550.0], photons_per_row=3000, seed=23, threads=1), 0.1, 1.5)
    mirror = np.array([1.0, -1.0, 1.0])
    w_in = _dirs(50.0, 40.0)[0]
    det = _dirs([20.0, 45.0, 60.0], [220.0, 270.0, 180.0])
    kw = dict(target_rel_err=1e-9, max_rays=65536, chunk=8192)
    z = W.trace(plain_mesh, mat, w_in, det, seed=5, twist_deg=(40.0, 40.0), **kw)
    s_mirror = W.trace(plain_mesh, mat, w_in * mirror, det * mirror, seed=6, twist_deg=(-40.0, -40.0), **kw)
    z_mirror = W.trace(plain_mesh, mat, w_in * mirror, det * mirror, seed=7, twist_deg=(40.0, 40.0), **kw)
    same = (z.beta - s_mirror.beta) / np.hypot(z.u_beta, s_mirror.u_beta)
    other = (z.beta - z_mirror.beta) / np.hypot(z.u_beta, z_mirror.u_beta)
    assert np.max(np.abs(same)) < 4.0, same
    assert np.max(np.abs(other)) > 6.0, other


# ------------------------------------------------------------------------------- shading normals
def _camera_beta(mesh, rho, w_in, det, rule, k=40):
    """Single scattering of a convex Lambertian tube by quadrature over its triangles (midpoints of
    k^2 sub-triangles): ``beta = rho / (A cos_i cos_o) sum int [all four cosines > 0] c dA`` with
    ``c = (w_in.N_s)(w_o.N_g)`` (the camera tracer's cosine at the light: the adjoint rule) or the
    transposed ``(w_in.N_g)(w_o.N_s)`` (the shading cosine on the detector side)."""
    pts = []
    for i in range(k):
        for j in range(k - i):
            pts.append(((i + 1 / 3) / k, (j + 1 / 3) / k))
            if i + j < k - 1:
                pts.append(((i + 2 / 3) / k, (j + 2 / 3) / k))
    bc = np.array(pts)
    w1, w2 = bc[:, 0], bc[:, 1]
    w0 = 1.0 - w1 - w2
    out = np.zeros(len(det))
    for f in mesh.faces:
        a, b, c = mesh.vertices[f]
        cr = np.cross(b - a, c - a)
        g = cr / np.linalg.norm(cr)
        ns = w0[:, None] * mesh.normals[f[0]] + w1[:, None] * mesh.normals[f[1]] + w2[:, None] * mesh.normals[f[2]]
        ns /= np.linalg.norm(ns, axis=1)[:, None]
        ci_s, ci_g = ns @ w_in, g @ w_in
        for d, wo in enumerate(det):
            co_s, co_g = ns @ wo, g @ wo
            ok = (ci_s > 0) & (ci_g > 0) & (co_s > 0) & (co_g > 0)
            val = ci_s * co_g if rule == "adjoint" else ci_g * co_s
            out[d] += 0.5 * np.linalg.norm(cr) * np.mean(np.where(ok, val, 0.0))
    return rho * out / (mesh.Lx * mesh.Ly * w_in[2] * det[:, 2])


def test_the_light_tracer_is_the_adjoint_of_a_camera_tracer_with_shading_normals():
    """One straight 8-sided yarn (convex; its periodic copies 40 um apart do not shadow it at these
    angles), a dark Lambertian albedo so that only single scattering counts (the copies' second
    bounce is ~rho x a few % of it): the traced beta is the quadrature of the adjoint rule, and not
    of the detector-side cosine the tracer used to apply."""
    mesh = straight_yarn_mesh(10.0, 40.0, 60.0, n_s=2, sides=8)
    rho = 0.02
    w_in = _dirs(30.0, 90.0)[0]
    det = _dirs([0.0, 20.0, 35.0, 45.0, 60.0], [90.0, -90.0, -90.0, -90.0, 90.0])
    res = W.trace(mesh, W.Lambert(rho), w_in, det, target_rel_err=1e-9, max_rays=2 ** 17, seed=3, chunk=8192)
    adjoint = _camera_beta(mesh, rho, w_in, det, "adjoint")
    transposed = _camera_beta(mesh, rho, w_in, det, "transposed")
    u = res.u_beta[:, 0]
    assert np.all(np.abs(res.beta[:, 0] - adjoint) < 4 * u + 2e-3 * adjoint), (res.beta[:, 0], adjoint, u)
    assert np.max(np.abs(res.beta[:, 0] - transposed) / u) > 8.0


def test_vertex_normals_converge_to_the_faceted_tube_and_lose_no_energy_in_the_limit():
    """A white Lambertian weave (reflected + transmitted = 1 for the smooth tube): the faceted tube
    conserves it exactly at any resolution; the shading-normal rule loses the light it absorbs
    below the shading horizon (and rejects below the geometric one), which vanishes as the tube is
    refined, and its beta approaches the faceted tube's."""
    w_in = _dirs(20.0, 20.0)[0]
    det = _dirs([0.0, 30.0, 60.0], [0.0, 90.0, 200.0])
    kw = dict(target_rel_err=1e-9, max_rays=65536, seed=13, chunk=8192)
    loss = {}
    for sides in (12, 48):
        mesh = weave_mesh(weave.Weave(np.array([[1, 0], [0, 1]]), spacing_um=300.0, width_um=250.0,
                                      height_um=100.0, points_per_span=8, sides=sides))
        v = W.trace(mesh, W.Lambert(1.0), w_in, det, **kw)
        f = W.trace(mesh, W.Lambert(1.0), w_in, det, normals="face", **kw)
        np.testing.assert_allclose(f.reflected + f.transmitted, 1.0, rtol=1e-12)
        assert v.info["self_hit_fraction"] == 0.0 and f.info["self_hit_fraction"] == 0.0
        loss[sides] = 1.0 - float((v.reflected + v.transmitted)[0])
        if sides == 48:
            z = (v.beta - f.beta) / np.hypot(v.u_beta, f.u_beta)
            assert np.all(np.abs(v.beta / f.beta - 1.0) < 0.003 + 4 * np.hypot(v.u_beta, f.u_beta) / f.beta), z
    assert 0.0 < loss[48] < 0.005 and loss[48] < loss[12] / 4, loss


def test_no_continued_ray_re_hits_the_triangle_it_left(plain_mesh, grey_tables):
    res = W.trace(plain_mesh, W.FiberSurface(grey_tables[0], 0.35, 1.5), _dirs(40.0)[0], _dirs([0.0, 30.0]),
                  target_rel_err=1e-9, max_rays=16384, seed=2, chunk=4096)
    assert res.info["self_hit_fraction"] == 0.0


def test_normals_must_be_vertex_or_face(plain_mesh):
    with pytest.raises(ValueError, match="normals"):
        W.trace(plain_mesh, W.Lambert(0.5), _dirs(10.0)[0], _dirs([0.0]), normals="smooth")
