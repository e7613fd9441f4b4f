"""The felt in the table cache: a hit is the built felt array for array; any changed input is a miss."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from simulate.fabric import structure as ST
from simulate.fiber import tablecache
from simulate.geometry import felt as FM
from simulate.geometry.mesh import FabricMesh


def _spec(**kw) -> ST.StructureSpec:
    return ST.StructureSpec(**{"kind": "nonwoven", "felt_spread_deg": 15.0, "layers": 1, **kw})


def _assert_same(a: FabricMesh, b: FabricMesh) -> None:
    for f in dataclasses.fields(FabricMesh):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), f.name
        else:
            assert type(x) is type(y) and x == y, f.name


@pytest.mark.parametrize("kw", [{}, {"felt_crimp_percent": 13.0}, {"felt_normal_fraction": 0.3}],
                         ids=["straight", "crimped", "needled"])
def test_a_hit_returns_the_felt_a_build_gives(cache_dir, kw):
    built = FM.felt_mesh(_spec(**kw), 10.0, seed=7)
    first, hit1 = FM.cached_felt_mesh(_spec(**kw), 10.0, seed=7)
    second, hit2 = FM.cached_felt_mesh(_spec(**kw), 10.0, seed=7)
    assert (hit1, hit2) == (False, True)
    assert len(list(cache_dir.glob("felt-*" + tablecache.SUFFIX))) == 1
    _assert_same(first, built)
    _assert_same(second, built)


def test_a_changed_input_is_a_miss_and_rebuilds(cache_dir):
    a, _ = FM.cached_felt_mesh(_spec(), 10.0, seed=1)
    b, hit = FM.cached_felt_mesh(_spec(felt_spread_deg=25.0), 10.0, seed=1)
    assert not hit
    assert not np.array_equal(a.tangents[a.vertex_base], b.tangents[b.vertex_base])
    c, hit = FM.cached_felt_mesh(_spec(), 10.0, seed=2)
    assert not hit and not np.array_equal(a.vertices[:10], c.vertices[:10])
    assert len(list(cache_dir.glob("felt-*" + tablecache.SUFFIX))) == 3


def test_the_key_covers_every_input_of_the_felt():
    base = FM.felt_key(_spec(), 10.0, seed=1)
    assert FM.felt_key(_spec(), 10.0, seed=1) == base
    changed = {"layers": 3, "packing_fraction": 0.5, "felt_spread_deg": 16.0, "felt_normal_fraction": 0.1,
               "felt_normal_spread_deg": 20.0, "felt_crimp_percent": 5.0, "felt_crimp_per_cm": 5.0,
               "felt_crimp_plane": "random", "felt_fuzz_fraction": 0.2, "felt_fuzz_depth_um": 200.0}
    # every input the felt reads is tried here (the spacing ratio through the packing fraction)
    assert set(changed) - {"packing_fraction"} | {"spacing_ratio"} == set(FM.felt_inputs(_spec()))
    for name, value in changed.items():
        assert FM.felt_key(dataclasses.replace(_spec(), **{name: value}), 10.0, seed=1) != base, name
    assert FM.felt_key(_spec(), 10.5, seed=1) != base
    assert FM.felt_key(_spec(), 10.0, seed=2) != base
    assert FM.felt_key(_spec(), 10.0, seed=1, sides=24) != base
    assert FM.felt_key(_spec(), 10.0, seed=1, n_s=5) != base
    # a field the felt does not read (a weave's twist) leaves the key as it is
    assert FM.felt_key(dataclasses.replace(_spec(), warp_twist_deg=30.0), 10.0, seed=1) == base


def test_the_structures_felt_fields_are_all_inputs():
    names = {f.name for f in dataclasses.fields(ST.StructureSpec)}
    assert {n for n in names if n.startswith("felt_")} | {"layers", "spacing_ratio"} == set(FM.felt_inputs(_spec()))


def test_the_key_follows_the_felt_code(monkeypatch):
    base = FM.felt_key(_spec(), 10.0, seed=1)
    seen = []

    def other_code(modules):
        seen.append(tuple(modules))
        return "0" * 64
    monkeypatch.setattr(tablecache, "code_version", other_code)
    assert FM.felt_key(_spec(), 10.0, seed=1) != base
    assert "simulate.geometry.felt" in seen[0] and "simulate.geometry.mesh" in seen[0]


def _dot(x, y):
    """A row-wise dot product of 3-vectors summed in the order the compiled kernel sums it,
    ``(x0 y0 + x2 y2) + x1 y1``, with numpy's element-wise ``*`` and ``+`` (``np.einsum`` may sum in
    another order, and fuse, depending on the CPU's vector width)."""
    return (x[..., 0] * y[..., 0] + x[..., 2] * y[..., 2]) + x[..., 1] * y[..., 1]


def _segment_distance_ordered(p1, d1, p2, d2):
    """``simulate.geometry.felt._segment_distance`` with its dot products summed by :func:`_dot`."""
    r = p1 - p2
    a, e, b, c, f = _dot(d1, d1), _dot(d2, d2), _dot(d1, d2), _dot(d1, r), _dot(d2, r)
    den = a * e - b * b
    skew = den > 1e-12 * a * e
    s = np.where(skew, np.clip((b * f - c * e) / np.where(skew, den, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    d = r + s[..., None] * d1 - t[..., None] * d2
    return np.sqrt(_dot(d, d))


def _free_height_numpy(p1, d1, p2, d2, span, zj, z, contact, iters):
    """The placement's lowest free height computed with numpy over all pairs at once (the compiled kernel's
    reference: golden section for each pair's closest height, bisection for its overlap interval's ends).

    Bit for bit on any CPU by construction: both sides use only ``+ - * /``, ``sqrt``, ``min``/``max``
    and comparisons (IEEE 754 correctly rounded everywhere; the kernel is compiled without fastmath, so
    LLVM fuses no multiply-add) in the same order (:func:`_dot`), so every comparison, and the mesh,
    come out the same."""
    def gap(w, rows):
        sel = slice(None) if rows is None else rows
        p = np.array(p1[sel])
        p[:, 2] += w
        return _segment_distance_ordered(p, d1[sel], p2[sel], d2[sel])

    a, b = -span, span.copy()
    golden = 0.5 * (np.sqrt(5.0) - 1.0)
    for _ in range(iters):
        c1, c2 = b - golden * (b - a), a + golden * (b - a)
        left = gap(c1, None) < gap(c2, None)
        a, b = np.where(left, a, c1), np.where(left, c2, b)
    w_min = 0.5 * (a + b)
    hit = gap(w_min, None) < contact
    rows = np.flatnonzero(hit)
    zj, w_min, span = zj[hit], w_min[hit], span[hit]
    top_in, top_out, bot_out, bot_in = w_min.copy(), span.copy(), -span, w_min.copy()
    for _ in range(iters):
        mid = 0.5 * (top_in + top_out)
        inside = gap(mid, rows) < contact
        top_in, top_out = np.where(inside, mid, top_in), np.where(inside, top_out, mid)
        mid = 0.5 * (bot_out + bot_in)
        inside = gap(mid, rows) < contact
        bot_out, bot_in = np.where(inside, bot_out, mid), np.where(inside, mid, bot_in)
    lo, hi = zj + bot_out, zj + top_out
    for s0, e0 in zip(*(v[np.argsort(lo)] for v in (lo, hi)), strict=True):
        if s0 >= z:
            break
        z = max(z, float(e0))
    return z


@pytest.mark.parametrize("kw, seed", [({}, 0), ({}, 1_000_003), ({"felt_spread_deg": 5.0}, 5),
                                      ({"felt_crimp_percent": 13.0}, 3),
                                      ({"felt_crimp_percent": 20.0, "felt_crimp_per_cm": 10.0,
                                        "felt_crimp_plane": "random", "felt_fuzz_fraction": 0.2, "felt_fuzz_depth_um": 200.0}, 4),
                                      ({"felt_normal_fraction": 0.3}, 2)],
                         ids=["seed0", "seed1000003", "seed5", "crimped", "crimped-random", "needled"])
def test_the_compiled_placement_builds_the_felt_bit_for_bit(monkeypatch, kw, seed):
    spec = _spec(layers=3, **kw)
    fast = FM.felt_mesh(spec, 10.0, seed=seed)
    monkeypatch.setattr(FM, "_free_height", _free_height_numpy)
    _assert_same(fast, FM.felt_mesh(spec, 10.0, seed=seed))
