"""A nonwoven felt for the ray tracer: a random layer of fibers in a periodic cell.

The summation's felt (:func:`simulate.fabric.structure.felt_facets`, docs/physics.md 6.2) built as
geometry and traced on Embree like the weave's yarns: straight or crimped tubes of the fiber's radius
``R``, in-plane direction uniform, inclination normal with standard deviation ``felt_spread_deg``
(truncated at +-80 deg), as much fiber per unit area as the summation's ``layers`` layers.

Public objects
--------------
- :func:`felt_mesh`: the felt of a ``[structure]`` as a :class:`~simulate.geometry.mesh.FabricMesh`
  (one "yarn" per fiber image); :func:`felt_inputs`: the fields it reads.
- :func:`cached_felt_mesh`, :func:`felt_key`, :data:`CACHE_MODULES`: a felt through the table cache
  (:mod:`simulate.fiber.tablecache`), keyed by every input and this module's source.
- :func:`crimp_axis`, :func:`crimp_amplitude`: a crimped fiber's sine; :func:`fiber_pieces`: a mesh's
  fiber axes as straight pieces; :data:`CELL_RADII`, :data:`LENGTH_RADII`.

Notes
-----
- **Deposition.** No two fibers interpenetrate (a tracer walking each fiber's volume from its exit
  table would walk shared material twice): each fiber goes at the lowest height where it lies on the
  floor or in a gap of the fibers below, axes ``2 R`` apart (:func:`_lowest_free_height`). The felt
  takes the thickness this gives (``info["volume_fraction"]``); its top is at ``z = 0``.
- **Cell and mesh.** ``[0, L)^2``, ``L = 40 R``, fibers ``40 R`` long, put in at their periodic images
  too; open tubes (``open_fibers``), ``s`` the arc length, the yarn table the fiber's own (``r_yarn = R``).
- **Needle-punched fibers** (``felt_normal_fraction``, ``felt_normal_spread_deg``): a second population
  tilted from the normal by ``|N(0, felt_normal_spread_deg)|`` [1], deposited like the others.
- **Crimp** (``felt_crimp_percent``, ``felt_crimp_per_cm``, ``felt_crimp_plane``): each fiber a piece of
  a sine whose wave's arc length is ``lambda / (1 - c)`` [2] (:func:`crimp_amplitude`), lying in the
  felt's plane or turned about its run; its axis a polyline (:func:`_crimp_pieces`), its rings in a
  parallel-transported frame, placed against every piece it can meet.
- **Loose top** (``felt_fuzz_fraction``, ``felt_fuzz_depth_um``): the last fibers' lowest points drawn
  uniformly over a depth above the compact felt's top (:func:`_place_loose`).
- Each option at 0 (its default) draws nothing from the stream; the summation's felt has none of them.
- Limits: rigid fibers, a flat floor, a cell of about 20 fibers across (the spread between
  realisations goes into ``u_beta``: :mod:`simulate.raytrace.estimate`, "A felt"). Volume fractions and
  what the options change: docs/physics.md 6 ("Felt"), docs/notes/felt-structure.md.

References
----------
[1] Fiber orientation of needle-punched nonwovens by X-ray CT, Text. Res. J., doi 10.1177/0040517517736470.
[2] ASTM D3937, crimp frequency of manufactured staple fibers.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np

from simulate.geometry.mesh import FabricMesh, grid_faces

__all__ = ["felt_mesh", "felt_inputs", "LOOSE_TRIES", "felt_key", "cached_felt_mesh", "CACHE_MODULES", "CELL_RADII", "LENGTH_RADII", "crimp_amplitude", "crimp_axis", "fiber_pieces"]

#: the cell's side and the fibers' length, in fiber radii
CELL_RADII = 40.0
LENGTH_RADII = 40.0
#: two fibers' axes are kept at least this many diameters apart (a margin for rounding; the mesh's
#: polygonal tubes are inscribed in the cylinders)
CONTACT = 1.0 + 1e-6
#: a crimped fiber's polyline leaves its sine by at most this many fiber radii between two rings, with
#: at most ``MAX_PIECES`` pieces (:func:`_crimp_pieces`)
CRIMP_SAGITTA = 0.1
MAX_PIECES = 16
#: a loose top fiber's height is drawn at most this many times (:func:`_place_loose`)
LOOSE_TRIES = 1000



def _tube(c: np.ndarray, t: np.ndarray, radius: float, length: float, n_s: int, sides: int):
    """Vertices, normals, s and phi of one straight tube (centre ``c``, unit direction ``t``)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(t[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, t)
    u /= np.linalg.norm(u)
    v = np.cross(t, u)                       # (u, v, t) right-handed: dP/dphi x dP/ds points out
    s = np.linspace(0.0, length, n_s + 1)
    phi = 2.0 * math.pi * np.arange(sides + 1) / sides
    cos, sin = np.cos(phi), np.sin(phi)
    cos[-1], sin[-1] = cos[0], sin[0]
    S, C = np.meshgrid(s, cos, indexing="ij")
    _, Sn = np.meshgrid(s, sin, indexing="ij")
    nrm = C[..., None] * u + Sn[..., None] * v
    pts = c + (S[..., None] - 0.5 * length) * t + radius * nrm
    PHI = np.broadcast_to(phi[None, :], S.shape)
    return pts.reshape(-1, 3), nrm.reshape(-1, 3), S.reshape(-1), PHI.reshape(-1)


def crimp_amplitude(percent: float, wavelength: float) -> float:
    """The amplitude ``A`` of the sine ``A sin(2 pi x / wavelength)`` whose crimp is ``percent``.

    One wave's arc length is ``wavelength / (1 - percent / 100)`` (module docstring, "Crimp"). 0 at 0.
    """
    c = float(percent) / 100.0
    if c <= 0.0:
        return 0.0
    target = 1.0 / (1.0 - c)
    u = 2.0 * math.pi * np.arange(4096) / 4096    # one period: the mean of a periodic integrand

    def stretch(k: float) -> float:                  # arc length over wavelength at slope amplitude k
        return float(np.mean(np.sqrt(1.0 + (k * np.cos(u)) ** 2)))

    lo, hi = 0.0, 2.0 * target + 1.0                  # stretch(k) >= 2 k / pi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stretch(mid) < target else (lo, mid)
    return 0.5 * (lo + hi) * wavelength / (2.0 * math.pi)


def crimp_axis(length: float, amplitude: float, wavelength: float, phase: float, n: int):
    """A crimped fiber's axis in its wave's frame.

    ``n + 1`` points at uniform arc length over ``length`` on ``y = A (sin(k x + phase) - sin(phase))``
    (``k = 2 pi / wavelength``), the arc's midpoint at the origin. Returns ``x``, ``y`` and the slope
    ``dy/dx`` at the points.
    """
    k = 2.0 * math.pi / wavelength
    x = np.linspace(-0.5 * length, 0.5 * length, 4001)   # the arc is at least its chord: x within +-l/2
    ds = np.sqrt(1.0 + (amplitude * k * np.cos(k * x + phase)) ** 2)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]) * np.diff(x))])
    s -= s[2000]                                          # arc length from the midpoint x = 0
    xk = np.interp(length * (np.arange(n + 1) / n - 0.5), s, x)
    return (xk, amplitude * (np.sin(k * xk + phase) - math.sin(phase)),
            amplitude * k * np.cos(k * xk + phase))


def _crimp_pieces(ell: float, R: float, amplitude: float, wavelength: float, n_s: int) -> int:
    """Pieces of a crimped fiber's polyline: at least ``n_s``, at most ``MAX_PIECES``.

    Enough that the axis leaves the sine by at most ``CRIMP_SAGITTA R`` between two rings (the sagitta
    ``l^2 kappa / 8`` at the sine's largest curvature ``A k^2``).
    """
    kappa = amplitude * (2.0 * math.pi / wavelength) ** 2
    if kappa <= 0.0:
        return n_s
    piece = math.sqrt(8.0 * CRIMP_SAGITTA * R / kappa)
    return int(min(max(math.ceil(ell / piece), n_s), MAX_PIECES))


def _crimp_plane(t: np.ndarray, turn: float) -> np.ndarray:
    """The crimp's displacement direction for a fiber along ``t``.

    The horizontal perpendicular ``z x t`` (the felt's plane), turned by ``turn`` about ``t``.
    """
    h = np.cross([0.0, 0.0, 1.0], t)
    if np.linalg.norm(h) < 1e-9:                          # a fiber along the normal: any perpendicular
        h = np.cross([1.0, 0.0, 0.0], t)
    h /= np.linalg.norm(h)
    return h if turn == 0.0 else math.cos(turn) * h + math.sin(turn) * np.cross(t, h)


def _crimped_tube(c: np.ndarray, t: np.ndarray, d: np.ndarray, radius: float, length: float, amplitude: float,
                  wavelength: float, phase: float, n_s: int, sides: int):
    """Vertices, normals, tangents, s and phi of one crimped tube; also the ring centres.

    Its axis is :func:`crimp_axis` in the plane of ``t`` (the wave's run) and ``d`` (its displacement,
    unit, perpendicular to ``t``), the arc's midpoint at
    ``c``; rings of ``sides`` at its ``n_s + 1`` points, perpendicular to the sine's tangent there, in a
    parallel-transported frame (``phi`` continuous along the fiber).
    """
    x, y, slope = crimp_axis(length, amplitude, wavelength, phase, n_s)
    P = c + x[:, None] * t + y[:, None] * d
    T = t + slope[:, None] * d
    T /= np.linalg.norm(T, axis=1)[:, None]
    helper = np.array([0.0, 0.0, 1.0]) if abs(T[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    U = np.zeros_like(T)
    U[0] = np.cross(helper, T[0])
    U[0] /= np.linalg.norm(U[0])
    for k in range(1, n_s + 1):                           # transport: drop the new tangent's component
        u = U[k - 1] - (U[k - 1] @ T[k]) * T[k]
        U[k] = u / np.linalg.norm(u)
    V = np.cross(T, U)                                    # (u, v, t) right-handed, as a straight tube
    phi = 2.0 * math.pi * np.arange(sides + 1) / sides
    cos, sin = np.cos(phi), np.sin(phi)
    cos[-1], sin[-1] = cos[0], sin[0]
    nrm = cos[None, :, None] * U[:, None, :] + sin[None, :, None] * V[:, None, :]
    pts = P[:, None, :] + radius * nrm
    S = np.broadcast_to(np.linspace(0.0, length, n_s + 1)[:, None], nrm.shape[:2])
    PHI = np.broadcast_to(phi[None, :], nrm.shape[:2])
    tans = np.broadcast_to(T[:, None, :], nrm.shape)
    return (pts.reshape(-1, 3), nrm.reshape(-1, 3), tans.reshape(-1, 3), S.reshape(-1), PHI.reshape(-1), P)


def _fiber_tops(C: np.ndarray, T: np.ndarray, P0: np.ndarray, PD: np.ndarray, crimped: bool, ell: float,
                R: float) -> np.ndarray:
    """Each placed fiber's highest point.

    A straight one's from its centre ``C``, direction ``T`` and length ``ell``, a crimped one's from its
    pieces ``P0``, ``PD`` (from its centre).
    """
    if crimped:
        ends = np.concatenate([P0[:, :, 2], P0[:, -1:, 2] + PD[:, -1:, 2]], axis=1)
        return C[:, 2] + ends.max(axis=1) + R
    return C[:, 2] + 0.5 * ell * np.abs(T[:, 2]) + R


def _place_loose(place: Callable[..., float], rng: np.random.Generator, xy: np.ndarray, low: float,
                 top: float, depth: float, L: float) -> tuple[np.ndarray, float]:
    """A loose top fiber's position and centre height (module docstring, "Loose top").

    Its lowest point is drawn uniformly in ``[top, top + depth]`` and the fiber over ``xy`` put at the
    lowest free height from there
    (``place(xy, floor)``, the deposition's rule); when the loose fibers placed there raise it beyond
    ``top + depth``, drawn again at a new position in the cell (``L``). ``low``: the fiber's centre over its
    lowest point.
    """
    from simulate.montecarlo import ParameterError

    for k in range(LOOSE_TRIES):
        if k:
            xy = np.array([rng.uniform(0.0, L), rng.uniform(0.0, L)])
        z = place(xy, floor=top + rng.uniform(0.0, depth))
        if z - low <= top + depth:
            return xy, z
    raise ParameterError(f"[structure] felt_fuzz_depth_um = {depth:g}: the loose top fibers (felt_fuzz_fraction) "
                         "do not fit in that depth; raise felt_fuzz_depth_um or lower felt_fuzz_fraction")


def _segment_distance(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Closest distance between the segments ``p1 + s d1`` and ``p2 + t d2``, ``s, t`` in ``[0, 1]``.

    Rows broadcast; no degenerate segment. The clamped closest-point solution of Ericson (2005),
    *Real-Time Collision Detection*, section 5.1.9, vectorised.
    """
    r = p1 - p2
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    b = np.einsum("...i,...i->...", d1, d2)
    c = np.einsum("...i,...i->...", d1, r)
    f = np.einsum("...i,...i->...", d2, r)
    den = a * e - b * b
    skew = den > 1e-12 * a * e                 # not parallel
    s = np.where(skew, np.clip((b * f - c * e) / np.where(skew, den, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    d = r + s[..., None] * d1 - t[..., None] * d2
    return np.sqrt(np.einsum("...i,...i->...", d, d))


def _image_offsets(xy: np.ndarray, C: np.ndarray, L: float) -> np.ndarray:
    """The candidate's centre ``xy`` from each placed fiber's centre ``C[:, :2]`` in the plane.

    The nearest periodic image and its 8 neighbours, ``[len(C) * 9, 2]`` (fiber by fiber, 9 images each).
    """
    shifts = np.array([[i * L, j * L] for i in (-1, 0, 1) for j in (-1, 0, 1)])
    dxy = xy[None, :] - C[:, :2]
    dxy -= L * np.round(dxy / L)               # the nearest image, then its neighbours
    return (dxy[:, None, :] + shifts[None]).reshape(-1, 2)


def _lowest_free_height(xy: np.ndarray, t: np.ndarray, C: np.ndarray, T: np.ndarray, R: float, ell: float,
                        L: float, iters: int = 36, floor: float = 0.0) -> float:
    """The lowest centre height at which a fiber over ``xy`` touches none of the fibers placed so far.

    The fiber, of direction ``t``, lies on the floor or in a gap of the placed fibers (centres ``C``,
    directions ``T``, periodic with period ``L``) without overlapping any of them (module docstring:
    contact distance ``CONTACT x 2R`` between the axes).

    For each fiber it can meet (its axis within ``2R`` of the candidate's in the plane: a necessary
    condition), the distance between the two axes as the candidate is moved vertically by ``w`` is
    convex in ``w`` (the distance between a translated convex set and a fixed one), so the heights at
    which they overlap are one interval: its minimum by golden section, its ends by bisection. The
    candidate goes at the lowest height above the floor outside every interval. ``floor``: the height the
    fiber's lowest point may not go below (0: the felt's floor; a loose top fiber's drawn height).
    """
    z = 0.5 * ell * abs(t[2]) + R + floor       # resting on the floor z = floor
    if len(C) == 0:
        return z
    contact = 2.0 * R * CONTACT
    q = np.zeros((len(C) * 9, 3))
    q[:, :2] = _image_offsets(xy, C, L)
    Tj, zj = np.repeat(T, 9, axis=0), np.repeat(C[:, 2], 9)
    t2, Tj2 = t * [1.0, 1.0, 0.0], Tj * [1.0, 1.0, 0.0]
    near = _segment_distance(q - 0.5 * ell * t2, ell * t2, -0.5 * ell * Tj2, ell * Tj2) < contact
    if not near.any():
        return z
    q, Tj, zj = q[near], Tj[near], zj[near]
    p1 = q - 0.5 * ell * t                       # the candidate's axis, its centre w above j's (q[:, 2] = 0)
    span = 0.5 * ell * (abs(t[2]) + np.abs(Tj[:, 2])) + contact + 1.0
    return _free_height(p1, np.broadcast_to(ell * t, p1.shape), -0.5 * ell * Tj, ell * Tj, span, zj, z, contact, iters)


def _lowest_free_height_pieces(xy: np.ndarray, A0: np.ndarray, AD: np.ndarray, C: np.ndarray, P0: np.ndarray,
                               PD: np.ndarray, R: float, L: float, iters: int = 36, floor: float = 0.0) -> float:
    """:func:`_lowest_free_height` for fibers made of straight pieces (a crimped fiber's polyline).

    The candidate's pieces start at ``A0`` (``[n, 3]``, from its centre) with vectors ``AD``; the placed
    fibers' centres are ``C`` (``[m, 3]``), their pieces ``P0``, ``PD`` (``[m, n, 3]``). The argument holds
    per pair of pieces (the distance between a vertically moved segment and a fixed one is convex in the
    move), so every pair that can meet gives one interval of forbidden heights, and the candidate goes at
    the lowest height above the floor outside all of them. Pairs that cannot meet are left out first: whole
    fibers by their reach in the plane, then pieces by their midpoints' distance in the plane.
    """
    ends = np.concatenate([A0[:, 2], A0[:, 2] + AD[:, 2]])
    z = R - float(ends.min()) + floor               # resting on the floor z = floor
    if len(C) == 0:
        return z
    contact = 2.0 * R * CONTACT
    q = _image_offsets(xy, C, L)
    fiber = np.repeat(np.arange(len(C)), 9)

    def reach(p0: np.ndarray, pd: np.ndarray) -> np.ndarray:     # farthest point from the centre, in the plane
        return np.maximum(np.linalg.norm(p0[..., :2], axis=-1), np.linalg.norm((p0 + pd)[..., :2], axis=-1)).max(-1)

    near = np.linalg.norm(q, axis=1) < reach(A0, AD) + reach(P0, PD)[fiber] + contact
    if not near.any():
        return z
    q, fiber = q[near], fiber[near]
    # every (image, candidate piece, placed piece) whose midpoints are close enough in the plane
    am = A0 + 0.5 * AD                               # [n, 3]
    bm = P0[fiber] + 0.5 * PD[fiber]                 # [K, n, 3]
    sep = q[:, None, None, :] + am[None, :, None, :2] - bm[:, None, :, :2]
    half = 0.5 * (np.linalg.norm(AD, axis=1)[None, :, None] + np.linalg.norm(PD[fiber], axis=2)[:, None, :])
    img, ia, ib = np.nonzero(np.linalg.norm(sep, axis=-1) < half + contact)
    if len(img) == 0:
        return z
    j = fiber[img]
    qa = np.zeros((len(img), 3))
    qa[:, :2] = q[img]
    a0, ad = qa + A0[ia], AD[ia]                    # the candidate's piece, its centre at height 0 ...
    b0, bd = P0[j, ib], PD[j, ib]                   # ... over the placed piece (its fiber's centre at 0)
    zj = C[j, 2]

    def zext(p0: np.ndarray, pd: np.ndarray) -> np.ndarray:
        return np.maximum(np.abs(p0[:, 2]), np.abs(p0[:, 2] + pd[:, 2]))

    span = zext(a0, ad) + zext(b0, bd) + contact + 1.0
    return _free_height(a0, ad, b0, bd, span, zj, z, contact, iters)


def _free_height(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray, span: np.ndarray, zj: np.ndarray,
                 z: float, contact: float, iters: int) -> float:
    """The lowest height ``>= z`` outside every pair's overlap interval (:func:`_lowest_free_height`).

    Pair ``i``: the candidate's segment ``p1[i] + w e_z`` (``w`` its centre's height over the placed
    piece's fiber centre) along ``d1[i]``, the placed one ``p2[i]`` along ``d2[i]``; ``span``: a relative
    height beyond which the pair cannot overlap; ``zj``: the placed fibers' centre heights. A pair's overlap
    heights are one interval (the distance is convex in ``w``): its minimum by golden section, its ends by
    bisection (:func:`_overlap_intervals`, compiled).
    """
    lo, hi = _overlap_intervals(np.ascontiguousarray(p1, dtype=float), np.ascontiguousarray(d1, dtype=float),
                                np.ascontiguousarray(p2, dtype=float), np.ascontiguousarray(d2, dtype=float),
                                np.ascontiguousarray(span, dtype=float), np.ascontiguousarray(zj, dtype=float),
                                float(contact), int(iters))
    for s0, e0 in zip(*(v[np.argsort(lo)] for v in (lo, hi)), strict=True):
        if s0 >= z:
            break
        z = max(z, float(e0))
    return z


@numba.njit(cache=True)
def _pair_gap(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray, i: int, w: float) -> float:
    """:func:`_segment_distance` of pair ``i`` with the candidate raised by ``w``.

    The same operations in the same order, so the same bits.
    """
    r0, r1, r2 = p1[i, 0] - p2[i, 0], p1[i, 1] - p2[i, 1], (p1[i, 2] + w) - p2[i, 2]
    u0, u1, u2 = d1[i, 0], d1[i, 1], d1[i, 2]
    v0, v1, v2 = d2[i, 0], d2[i, 1], d2[i, 2]
    # the dot products summed as numpy's einsum sums three terms: (x0 y0 + x2 y2) + x1 y1
    a = (u0 * u0 + u2 * u2) + u1 * u1
    e = (v0 * v0 + v2 * v2) + v1 * v1
    b = (u0 * v0 + u2 * v2) + u1 * v1
    c = (u0 * r0 + u2 * r2) + u1 * r1
    f = (v0 * r0 + v2 * r2) + v1 * r1
    den = a * e - b * b
    s = 0.0
    if den > 1e-12 * a * e:                    # not parallel
        s = min(max((b * f - c * e) / den, 0.0), 1.0)
    t = (b * s + f) / e
    if t < 0.0:
        s = min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        s = min(max((b - c) / a, 0.0), 1.0)
    t = min(max(t, 0.0), 1.0)
    x0 = r0 + s * u0 - t * v0
    x1 = r1 + s * u1 - t * v1
    x2 = r2 + s * u2 - t * v2
    return math.sqrt((x0 * x0 + x2 * x2) + x1 * x1)


@numba.njit(cache=True)
def _overlap_intervals(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray, span: np.ndarray,
                       zj: np.ndarray, contact: float, iters: int) -> tuple[np.ndarray, np.ndarray]:
    """The overlap intervals ``[lo, hi]`` of the pairs that overlap somewhere (:func:`_free_height`).

    Absolute heights, both ends on the free side; each pair's golden section and bisections in turn.
    """
    golden = 0.5 * (math.sqrt(5.0) - 1.0)
    n = len(span)
    lo, hi = np.empty(n), np.empty(n)
    k = 0
    for i in range(n):
        a, b = -span[i], span[i]
        for _ in range(iters):
            c1, c2 = b - golden * (b - a), a + golden * (b - a)
            if _pair_gap(p1, d1, p2, d2, i, c1) < _pair_gap(p1, d1, p2, d2, i, c2):
                b = c2
            else:
                a = c1
        w_min = 0.5 * (a + b)
        if not _pair_gap(p1, d1, p2, d2, i, w_min) < contact:
            continue
        top_in, top_out = w_min, span[i]                # the interval's upper end
        bot_out, bot_in = -span[i], w_min               # and its lower end
        for _ in range(iters):
            mid = 0.5 * (top_in + top_out)
            if _pair_gap(p1, d1, p2, d2, i, mid) < contact:
                top_in = mid
            else:
                top_out = mid
            mid = 0.5 * (bot_out + bot_in)
            if _pair_gap(p1, d1, p2, d2, i, mid) < contact:
                bot_in = mid
            else:
                bot_out = mid
        lo[k], hi[k] = zj[i] + bot_out, zj[i] + top_out
        k += 1
    return lo[:k], hi[:k]


def felt_inputs(spec: object) -> dict:
    """Every field of ``spec`` the felt is built from, with the defaults of a spec that lacks one.

    :func:`felt_mesh` reads them here only: with the radius, the seed and the mesh's sizes, the whole of a
    felt's inputs (the key of :func:`cached_felt_mesh`).
    """
    return {"layers": int(getattr(spec, "layers", 0)),
            "spacing_ratio": float(getattr(spec, "spacing_ratio", 1.0)),
            "felt_spread_deg": float(getattr(spec, "felt_spread_deg", 20.0)),
            "felt_normal_fraction": float(getattr(spec, "felt_normal_fraction", 0.0)),
            "felt_normal_spread_deg": float(getattr(spec, "felt_normal_spread_deg", 15.0)),
            "felt_crimp_percent": float(getattr(spec, "felt_crimp_percent", 0.0)),
            "felt_crimp_per_cm": float(getattr(spec, "felt_crimp_per_cm", 4.4)),
            "felt_crimp_plane": str(getattr(spec, "felt_crimp_plane", "felt")),
            "felt_fuzz_fraction": float(getattr(spec, "felt_fuzz_fraction", 0.0)),
            "felt_fuzz_depth_um": float(getattr(spec, "felt_fuzz_depth_um", 300.0))}


@dataclass(frozen=True)
class _FeltParameters:
    """What :func:`felt_mesh` builds a felt from, in micrometres and radians (:func:`felt_inputs` resolved)."""

    R: float                 # fiber radius
    L: float                 # the cell's side
    ell: float               # fiber length
    layers: int
    target: float            # the layers' projected fiber area
    spread: float            # sd of an in-plane fiber's inclination
    punched: float           # fraction of needle-punched fibers
    tilt_sd: float           # sd of a needle-punched fiber's tilt from the normal
    crimp: float             # crimp percentage (0: straight fibers)
    wavelength: float        # crimp wave length
    amplitude: float         # crimp wave amplitude
    random_plane: bool       # crimp wave turned about its run by a uniform angle
    n_s: int                 # pieces per fiber
    fuzz: float              # fraction of the fiber amount in the loose top
    fuzz_depth: float        # depth of the loose top


def _felt_parameters(spec: object, radius_um: float, n_s: int) -> _FeltParameters:
    """The felt's parameters from ``spec`` (:func:`felt_inputs`) and the fiber radius."""
    R = float(radius_um)
    L = CELL_RADII * R
    ell = LENGTH_RADII * R
    given = felt_inputs(spec)
    layers = given["layers"] or 10
    crimp = given["felt_crimp_percent"]
    wavelength, amplitude, random_plane = 1.0, 0.0, False
    if crimp > 0.0:                            # crimped fibers (drawn only then: a straight felt keeps its stream)
        wavelength = 1e4 / given["felt_crimp_per_cm"]
        amplitude = crimp_amplitude(crimp, wavelength)
        random_plane = given["felt_crimp_plane"] == "random"
        n_s = _crimp_pieces(ell, R, amplitude, wavelength, n_s)
    return _FeltParameters(
        R=R, L=L, ell=ell, layers=layers, target=layers * L * L / given["spacing_ratio"],
        spread=math.radians(given["felt_spread_deg"]), punched=given["felt_normal_fraction"],
        tilt_sd=math.radians(given["felt_normal_spread_deg"]), crimp=crimp, wavelength=wavelength,
        amplitude=amplitude, random_plane=random_plane, n_s=n_s, fuzz=given["felt_fuzz_fraction"],
        fuzz_depth=given["felt_fuzz_depth_um"])


def _draw_direction(rng: np.random.Generator, fp: _FeltParameters) -> tuple[np.ndarray, float, bool, bool]:
    """One fiber's direction from the stream: ``(t, amount, flat, punched)``.

    ``amount`` is the fiber's projected area (a needle-punched fiber's counted as a fiber lying flat),
    ``flat`` whether the fiber is an in-plane one, ``punched`` whether it is a needle-punched one.
    """
    R, ell = fp.R, fp.ell
    az = rng.uniform(0.0, math.pi)
    # a needle-punched fiber (drawn only when the fraction is set: an in-plane felt keeps its stream)
    if fp.punched > 0.0 and rng.uniform() < fp.punched:
        az *= 2.0                          # the tilt's azimuth over the full circle
        tilt = abs(rng.normal(0.0, fp.tilt_sd)) if fp.tilt_sd > 0 else 0.0
        while tilt > math.radians(80.0):
            tilt = abs(rng.normal(0.0, fp.tilt_sd))
        eps = 0.5 * math.pi - tilt
        amount = 2.0 * R * ell             # its material, counted as a fiber lying flat
        punched, flat = True, False
    else:
        eps = rng.normal(0.0, fp.spread) if fp.spread > 0 else 0.0
        while abs(eps) > math.radians(80.0):
            eps = rng.normal(0.0, fp.spread)
        amount = 2.0 * R * ell * math.cos(eps)
        punched, flat = False, True
    t = np.array([math.cos(eps) * math.cos(az), math.cos(eps) * math.sin(az), math.sin(eps)])
    return t, amount, flat, punched


@dataclass
class _Deposit:
    """The fibers deposited so far: centres ``C``, directions ``T``, a crimped felt's pieces and waves."""

    C: np.ndarray
    T: np.ndarray
    P0: np.ndarray           # crimped: each fiber's pieces' starts, from its centre
    PD: np.ndarray           # crimped: each fiber's pieces' vectors
    planes: list = field(default_factory=list)
    phases: list = field(default_factory=list)
    n_normal: int = 0        # needle-punched fibers
    n_compact: int = -1      # fibers of the compact felt (set when the first loose fiber is drawn)
    top_compact: float = 0.0


def _placement(rng: np.random.Generator, fp: _FeltParameters, dep: _Deposit, t: np.ndarray, flat: bool,
               amount: float) -> tuple[Callable[..., float], float, float, tuple | None]:
    """How a fiber along ``t`` is placed: ``(place, low, amount, wave)``.

    ``place(xy, floor)`` is its lowest free height over ``xy``, ``low`` its centre over its lowest point,
    ``amount`` its projected area (a crimped in-plane fiber's polyline's), ``wave`` a crimped fiber's
    ``(p0, pd, plane, phase)`` (None for a straight one). A crimped fiber draws its phase and plane here.
    """
    R, ell = fp.R, fp.ell
    if fp.crimp > 0.0:
        phase = rng.uniform(0.0, 2.0 * math.pi)
        d = _crimp_plane(t, rng.uniform(0.0, 2.0 * math.pi) if fp.random_plane else 0.0)
        x, y, _ = crimp_axis(ell, fp.amplitude, fp.wavelength, phase, fp.n_s)
        pts = x[:, None] * t + y[:, None] * d
        p0, pd = pts[:-1], np.diff(pts, axis=0)
        if flat:                           # the polyline's projected area
            amount = 2.0 * R * float(np.linalg.norm(pd[:, :2], axis=1).sum())
        low = R - float(np.concatenate([p0[:, 2], p0[:, 2] + pd[:, 2]]).min())   # centre over lowest point
        place: Callable[..., float] = functools.partial(
            _lowest_free_height_pieces, A0=p0, AD=pd, C=dep.C, P0=dep.P0, PD=dep.PD, R=R, L=fp.L)
        return place, low, amount, (p0, pd, d, phase)
    low = 0.5 * ell * abs(t[2]) + R
    place = functools.partial(_lowest_free_height, t=t, C=dep.C, T=dep.T, R=R, ell=ell, L=fp.L)
    return place, low, amount, None


def _deposit(fp: _FeltParameters, rng: np.random.Generator) -> _Deposit:
    """Deposit fibers one by one until their projected area reaches the layers' (module docstring)."""
    compact = fp.target * (1.0 - fp.fuzz)     # the compact felt's amount; the rest is the loose top's
    area = 0.0
    dep = _Deposit(C=np.zeros((0, 3)), T=np.zeros((0, 3)), P0=np.zeros((0, fp.n_s, 3)), PD=np.zeros((0, fp.n_s, 3)))
    while area < fp.target:
        t, amount, flat, punched = _draw_direction(rng, fp)
        dep.n_normal += punched
        xy = np.array([rng.uniform(0.0, fp.L), rng.uniform(0.0, fp.L)])
        place, low, amount, wave = _placement(rng, fp, dep, t, flat, amount)
        if fp.fuzz > 0.0 and area >= compact:    # a loose top fiber (drawn only then: a compact felt keeps its stream)
            if dep.n_compact < 0:
                dep.n_compact = len(dep.C)
                dep.top_compact = float(np.max(_fiber_tops(dep.C, dep.T, dep.P0, dep.PD, fp.crimp > 0.0, fp.ell,
                                                           fp.R)))
            xy, z = _place_loose(place, rng, xy, low, dep.top_compact, fp.fuzz_depth, fp.L)
        else:
            z = place(xy, floor=0.0)
        if wave is not None:
            p0, pd, d, phase = wave
            dep.P0, dep.PD = np.concatenate([dep.P0, p0[None]]), np.concatenate([dep.PD, pd[None]])
            dep.planes.append(d)
            dep.phases.append(phase)
        dep.C, dep.T = np.vstack([dep.C, [xy[0], xy[1], z]]), np.vstack([dep.T, t])
        area += amount
    return dep


def _fiber_images(fp: _FeltParameters, dep: _Deposit, sides: int) -> tuple[list, ...]:
    """Each fiber's tube at each periodic image that reaches into the cell.

    Returns the lists of the images' vertices, normals, tangents, ``s``, ``phi`` and lengths.
    """
    R, L, ell, n_s = fp.R, fp.L, fp.ell, fp.n_s
    verts, norms, tans, ss, phis, yarn_len = [], [], [], [], [], []
    for k, (c, t) in enumerate(zip(dep.C, dep.T, strict=True)):
        if fp.crimp > 0.0:                     # the polyline's box (its arc midpoint at c)
            xy_all = np.concatenate([dep.P0[k, :, :2], dep.P0[k, -1:, :2] + dep.PD[k, -1:, :2]])
            box_lo, box_hi = xy_all.min(axis=0) - R, xy_all.max(axis=0) + R
        else:
            half = 0.5 * ell * np.abs(t[:2]) + R
            box_lo, box_hi = -half, half
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                cc = c + np.array([i * L, j * L, 0.0])
                if np.any(cc[:2] + box_hi < 0.0) or np.any(cc[:2] + box_lo > L):
                    continue                   # this image does not reach into the cell
                if fp.crimp > 0.0:
                    p, nrm, tan, s, phi, _ = _crimped_tube(cc, t, dep.planes[k], R, ell, fp.amplitude, fp.wavelength,
                                                           dep.phases[k], n_s, sides)
                else:
                    p, nrm, s, phi = _tube(cc, t, R, ell, n_s, sides)
                    tan = np.broadcast_to(t, p.shape)
                verts.append(p)
                norms.append(nrm)
                tans.append(tan)
                ss.append(s)
                phis.append(phi)
                yarn_len.append(ell)
    return verts, norms, tans, ss, phis, yarn_len


def _felt_info(fp: _FeltParameters, dep: _Deposit, top: float, n_bulk: int, n_images: int, triangles: int,
               seed: int) -> dict:
    """The felt's ``info``: counts, sizes, the bulk volume fraction and the crimp's and loose top's settings."""
    C, T, P0, PD = dep.C, dep.T, dep.P0, dep.PD
    info: dict = {"fibers": len(C), "images": n_images, "cell_um": fp.L, "fiber_length_um": fp.ell,
                  "thickness_um": top, "layers": fp.layers, "spread_deg": math.degrees(fp.spread),
                  "normal_fibers": dep.n_normal, "triangles": triangles,
                  "volume_fraction": (bulk_volume_fraction_pieces(C[:n_bulk], C[:n_bulk, None, :] + P0[:n_bulk],
                                                                  PD[:n_bulk], fp.R, fp.L) if fp.crimp > 0.0
                                      else bulk_volume_fraction(C[:n_bulk], T[:n_bulk], fp.R, fp.ell, fp.L)),
                  "seed": int(seed)}
    if fp.crimp > 0.0:
        info.update({"crimp_percent": fp.crimp, "crimp_wavelength_um": fp.wavelength,
                     "crimp_amplitude_um": fp.amplitude, "crimp_plane": "random" if fp.random_plane else "felt",
                     "pieces": fp.n_s})
    if fp.fuzz > 0.0:
        info.update({"fuzz_fraction": fp.fuzz, "fuzz_depth_um": fp.fuzz_depth, "fuzz_fibers": len(C) - n_bulk,
                     "compact_top_um": dep.top_compact - top})   # the compact felt's top, below the felt's
    return info


def felt_mesh(spec: object, radius_um: float, seed: int = 0, *, sides: int = 48, n_s: int = 4) -> FabricMesh:
    """The felt of ``spec`` for fibers of radius ``radius_um``.

    Parameters
    ----------
    spec : simulate.fabric.structure.StructureSpec
        A ``kind = "nonwoven"`` structure (its fields: :func:`felt_inputs`).
    radius_um : float
        The fibers' radius.
    seed : int
        The stream the random fibers are drawn from (module docstring).
    sides, n_s : int
        The tubes' sides and pieces (a crimped fiber's pieces: at least ``n_s``, :func:`_crimp_pieces`).

    Returns
    -------
    FabricMesh
        Open tubes, one "yarn" per fiber image; ``info`` holds the counts, the thickness and the bulk
        volume fraction.
    """
    fp = _felt_parameters(spec, radius_um, n_s)
    rng = np.random.default_rng([int(seed), 0x7E17])
    dep = _deposit(fp, rng)
    top = float(np.max(_fiber_tops(dep.C, dep.T, dep.P0, dep.PD, fp.crimp > 0.0, fp.ell, fp.R)))
    dep.C[:, 2] -= top                         # the felt's top at z = 0
    n_bulk = dep.n_compact if dep.n_compact >= 0 else len(dep.C)     # the compact felt's fibers (the bulk's)
    if dep.n_compact < 0:                      # no loose fiber drawn (a fraction below the last fiber's amount)
        dep.top_compact = top
    verts, norms, tans, ss, phis, yarn_len = _fiber_images(fp, dep, sides)
    n_s, R, L = fp.n_s, fp.R, fp.L
    n_y = len(verts)
    ring = (n_s + 1) * (sides + 1)
    vertex_base = (np.arange(n_y) * ring).astype(np.int64)
    face_base = (np.arange(n_y) * 2 * n_s * sides).astype(np.int64)
    faces = np.concatenate([grid_faces(n_s, sides, int(vertex_base[y])) for y in range(n_y)]).astype(np.int32)
    vertices = np.concatenate(verts)
    info = _felt_info(fp, dep, top, n_bulk, n_y, int(faces.shape[0]), seed)
    return FabricMesh(
        vertices=vertices, faces=faces, normals=np.concatenate(norms), tangents=np.ascontiguousarray(np.concatenate(tans)),
        vertex_s=np.concatenate(ss), vertex_phi=np.concatenate(phis),
        vertex_yarn=np.repeat(np.arange(n_y, dtype=np.int32), ring),
        face_yarn=np.repeat(np.arange(n_y, dtype=np.int32), 2 * n_s * sides),
        vertex_base=vertex_base, face_base=face_base, n_s=np.full(n_y, n_s, dtype=np.int32),
        yarn_length=np.array(yarn_len, float), sides=int(sides), Lx=L, Ly=L,
        z_min=float(vertices[:, 2].min()), z_max=float(vertices[:, 2].max()), yarn_radius_um=R,
        open_fibers=True, info=info)


#: the modules whose source a cached felt depends on (:func:`cached_felt_mesh`)
CACHE_MODULES = ("simulate.geometry.felt", "simulate.geometry.mesh")
_ARRAYS = ("vertices", "faces", "normals", "tangents", "vertex_s", "vertex_phi", "vertex_yarn", "face_yarn",
           "vertex_base", "face_base", "n_s", "yarn_length")
_SCALARS = ("sides", "Lx", "Ly", "z_min", "z_max", "yarn_radius_um", "open_fibers", "info")


def felt_key(spec: object, radius_um: float, seed: int = 0, *, sides: int = 48, n_s: int = 4) -> str:
    """The table cache's key of a felt (:mod:`simulate.fiber.tablecache`).

    It covers every input of :func:`felt_mesh` (:func:`felt_inputs`, the radius, the seed, the mesh's
    sizes) and the source of :data:`CACHE_MODULES`.
    """
    from simulate.fiber import tablecache

    inputs = {"spec": felt_inputs(spec), "radius_um": float(radius_um), "seed": int(seed), "sides": int(sides),
              "n_s": int(n_s)}
    return tablecache.content_key("felt", inputs, CACHE_MODULES)


def cached_felt_mesh(spec: object, radius_um: float, seed: int = 0, *, sides: int = 48,
                     n_s: int = 4) -> tuple[FabricMesh, bool]:
    """``(felt, hit)``: :func:`felt_mesh` from the table cache (``FABRIC_OPTICS_CACHE_DIR``).

    Built and stored on a miss. The key (:func:`felt_key`) covers every input and the code, so a hit is
    the felt a build would
    give, array for array; the runs of a fit that keeps the structure build each realisation once.
    """
    from simulate.fiber import tablecache

    def build() -> dict:
        m = felt_mesh(spec, radius_um, seed, sides=sides, n_s=n_s)
        out: dict = {name: getattr(m, name) for name in _ARRAYS}
        out["scalars"] = np.array(json.dumps({name: getattr(m, name) for name in _SCALARS}))
        return out

    arrays, hit = tablecache.cached(felt_key(spec, radius_um, seed, sides=sides, n_s=n_s), build)
    fields: dict = {name: arrays[name] for name in _ARRAYS}
    fields.update(json.loads(str(arrays["scalars"])))
    return FabricMesh(**fields), hit


def fiber_pieces(m: FabricMesh) -> tuple[np.ndarray, np.ndarray]:
    """Each fiber image's axis as straight pieces, read off its mesh (the centres of its rings).

    Returns the starts ``[images, n_s, 3]`` and the pieces' vectors.
    """
    ns, sides = int(m.n_s[0]), int(m.sides)
    centres = m.vertices.reshape(len(m.vertex_base), ns + 1, sides + 1, 3)[:, :, :-1].mean(axis=2)
    return centres[:, :-1], np.diff(centres, axis=1)


def bulk_volume_fraction(C: np.ndarray, T: np.ndarray, R: float, ell: float, L: float, n: int = 4000) -> float:
    """The fraction of the felt's bulk inside a fiber.

    The bulk is the cell between the quartiles of the fibers' centre heights, sampled by ``n`` fixed-seed
    random points (standard error ``sqrt(f (1 - f) / n)``).
    """
    rng = np.random.default_rng(0xF17)
    z_lo, z_hi = np.quantile(C[:, 2], [0.25, 0.75])
    p = np.stack([rng.uniform(0.0, L, n), rng.uniform(0.0, L, n), rng.uniform(z_lo, z_hi, n)], axis=-1)
    inside = np.zeros(n, bool)
    for c, t in zip(C, T, strict=True):
        d = p - c
        d[:, :2] -= L * np.round(d[:, :2] / L)  # nearest image (a fiber's half-projection is <= L / 2)
        a = d @ t
        inside |= (np.abs(a) <= 0.5 * ell) & (np.einsum("ij,ij->i", d, d) - a * a < R * R)
    return float(inside.mean())


def bulk_volume_fraction_pieces(C: np.ndarray, S: np.ndarray, D: np.ndarray, R: float, L: float, n: int = 4000) -> float:
    """:func:`bulk_volume_fraction` for fibers of straight pieces (a crimped fiber's polyline).

    Fiber ``j``'s pieces start at ``S[j]`` (``[pieces, 3]``, absolute) with vectors ``D[j]``; a point is
    inside a fiber when
    it is inside one of its pieces' cylinders (the nearest image of each piece).
    """
    rng = np.random.default_rng(0xF17)
    z_lo, z_hi = np.quantile(C[:, 2], [0.25, 0.75])
    p = np.stack([rng.uniform(0.0, L, n), rng.uniform(0.0, L, n), rng.uniform(z_lo, z_hi, n)], axis=-1)
    inside = np.zeros(n, bool)
    for s, dv in zip(S, D, strict=True):
        length = np.linalg.norm(dv, axis=1)
        e = dv / length[:, None]
        d = p[None, :, :] - (s + 0.5 * dv)[:, None, :]    # from each piece's midpoint
        d[..., :2] -= L * np.round(d[..., :2] / L)        # nearest image (a piece is far shorter than L / 2)
        a = np.einsum("pij,pj->pi", d, e)
        hit = (np.abs(a) <= 0.5 * length[:, None]) & (np.einsum("pij,pij->pi", d, d) - a * a < R * R)
        inside |= hit.any(axis=0)
    return float(inside.mean())
