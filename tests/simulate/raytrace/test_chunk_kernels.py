"""The compiled per-bounce bookkeeping of the ray tracer against the numpy code it replaces.

``simulate.raytrace.integrator._chunk`` scores escapes, gathers the hits, picks and plays the next-event
candidates (the shadow roulette), scores the visible ones and plays the path's roulette in compiled
kernels; ``simulate.raytrace.scene.PeriodicScene`` walks the periodic cell in compiled code around each
Embree call. Each kernel is checked here on random inputs against the numpy lines it replaces (kept
below as the reference), bit for bit: the kernels add in the same order with the same arithmetic, so a
run's ``radiance.csv`` does not move.

Why bit for bit holds on every CPU, not only on this one: both sides use only ``+ - * /``, comparisons and
integer casts (IEEE 754 correctly rounded on every x86-64 and ARM CPU); the kernels are compiled without
fastmath, so LLVM fuses no multiply-add; the one transcendental, the escape's ``arctan2`` azimuth, is
computed by numpy and passed to the kernel (the same values on both sides); ``np.add.at`` adds in index
order, as the kernels' loops do. Nothing here is chosen by the CPU's vector width.
"""

from __future__ import annotations

import numpy as np
import pytest

from simulate.raytrace import integrator as I
from simulate.raytrace.scene import ESCAPED_DOWN, ESCAPED_UP, LOST, PeriodicScene, _segment_limits

# ------------------------------------------------------------------------------------------------
# escapes and hits


def _ref_escapes(prim, ray, last, dirs, weight, n, n_mu, n_phi, refl, trans, bins, bins2):
    up = prim == ESCAPED_UP
    if np.any(up):
        refl[ray[up]] += weight[up]
        d = dirs[up]
        imu = np.minimum((d[:, 2] * n_mu).astype(int), n_mu - 1)
        iph = np.minimum(((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * n_phi).astype(int), n_phi - 1)
        g_up = ray[up] // n
        np.add.at(bins, (g_up, imu, iph), weight[up])
        np.add.at(bins2, (g_up, imu, iph), weight[up] ** 2)
    down = prim == ESCAPED_DOWN
    if np.any(down):
        trans[ray[down]] += weight[down]
    h = prim >= 0
    return (int(np.count_nonzero(prim == LOST)), int(np.count_nonzero(last >= 0)),
            int(np.count_nonzero(h & (prim == last))), h)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_escapes_and_hits_match_numpy(seed):
    rng = np.random.default_rng(seed)
    G, n, L, n_mu, n_phi = 3, 40, 5, 4, 6
    N = 90
    ray = np.sort(rng.choice(G * n, N, replace=False))
    prim = rng.integers(-3, 8, N).astype(np.int64)
    last = rng.integers(-1, 8, N).astype(np.int64)
    dirs = rng.normal(size=(N, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    dirs[:, 2] = np.where(prim == ESCAPED_UP, np.abs(dirs[:, 2]), dirs[:, 2])
    weight = rng.random((N, L))
    u, v, pos = rng.random(N), rng.random(N), rng.normal(size=(N, 3))
    ref = [np.zeros((G * n, L)), np.zeros((G * n, L)), np.zeros((G, n_mu, n_phi, L)), np.zeros((G, n_mu, n_phi, L))]
    new = [x.copy() for x in ref]
    lost, cont, selfh, h = _ref_escapes(prim, ray, last, dirs, weight, n, n_mu, n_phi, *ref)
    hit_ray, hit_idx = np.empty(N, np.int64), np.empty(N, np.int64)
    m, lost2, cont2, selfh2 = I._tally_escapes(prim, ray, last, dirs, np.arctan2(dirs[:, 1], dirs[:, 0]), weight,
                                               n, n_mu, n_phi, *new, hit_ray, hit_idx)
    assert (lost2, cont2, selfh2) == (lost, cont, selfh)
    for a, b in zip(ref, new, strict=True):
        assert np.array_equal(a, b)
    assert m == np.count_nonzero(h) and np.array_equal(hit_ray[:m], ray[h])
    out = [np.empty(N, np.int64), np.empty(N), np.empty(N), np.empty((N, 3)), np.empty((N, 3)), np.empty((N, L))]
    I._gather_hits(hit_idx, m, prim, u, v, pos, dirs, weight, *out)
    for a, b in zip(out, (prim[h], u[h], v[h], pos[h], dirs[h], weight[h]), strict=True):
        assert np.array_equal(a[:m], b)


# ------------------------------------------------------------------------------------------------
# next-event candidates, the shadow roulette, the visible ones scored


def _ref_shadow(need, nee_c, nee_o, hit_group, hit_ray, detectors, cand, n, roulette, shadow_rng, vis_of, acc,
                wrap, lx, ly):
    """The numpy code of ``_chunk`` (one bounce's next-event part); ``vis_of(origins, dirs)``: visibility."""
    D = detectors.shape[1]
    G = detectors.shape[0]
    nee_o = nee_o.copy()
    if wrap:
        nee_o[..., 0] %= lx
        nee_o[..., 1] %= ly
    idx_i, idx_e, idx_d = np.nonzero(need)
    traced = 0
    if idx_i.size:
        contrib = nee_c[idx_i, idx_e, idx_d]
        size = contrib.max(axis=1)
        trace_it = size > 0.0
        p = np.ones(size.shape)
        if roulette:
            flat = hit_group[idx_i] * D + idx_d
            cand += np.bincount(flat, weights=size, minlength=G * D)
            level = I.SHADOW_LEVEL / n * cand[flat]
            np.divide(size, level, out=p, where=level > size)
            low = trace_it & (p < 1.0)
            if np.any(low):
                trace_it[low] = shadow_rng.random(int(np.count_nonzero(low))) < p[low]
        k = np.nonzero(trace_it)[0]
        traced = k.size
        if k.size:
            ki, ke, kd = idx_i[k], idx_e[k], idx_d[k]
            vis = vis_of(nee_o[ki, ke], detectors[hit_group[ki], kd])
            if np.any(vis):
                kv = k[vis]
                np.add.at(acc, (hit_ray[idx_i[kv]], idx_d[kv]), contrib[kv] / p[kv, None])
    return int(idx_i.size), traced


@pytest.mark.parametrize("roulette", [True, False])
@pytest.mark.parametrize("seed", [3, 4])
def test_shadow_candidates_match_numpy(seed, roulette):
    rng = np.random.default_rng(seed)
    G, D, L, n, M, lx, ly = 2, 4, 6, 50, 60, 30.0, 20.0
    hit_ray = np.sort(rng.choice(G * n, M, replace=False))
    hit_group = hit_ray // n
    need = rng.random((M, 2, D)) < 0.5
    nee_c = rng.random((M, 2, D, L)) ** 4          # a spread of sizes, some candidates far below the level
    nee_c[rng.random((M, 2, D)) < 0.2] = 0.0       # zero contributions: never traced
    nee_c[~need] = np.nan                          # not flagged: never read
    nee_o = rng.uniform(-40.0, 60.0, (M, 2, 3))
    detectors = rng.normal(size=(G, D, 3))
    mask_rng = np.random.default_rng(seed + 100)
    vis_bits = mask_rng.random(10 * M * D) < 0.4

    def vis_of(o, d):
        seen.append((o.copy(), d.copy()))
        return vis_bits[:o.shape[0]]

    for wrap in (True, False):
        cand_ref, cand_new = rng.random(G * D), None
        cand_new = cand_ref.copy()
        acc_ref, acc_new = np.zeros((G * n, D, L)), np.zeros((G * n, D, L))
        for bounce in range(3):          # the running sums carry over bounces
            seen: list = []
            s_ref = np.random.default_rng([seed, bounce])
            s_new = np.random.default_rng([seed, bounce])
            c_ref, t_ref = _ref_shadow(need, nee_c, nee_o, hit_group, hit_ray, detectors, cand_ref, n, roulette,
                                       s_ref, vis_of, acc_ref, wrap, lx, ly)
            K = M * 2 * D
            cidx, size, p = np.empty((K, 3), np.int64), np.empty(K), np.empty(K)
            state, binsum = np.empty(K, np.int8), np.zeros(G * D)
            c, n_draw = I._shadow_candidates(need, nee_c, hit_group, D, cand_new, I.SHADOW_LEVEL / n, roulette, cidx,
                                             size, p, state, binsum)
            assert c == c_ref
            assert np.array_equal(cand_new, cand_ref)
            draws = s_new.random(int(n_draw)) if n_draw else np.empty(0)
            traced, o, d = np.empty(K, np.int64), np.empty((K, 3)), np.empty((K, 3))
            t = I._shadow_rays(c, state, p, draws, cidx, nee_o, detectors, hit_group, wrap, lx, ly, traced, o, d)
            assert t == t_ref
            if t:
                assert np.array_equal(o[:t], seen[0][0]) and np.array_equal(d[:t], seen[0][1])
                I._score_visible(t, traced, vis_bits[:t].copy(), cidx, p, nee_c, hit_ray, acc_new)
            assert np.array_equal(acc_new, acc_ref)
            assert s_new.random() == s_ref.random()     # the same draws taken from the roulette's stream
        assert np.any(acc_ref != 0.0)


@pytest.mark.parametrize("seed", [7, 8])
def test_bounded_candidates_match_numpy(seed):
    """The roulette on deferred contributions (integrator.SHADOW_BOUND): sizes the bounds
    ``max_k weight * scale * t_max[row]`` (the surface term, row -1, ``max_k weight * scale``), the visible
    kept ones scored with ``weight * t_rows[row] * scale`` (or ``weight * scale``) over their probability."""
    rng = np.random.default_rng(seed)
    G, D, L, n, M, R = 2, 3, 5, 40, 50, 30
    hit_ray = np.sort(rng.choice(G * n, M, replace=False))
    hit_group = hit_ray // n
    need = rng.random((M, 2, D)) < 0.6
    row = rng.integers(0, R, (M, 2, D))
    row[:, 0] = -1                                     # the surface terms
    scale = rng.random((M, 2, D)) ** 3
    weight = rng.random((M, L)) ** 2
    weight[rng.random(M) < 0.1] = 0.0                  # dead rays: zero bounds, never traced
    t_rows = rng.random((R, L)) ** 4
    t_max = t_rows.max(axis=1)
    cand = rng.random(G * D)
    cand_ref = cand.copy()
    K = M * 2 * D
    cidx, size, p = np.empty((K, 3), np.int64), np.empty(K), np.empty(K)
    state, binsum = np.empty(K, np.int8), np.zeros(G * D)
    c, n_draw = I._bounded_candidates(need, row, scale, weight, t_max, hit_group, D, cand, I.SHADOW_LEVEL / n,
                                      cidx, size, p, state, binsum)
    i, e, d = np.nonzero(need)
    bound = weight.max(axis=1)[i] * scale[i, e, d]
    bound = np.where(row[i, e, d] >= 0, bound * t_max[row[i, e, d]], bound)
    assert c == i.size and np.array_equal(cidx[:c], np.column_stack([i, e, d])) and np.array_equal(size[:c], bound)
    flat = hit_group[i] * D + d
    cand_ref += np.bincount(flat, weights=bound, minlength=G * D)
    assert np.array_equal(cand, cand_ref)
    level = I.SHADOW_LEVEL / n * cand_ref[flat]
    p_ref = np.where(level > bound, bound / level, 1.0)
    assert np.array_equal(p[:c], p_ref)
    assert np.array_equal(state[:c], np.where(bound > 0.0, np.where(p_ref < 1.0, 2, 1), 0))
    assert n_draw == np.count_nonzero(state[:c] == 2) > 0
    # every kept candidate scored: the contributions the shading would have formed, over p
    traced = np.nonzero(state[:c] > 0)[0]
    vis = rng.random(traced.size) < 0.5
    acc, acc_ref = np.zeros((G * n, D, L)), np.zeros((G * n, D, L))
    I._score_visible_bounded(traced.size, traced, vis, cidx, p, row, scale, weight, t_rows, hit_ray, acc)
    for q in traced[vis]:
        a, b, k = cidx[q]
        r = row[a, b, k]
        contrib = weight[a] * t_rows[r] * scale[a, b, k] if r >= 0 else weight[a] * scale[a, b, k]
        acc_ref[hit_ray[a], k] += contrib / p[q]
    assert np.array_equal(acc, acc_ref) and np.any(acc != 0.0)


# ------------------------------------------------------------------------------------------------
# the path's roulette and the compaction of the live rays


@pytest.mark.parametrize("wrap", [True, False])
@pytest.mark.parametrize("seed", [5, 6])
def test_path_roulette_and_compaction_match_numpy(seed, wrap):
    rng = np.random.default_rng(seed)
    M, L, lx, ly = 200, 4, 30.0, 20.0
    o = rng.uniform(-40.0, 60.0, (M, 3))
    d = rng.normal(size=(M, 3))
    w = rng.random((M, L)) * np.where(rng.random(M) < 0.5, 0.02, 1.0)[:, None]
    w[rng.random(M) < 0.1] = 0.0                          # dead rays
    left = rng.integers(0, 100, M).astype(np.int64)
    hit_ray = np.sort(rng.choice(1000, M, replace=False))
    # the numpy reference
    r_ref = np.random.default_rng(seed)
    wr = w.copy()
    wmax = wr.max(axis=1)
    low_ref = (wmax < I._ROULETTE_BELOW) & (wmax > 0)
    if np.any(low_ref):
        survive = r_ref.random(int(low_ref.sum())) < I.ROULETTE_SURVIVE
        wl = wr[low_ref]
        wl[survive] /= I.ROULETTE_SURVIVE
        wl[~survive] = 0.0
        wr[low_ref] = wl
    alive = wr.max(axis=1) > 0
    ref = [o[alive], d[alive], wr[alive], hit_ray[alive], left[alive]]
    if wrap:
        ref[0][:, 0] %= lx
        ref[0][:, 1] %= ly
    # the kernels
    r_new = np.random.default_rng(seed)
    wn = w.copy()
    low = np.empty(M, np.bool_)
    n_low = I._path_roulette(wn, I._ROULETTE_BELOW, low)
    assert np.array_equal(low, low_ref) and 0 < n_low < M
    draws = r_new.random(int(n_low))
    nxt = (np.empty((M, 3)), np.empty((M, 3)), np.empty((M, L)), np.empty(M, np.int64), np.empty(M, np.int64))
    a = I._survivors(o, d, wn, left, hit_ray, low, draws, I.ROULETTE_SURVIVE, wrap, lx, ly, *nxt)
    assert a == np.count_nonzero(alive)
    for x, y in zip(nxt, ref, strict=True):
        assert np.array_equal(x[:a], y)
    assert np.array_equal(wn, wr)


# ------------------------------------------------------------------------------------------------
# the periodic cell's walk around Embree


def _ref_loop(scene, origins, directions, occlusion):
    """``PeriodicScene._loop`` in numpy (the wrap of a side face's rays to the opposite face included)."""
    n = origins.shape[0]
    o = np.array(origins, dtype=np.float64, copy=True)
    d = np.ascontiguousarray(directions, dtype=np.float64)
    prim = np.full(n, LOST, dtype=np.int64)
    u, v = np.zeros(n), np.zeros(n)
    seg_origin = o.copy()
    active = np.arange(n)
    t, face = np.empty(n), np.empty(n, dtype=np.int64)
    queries = 0
    for _ in range(scene.max_wraps + 1):
        if active.size == 0:
            break
        oa, da = o[active], d[active]
        ta, fa = t[:active.size], face[:active.size]
        _segment_limits(oa, da, scene.lx, scene.ly, scene.z_lo, scene.z_hi, ta, fa)
        queries += active.size
        dists = np.maximum(ta, 1e-6).astype(np.float32)
        if occlusion:
            res = scene._scene.run(oa.astype(np.float32), da.astype(np.float32), dists=dists, query="OCCLUDED")
            hit = res != -1
        else:
            res = scene._scene.run(oa.astype(np.float32), da.astype(np.float32), dists=dists, output=1)
            hit = res["primID"] >= 0
        idx = active[hit]
        if occlusion:
            prim[idx] = 0
        else:
            prim[idx] = res["primID"][hit]
            u[idx] = res["u"][hit]
            v[idx] = res["v"][hit]
            tf = res["tfar"][hit].astype(np.float64)
            seg_origin[idx] = oa[hit]
            o[idx] = oa[hit] + tf[:, None] * da[hit]
        miss = ~hit
        for mask, code in ((miss & (fa == 1), ESCAPED_UP), (miss & (fa == 2), ESCAPED_DOWN)):
            k = active[mask]
            prim[k] = code
            o[k] = oa[mask] + ta[mask, None] * da[mask]
        side = miss & (fa >= 3)
        if not np.any(side):
            break
        os_ = oa[side] + ta[side, None] * da[side]
        fs = fa[side]
        os_[fs == 3, 0] = 0.0
        os_[fs == 4, 0] = scene.lx
        os_[fs == 5, 1] = 0.0
        os_[fs == 6, 1] = scene.ly
        o[active[side]] = os_
        active = active[side]
    return prim, u, v, o, seg_origin, queries


def test_periodic_walk_matches_numpy():
    pytest.importorskip("embreex")
    rng = np.random.default_rng(7)
    lx, ly = 40.0, 30.0
    # small random triangles in the cell: many rays wrap several times before they hit or escape
    centres = np.column_stack([rng.uniform(0, lx, 60), rng.uniform(0, ly, 60), rng.uniform(0, 10, 60)])
    verts = (centres[:, None, :] + rng.normal(scale=2.0, size=(60, 3, 3))).reshape(-1, 3)
    verts[:, 0] = np.clip(verts[:, 0], 0, lx)
    verts[:, 1] = np.clip(verts[:, 1], 0, ly)
    faces = np.arange(verts.shape[0]).reshape(-1, 3)
    scene = PeriodicScene(verts, faces, lx, ly, max_wraps=8)
    N = 3000
    origins = np.column_stack([rng.uniform(0, lx, N), rng.uniform(0, ly, N), rng.uniform(scene.z_lo, scene.z_hi, N)])
    dirs = rng.normal(size=(N, 3))
    dirs[:, 2] *= 0.15                                # shallow: long walks through the cell's faces
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    for occlusion in (False, True):
        stats: dict = {}
        got = scene._loop(origins, dirs, occlusion, stats)
        ref = _ref_loop(scene, origins, dirs, occlusion)
        for a, b in zip(got, ref[:5], strict=True):
            assert np.array_equal(a, b)
        assert stats["queries"] == ref[5] > 2 * N       # the walk wrapped
        codes = set(np.unique(got[0]).tolist())
        assert {ESCAPED_UP, ESCAPED_DOWN, LOST} <= codes and max(codes) >= 0


# ------------------------------------------------------------------------------------------------
# one shading call for all the groups of a bounce


def test_shade_groups_is_one_shade_call_per_group():
    from simulate import fiber as F
    from simulate import raytrace as W
    from simulate.fabric import structure as ST
    from simulate.geometry.felt import felt_mesh
    from simulate.media.medium import HGMedium
    from simulate.raytrace.shading import ShadeOutputs, new_outputs, shade, shade_groups

    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.3, 10.0)
    table = W.yarn_table(fib, [550.0, 650.0], photons_per_row=600, seed=12, threads=1)
    mesh = felt_mesh(ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0, layers=3), 10.0, seed=0)
    setup = I._Setup(mesh, W.FiberSurface(table, 0.35, 1.5), 2, (9, 12))
    rng = np.random.default_rng(8)
    N = 600
    origins = np.column_stack([rng.uniform(0, mesh.Lx, N), rng.uniform(0, mesh.Ly, N), np.full(N, setup.scene.top)])
    dirs = np.tile(-np.array([0.3, 0.2, 0.93]) / np.linalg.norm([0.3, 0.2, 0.93]), (N, 1))
    hits = setup.scene.intersect(origins, dirs)
    h = hits.prim >= 0
    M = int(np.count_nonzero(h))
    assert M > 200
    prim, u, v, pos, d = hits.prim[h].astype(np.int64), hits.u[h], hits.v[h], hits.position[h], dirs[h]
    w = rng.random((M, 2))
    G, D = 3, 4
    det = rng.normal(size=(G, D, 3))
    det[..., 2] = np.abs(det[..., 2]) + 0.2
    det /= np.linalg.norm(det, axis=2)[..., None]
    cuts = np.array([0, M // 3, M // 3, M])        # the middle group has no hits
    seeds = np.array([11, 0, 13], np.int64)
    got = new_outputs(M, D, 2)
    shade_groups(seeds, cuts, prim, u, v, pos, d, w, setup.inputs, det, got)
    ref = new_outputs(M, D, 2)
    for g in (0, 2):
        a, b = cuts[g], cuts[g + 1]
        shade(int(seeds[g]), prim[a:b], u[a:b], v[a:b], pos[a:b], d[a:b], w[a:b],
              setup.inputs._replace(detectors=det[g]), ShadeOutputs(*(x[a:b] for x in ref)))
    for x, y in zip(got, ref, strict=True):
        assert np.array_equal(x, y)
    assert np.any(got.nee_need) and np.any(got.out_w > 0)
