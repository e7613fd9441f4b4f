"""Shadow-hiding in the felt Monte Carlo against an independent brute-force tracer.

The felt's opposition peak must emerge from the transport (a ray scattered back towards the source
leaves along the path it came in by, which is free), not from a lobe. The reference here is a
brute-force tracer written in plain numpy: analytic ray-cylinder intersections with the felt's
fiber tubes in the periodic cell, its own random numbers. From the felt it takes only the geometry
(each tube's axis and radius, read off the mesh's vertices); it calls nothing of the tracer.

Both see the same random felt with an opaque Lambertian fiber surface (albedo 1) and score the
single scattering only (``trace(..., max_events=1)``: each ray's first hit, seen past the other
fibers, i.e. with its shadow ray). Compared: ``beta`` averaged on the ring 6 deg and on the ring
30 deg from the retro direction, and their ratio (the opposition ratio of
:mod:`compare.ratios`), within 4 combined standard errors. The reference's unshadowed ratio
(every exit path taken as free) is below 1, so the peak is the shadowing's; the tracer with its
shadow rays skipped misses the reference's ratio by many standard errors (the test can fail).

Hapke's sphere-limit shadow-hiding function is a coarser check, recorded with its numbers in
docs/notes/felt-structure.md (section 4), not a pass/fail reference: it is derived for spheres.

Geometry differences the comparison leaves in (all well below its standard errors): the mesh's
tubes are 48-sided polygons inscribed in the cylinders (radius 0.2 % smaller at the sides' middles)
shaded with interpolated normals. The tubes are open: a ray that enters one through an end and
meets its inside wall is scattered as by the wall's outside, the tracer's documented rule for light
already inside a fiber (:mod:`simulate.geometry.felt`, "Ends"); the reference does the same.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry.felt import felt_mesh
from simulate.raytrace.scene import PeriodicScene

THETA_I = 40.03                # one of the green felt file's measured incidences
RINGS = (6.0, 30.0)
PER_RING = 8
REF_RAYS = 10_000
TRACER_BATCHES, TRACER_RAYS = 8, 5_000


# ---------------------------------------------------------------- the brute-force reference
def _tubes(mesh):
    """Centre, unit axis and half-length of every fiber tube of the mesh, and the common radius.

    A tube's vertices are ``(n_s + 1)`` rings of ``sides`` points (plus a repeated seam column) round
    its axis: a ring's mean is a point on the axis, the first and last rings' give its ends."""
    ns, sides = int(mesh.n_s[0]), int(mesh.sides)
    assert np.all(mesh.n_s == ns)
    v = mesh.vertices.reshape(len(mesh.vertex_base), ns + 1, sides + 1, 3)[:, :, :sides]
    axis = v.mean(axis=2)
    ends = axis[:, -1] - axis[:, 0]
    half = 0.5 * np.linalg.norm(ends, axis=1)
    radius = float(np.linalg.norm(v[:, 0] - axis[:, :1], axis=-1).mean())
    return 0.5 * (axis[:, 0] + axis[:, -1]), ends / (2.0 * half)[:, None], half, radius


def _nearest_hit(o, d, c, a, half, radius, t_max):
    """Nearest ``t`` in ``(0, t_max]`` at which ``o + t d`` meets a tube's side wall (either root: the
    tubes are open), and which tube; ``inf`` where none. ``(n, m)`` pairs, closed-form quadratic."""
    wa = o @ a.T - np.einsum("mk,mk->m", c, a)                      # the origin's axial coordinate
    da = d @ a.T
    dw = np.einsum("nk,nk->n", d, o)[:, None] - d @ c.T
    ww = np.einsum("nk,nk->n", o, o)[:, None] - 2.0 * (o @ c.T) + np.einsum("mk,mk->m", c, c)
    qa, qb, qc = 1.0 - da * da, dw - da * wa, ww - wa * wa - radius * radius
    disc = qb * qb - qa * qc
    ok = (disc >= 0.0) & (qa > 1e-14)
    sq, qa = np.sqrt(np.where(ok, disc, 0.0)), np.where(ok, qa, 1.0)
    best = np.full(qa.shape, np.inf)
    for sign in (1.0, -1.0):
        t = (-qb + sign * sq) / qa
        valid = ok & (t > 1e-9) & (t <= t_max[:, None]) & (np.abs(wa + t * da) <= half)
        best = np.where(valid & (t < best), t, best)
    j = np.argmin(best, axis=1)
    return best[np.arange(len(o)), j], j


def _trace_periodic(o, d, tubes, cell, z_lo, z_hi, chunk=1000):
    """The first tube each ray meets in the periodic cell ``[0, cell)^2``: index ``>= 0`` and the point,
    or -1 (left through the top plane ``z_hi``) / -2 (the bottom plane). A ray is followed piece by
    piece: to the first side face, where it re-enters through the opposite one."""
    c, a, half, radius = tubes
    z_top = c[:, 2] + half * np.abs(a[:, 2]) + radius
    o = o.copy()
    which, point = np.full(len(o), -3), np.zeros_like(o)
    active = np.arange(len(o))
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(200):
            if active.size == 0:
                break
            oa, da = o[active], d[active]
            limits = np.stack([np.where(da[:, 2] > 0, (z_hi - oa[:, 2]) / da[:, 2], np.inf),
                               np.where(da[:, 2] < 0, (z_lo - oa[:, 2]) / da[:, 2], np.inf),
                               np.where(da[:, 0] > 0, (cell - oa[:, 0]) / da[:, 0], np.inf),
                               np.where(da[:, 0] < 0, -oa[:, 0] / da[:, 0], np.inf),
                               np.where(da[:, 1] > 0, (cell - oa[:, 1]) / da[:, 1], np.inf),
                               np.where(da[:, 1] < 0, -oa[:, 1] / da[:, 1], np.inf)], axis=1)
            face = np.argmin(limits, axis=1)
            t_seg = np.maximum(limits[np.arange(len(oa)), face], 0.0)
            t_hit, j_hit = np.empty(len(oa)), np.zeros(len(oa), int)
            upward = bool(np.all(da[:, 2] > 0))
            order = np.argsort(oa[:, 2])
            for s in range(0, len(oa), chunk):
                k = order[s:s + chunk]
                # an upward ray cannot meet a tube lying wholly below its origin
                near = np.nonzero(z_top >= oa[k, 2].min() - 1e-6)[0] if upward else np.arange(len(c))
                if near.size == 0:
                    t_hit[k] = np.inf
                    continue
                t_hit[k], j = _nearest_hit(oa[k], da[k], c[near], a[near], half[near], radius, t_seg[k])
                j_hit[k] = near[j]
            hit = np.isfinite(t_hit)
            which[active[hit]] = j_hit[hit]
            point[active[hit]] = oa[hit] + t_hit[hit, None] * da[hit]
            which[active[~hit & (face == 0)]] = -1
            which[active[~hit & (face == 1)]] = -2
            side = ~hit & (face >= 2)
            moved = oa[side] + t_seg[side, None] * da[side]
            f = face[side]
            moved[f == 2, 0], moved[f == 3, 0], moved[f == 4, 1], moved[f == 5, 1] = 0.0, cell, 0.0, cell
            o[active[side]] = moved
            active = active[side]
    return which, point


def _first_hits(mesh, w_in, n_rays, seed):
    """The beam's rays (uniform over the cell, from above the felt) to their first tube: the tubes, the
    cell, the felt's top and bottom, the rays that hit, where, the unnormalised outward normal there,
    and the random generator (drawn from further by the caller)."""
    tubes = _tubes(mesh)
    c, a, half, radius = tubes
    reach = half * np.abs(a[:, 2]) + radius
    z_hi, z_lo = float((c[:, 2] + reach).max()) + 1.0, float((c[:, 2] - reach).min()) - 1.0
    cell = float(mesh.Lx)
    rng = np.random.default_rng(seed)
    o = np.column_stack([rng.uniform(0.0, cell, n_rays), rng.uniform(0.0, cell, n_rays), np.full(n_rays, z_hi)])
    which, p = _trace_periodic(o, np.tile(-w_in, (n_rays, 1)), tubes, cell, z_lo, z_hi)
    hit = np.nonzero(which >= 0)[0]
    j = which[hit]
    q = p[hit] - c[j]
    normal = q - np.einsum("ij,ij->i", q, a[j])[:, None] * a[j]
    return tubes, cell, z_lo, z_hi, hit, p, normal, rng


def reference_single_scatter(mesh, w_in, detectors, n_rays, seed):
    """Per ray and detector, ``beta`` of the first hit on opaque Lambertian tubes (albedo 1) with the
    exit seen past the fibers (shadowed) and with every exit taken as free (unshadowed): the ray's
    terms ``(w_o . N)^+ V / cos theta_o``, whose mean is ``beta = pi f`` (rays of the beam uniform over
    the cell)."""
    tubes, cell, z_lo, z_hi, hit, p, normal, rng = _first_hits(mesh, w_in, n_rays, seed)
    c, a, half, radius = tubes
    normal /= np.linalg.norm(normal, axis=1)[:, None]        # outward (the inside wall: scattered as outside)
    cos_o = np.clip(normal @ detectors.T, 0.0, None)
    i, k = np.nonzero(cos_o > 0.0)
    start = p[hit][i] + 1e-6 * radius * normal[i]
    start[:, :2] %= cell
    seen, _ = _trace_periodic(start, detectors[k], tubes, cell, z_lo, z_hi)
    visible = np.zeros_like(cos_o)
    visible[i, k] = seen == -1
    free = np.zeros((n_rays, len(detectors)))
    free[hit] = cos_o / detectors[:, 2]
    shadowed = np.zeros_like(free)
    shadowed[hit] = free[hit] * visible
    return shadowed, free


# ---------------------------------------------------------------- comparison
def _ring(w_r, radius_deg, n):
    """``n`` unit directions at ``radius_deg`` from ``w_r`` (in the x-z plane), evenly round it."""
    e1 = np.array([w_r[2], 0.0, -w_r[0]])
    e2 = np.cross(w_r, e1)
    psi = 2.0 * np.pi * np.arange(n) / n
    r = math.radians(radius_deg)
    return math.cos(r) * w_r + math.sin(r) * (np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2)


def _rings_and_ratio(per_sample):
    """Ring means, the ratio and their standard errors from ``[samples, 2 * PER_RING]`` independent
    samples (rays, or batches of rays): the delta method with the two rings' covariance."""
    inner, outer = per_sample[:, :PER_RING].mean(axis=1), per_sample[:, PER_RING:].mean(axis=1)
    n = len(per_sample)
    m = np.array([inner.mean(), outer.mean()])
    cov = np.cov(inner, outer) / n
    ratio = m[0] / m[1]
    g = np.array([1.0 / m[1], -m[0] / m[1] ** 2])
    return m, np.sqrt(np.diag(cov)), ratio, float(np.sqrt(g @ cov @ g))


@pytest.fixture(scope="module")
def case():
    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=20.0, layers=2)
    mesh = felt_mesh(spec, 10.0, seed=0)
    th = math.radians(THETA_I)
    w_in = np.array([math.sin(th), 0.0, math.cos(th)])
    detectors = np.vstack([_ring(w_in, r, PER_RING) for r in RINGS])
    shadowed, free = reference_single_scatter(mesh, w_in, detectors, REF_RAYS, seed=20240)
    return mesh, w_in, detectors, _rings_and_ratio(shadowed), _rings_and_ratio(free)


def _tracer(mesh, w_in, detectors):
    """The felt tracer's single scattering in independent batches (seeds): ring means and ratio with
    standard errors from the batches' spread."""
    setups: dict = {}
    batches = [W.trace(mesh, W.Lambert(1.0), w_in, detectors, target_rel_err=1e-9, max_rays=TRACER_RAYS,
                       seed=100 + s, chunk=TRACER_RAYS // 4, max_events=1, setups=setups).beta[:, 0]
               for s in range(TRACER_BATCHES)]
    return _rings_and_ratio(np.array(batches))


def test_the_felts_shadow_hiding_matches_a_brute_force_trace(case):
    mesh, w_in, detectors, (m_ref, u_ref, ratio_ref, ur_ref), (_, _, ratio_free, ur_free) = case
    m, u, ratio, ur = _tracer(mesh, w_in, detectors)
    for ring in range(2):     # beta on each ring: the level, not only the shape
        assert abs(m[ring] - m_ref[ring]) < 4.0 * math.hypot(u[ring], u_ref[ring]), (RINGS[ring], m, u, m_ref, u_ref)
    assert abs(ratio - ratio_ref) < 4.0 * math.hypot(ur, ur_ref), (ratio, ur, ratio_ref, ur_ref)
    # the peak emerges, and it is the shadowing's: the exits taken as free give a ratio below 1
    assert ratio_ref > 1.0 + 5.0 * ur_ref and ratio > 1.0 + 5.0 * ur
    assert ratio_free < 1.0 - 5.0 * ur_free


def test_without_its_shadow_rays_the_tracer_misses_the_reference(case, monkeypatch):
    """Every shadow ray taken as free: the tracer then agrees with the reference's unshadowed terms and
    its opposition ratio is many standard errors from the shadowed reference's (the comparison above
    would fail if the felt ignored shadowing)."""
    mesh, w_in, detectors, (_, _, ratio_ref, ur_ref), (m_free, u_free, ratio_free, ur_free) = case
    monkeypatch.setattr(PeriodicScene, "visible", lambda self, o, d, stats=None: np.ones(len(o), bool))
    m, u, ratio, ur = _tracer(mesh, w_in, detectors)
    assert abs(ratio - ratio_ref) > 10.0 * math.hypot(ur, ur_ref), (ratio, ratio_ref)
    assert abs(ratio - ratio_free) < 4.0 * math.hypot(ur, ur_free), (ratio, ur, ratio_free, ur_free)
    for ring in range(2):
        assert abs(m[ring] - m_free[ring]) < 4.0 * math.hypot(u[ring], u_free[ring]), (m, u, m_free, u_free)


def test_max_events_scores_the_first_scattering_only(case):
    """One event is the single scattering: with albedo 0.8 the full trace adds the light scattered
    again by other fibers; a bad count is refused."""
    mesh, w_in, detectors = case[:3]
    kw = dict(target_rel_err=1e-9, max_rays=4000, seed=3, chunk=1000)
    one = W.trace(mesh, W.Lambert(0.8), w_in, detectors, max_events=1, **kw)
    every = W.trace(mesh, W.Lambert(0.8), w_in, detectors, **kw)
    assert one.info["killed_at_max_bounces"] > 0.5 * one.rays and every.info["killed_at_max_bounces"] == 0
    gain = every.beta[:, 0].mean() - one.beta[:, 0].mean()
    assert gain > 5.0 * float(np.sqrt(np.mean(every.u_beta[:, 0] ** 2)))
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="max_events"):
            W.trace(mesh, W.Lambert(0.8), w_in, detectors, max_events=bad, **kw)


# ---------------------------------------------------------------- Hapke's sphere limit (a documented comparison)
def hapke_comparison(n_rays: int = 20_000, seed: int = 7) -> dict:
    """The shadow-hiding factor ``1 + B(g)`` of the test's felt, measured with the reference, beside
    Hapke's sphere-limit ``B(g) = B0 / (1 + tan(g / 2) / h)`` (opaque particles: ``B0 = 1``; equal
    spheres at filling factor ``phi``: ``h = -(3/8) ln(1 - phi)``, Hapke 2008, Icarus 195, 918), ``phi``
    the felt's bulk volume fraction. On the rings about the retro direction the phase angle ``g`` is the
    ring's radius. Measured ``1 + B`` (with its standard error): the shadowed single scattering over the same with each exit seen
    from an uncorrelated point (the hit point moved to a random place of the cell at the same depth,
    outside the fibers), which is the independent-paths reflectance Hapke's factor multiplies.

    ``python tests/simulate/raytrace/test_felt_shadow_hiding.py`` prints it (docs/notes/felt-structure.md 4)."""
    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=20.0, layers=2)
    mesh = felt_mesh(spec, 10.0, seed=0)
    th = math.radians(THETA_I)
    w_in = np.array([math.sin(th), 0.0, math.cos(th)])
    detectors = np.vstack([_ring(w_in, r, PER_RING) for r in RINGS])
    tubes, cell, z_lo, z_hi, hit, p, normal, rng = _first_hits(mesh, w_in, n_rays, seed)
    c, a, half, radius = tubes
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    start = p[hit] + 1e-6 * radius * normal
    start[:, :2] %= cell
    moved = start.copy()                       # the same depth, a random place outside the fibers
    todo = np.arange(len(moved))
    while todo.size:
        moved[todo, :2] = rng.uniform(0.0, cell, (todo.size, 2))
        d = moved[todo, None, :] - c[None]
        ax = np.einsum("nmk,mk->nm", d, a)
        inside = ((np.einsum("nmk,nmk->nm", d, d) - ax * ax < radius ** 2) & (np.abs(ax) <= half)).any(axis=1)
        todo = todo[inside]
    cos_o = np.clip(normal @ detectors.T, 0.0, None)
    i, k = np.nonzero(cos_o > 0.0)
    seen = [(_trace_periodic(s[i], detectors[k], tubes, cell, z_lo, z_hi)[0] == -1) for s in (start, moved)]
    per_ray = []                               # [hit, ring]: the ray's terms summed over the ring
    for v in seen:
        t = np.zeros_like(cos_o)
        t[i, k] = cos_o[i, k] * v
        per_ray.append(np.column_stack([t[:, :PER_RING].sum(axis=1), t[:, PER_RING:].sum(axis=1)]))
    x = np.hstack(per_ray)                     # shadowed inner, outer; uncorrelated inner, outer
    m, cov = x.mean(axis=0), np.cov(x, rowvar=False) / len(x)

    def ratio(num, den):                       # a ratio of means of the columns and its standard error
        r = float(np.prod(m[num]) / np.prod(m[den]))
        g = np.zeros(4)
        for col in num:
            g[col] += r / m[col]
        for col in den:
            g[col] -= r / m[col]
        return round(r, 4), round(float(np.sqrt(g @ cov @ g)), 4)

    measured = [ratio([0], [2]), ratio([1], [3])]
    phi = float(mesh.info["volume_fraction"])
    h = -0.375 * math.log(1.0 - phi)
    hapke = [1.0 + 1.0 / (1.0 + math.tan(math.radians(g) / 2.0) / h) for g in RINGS]
    return {"theta_i": THETA_I, "volume_fraction": phi, "h": h, "rings_deg": RINGS,
            "measured_1_plus_B": measured, "hapke_1_plus_B": [round(b, 4) for b in hapke],
            "measured_ratio": ratio([0, 3], [1, 2]), "hapke_ratio": round(hapke[0] / hapke[1], 4)}


if __name__ == "__main__":
    print(hapke_comparison())
