r"""Ray engine of the fibre-assembly Monte Carlo: Embree intersections in a periodic cell.

The woven micro-element (:mod:`simulate.geometry.weave`) tiles the fabric plane with period ``Lx`` along
x and ``Ly`` along y; its yarn tubes end exactly on the faces ``x = 0, Lx`` and ``y = 0, Ly``
(the weave generator guarantees continuity across them). A ray is traced in the central cell
only: Embree (through the ``embreex`` binding) finds the first triangle hit before the ray
leaves the cell's box; a ray that reaches a side face re-enters through the opposite face
(periodic wrap, docs/physics.md section 6), a ray that leaves through the top or bottom plane
has escaped (reflected / transmitted). Rays are traced in batches (a wavefront): one Embree
call per batch and wrap round, the bookkeeping in compiled code.

Why Embree and not a hand-written grid: it is a well-kept, SIMD BVH engine; ``simulate bench``
measures its rays per second on these meshes (docs/quality.md).

Precision: Embree works in float32; coordinates are in um and the micro-element is a few
hundred um wide, so positions are resolved to ~1e-4 um. Secondary rays start ``EPS_UM`` off
the surface along its normal.

References
----------
Wald, I. et al. (2014). Embree: a kernel framework for efficient CPU ray tracing. *ACM TOG*
33(4), 143. embreex: https://github.com/trimesh/embreex (Python binding, used by trimesh).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["PeriodicScene", "Hits", "ESCAPED_UP", "ESCAPED_DOWN", "LOST", "EPS_UM"]

#: offset of secondary-ray origins from the surface (um)
EPS_UM = 1e-3
#: ``Hits.prim`` codes of rays that hit nothing
ESCAPED_UP = -1
ESCAPED_DOWN = -2
LOST = -3          # still wrapping after ``max_wraps`` side-face crossings (a ray in a gap, parallel to it)

_MARGIN = 1.0      # the top / bottom planes lie this far (um) outside the geometry's z range


@dataclass
class Hits:
    """First hits of a batch of rays (``prim >= 0``) or how they ended (``ESCAPED_*``, ``LOST``).

    ``position`` is the hit point (or the point where the ray left the top/bottom plane),
    ``u, v`` Embree's barycentrics (``P = (1-u-v) v0 + u v1 + v v2``), ``origin`` the origin
    of the last (wrapped) segment -- the one that hit.
    """

    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    position: np.ndarray
    origin: np.ndarray


@numba.njit(cache=True)
def _segment_limits(origins, directions, lx, ly, z_lo, z_hi, t_out, face_out):
    """Distance to the first of the cell's side faces or top/bottom planes; which one (compiled)."""
    for i in range(origins.shape[0]):
        best = 1e30
        face = 0
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        if dz > 1e-12:
            best = (z_hi - oz) / dz
            face = 1
        elif dz < -1e-12:
            best = (z_lo - oz) / dz
            face = 2
        if dx > 1e-12:
            t = (lx - ox) / dx
            if t < best:
                best, face = t, 3
        elif dx < -1e-12:
            t = -ox / dx
            if t < best:
                best, face = t, 4
        if dy > 1e-12:
            t = (ly - oy) / dy
            if t < best:
                best, face = t, 5
        elif dy < -1e-12:
            t = -oy / dy
            if t < best:
                best, face = t, 6
        t_out[i] = max(best, 0.0)
        face_out[i] = face


@numba.njit(cache=True, nogil=True)
def _prepare(o, d, active, na, lx, ly, z_lo, z_hi, oa, da, ta, fa, o32, d32, dist32):
    """A wrap round's rays (``active[:na]``) gathered for Embree (compiled).

    Also their segments' limits (:func:`_segment_limits`) and Embree's float32 inputs (the distance at
    least 1e-6).
    """
    for j in range(na):
        i = active[j]
        for q in range(3):
            oa[j, q] = o[i, q]
            da[j, q] = d[i, q]
    _segment_limits(oa[:na], da[:na], lx, ly, z_lo, z_hi, ta, fa)
    for j in range(na):
        for q in range(3):
            o32[j, q] = np.float32(oa[j, q])
            d32[j, q] = np.float32(da[j, q])
        dist32[j] = np.float32(max(ta[j], 1e-6))


@numba.njit(cache=True, nogil=True)
def _settle(hit_prim, hit_u, hit_v, hit_t, occlusion, active, na, oa, da, ta, fa, lx, ly, prim, u, v, o,
            seg_origin):
    """Apply a wrap round's Embree answers (compiled).

    A hit's triangle, barycentrics and point, an escape's code and exit point, and the rays that reached a
    side face wrapped to the opposite one, kept in ``active`` (in order, in place). Returns how many go on.
    """
    ns = 0
    for j in range(na):
        i = active[j]
        if hit_prim[j] != -1:
            if occlusion:
                prim[i] = 0
            else:
                prim[i] = hit_prim[j]
                u[i] = hit_u[j]
                v[i] = hit_v[j]
                t = np.float64(hit_t[j])
                for q in range(3):
                    seg_origin[i, q] = oa[j, q]
                    o[i, q] = oa[j, q] + t * da[j, q]
            continue
        f = fa[j]
        for q in range(3):
            o[i, q] = oa[j, q] + ta[j] * da[j, q]
        if f == 1:
            prim[i] = ESCAPED_UP
        elif f == 2:
            prim[i] = ESCAPED_DOWN
        elif f >= 3:
            if f == 3:
                o[i, 0] = 0.0
            elif f == 4:
                o[i, 0] = lx
            elif f == 5:
                o[i, 1] = 0.0
            elif f == 6:
                o[i, 1] = ly
            active[ns] = i
            ns += 1
    return ns


class PeriodicScene:
    """Triangles of one micro-element in Embree, traced with periodic wrap at the side faces.

    Parameters
    ----------
    vertices : (V, 3) array
        Vertex positions (um), inside ``[0, Lx] x [0, Ly]`` in x and y.
    faces : (F, 3) int array
    lx, ly : float
        Periods (um).
    max_wraps : int
        Side-face crossings after which a ray counts as ``LOST`` (a ray running exactly along a
        gap between yarns would wrap for ever); the transport counts them.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, lx: float, ly: float, *, max_wraps: int = 256):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        v = np.ascontiguousarray(vertices, dtype=np.float64)
        self.lx = float(lx)
        self.ly = float(ly)
        self.z_lo = float(v[:, 2].min()) - _MARGIN
        self.z_hi = float(v[:, 2].max()) + _MARGIN
        self.max_wraps = int(max_wraps)
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self._scene, v.astype(np.float32), np.ascontiguousarray(faces, dtype=np.int32))

    # ------------------------------------------------------------------------------------
    def _loop(self, origins: np.ndarray, directions: np.ndarray, occlusion: bool, stats: dict | None):
        n = origins.shape[0]
        o = np.array(origins, dtype=np.float64, copy=True)
        d = np.ascontiguousarray(directions, dtype=np.float64)
        prim = np.full(n, LOST, dtype=np.int64)
        u = np.zeros(n)
        v = np.zeros(n)
        seg_origin = o.copy()
        active = np.arange(n)
        na = n
        oa, da = np.empty((n, 3)), np.empty((n, 3))
        o32, d32 = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
        t = np.empty(n)
        face = np.empty(n, dtype=np.int64)
        dist = np.empty(n, np.float32)
        nothing = np.empty(0, np.float32)
        for _ in range(self.max_wraps + 1):
            if na == 0:
                break
            _prepare(o, d, active, na, self.lx, self.ly, self.z_lo, self.z_hi, oa, da, t, face, o32, d32, dist)
            if stats is not None:
                stats["queries"] = stats.get("queries", 0) + na
            if occlusion:
                res = self._scene.run(o32[:na], d32[:na], dists=dist[:na], query="OCCLUDED")
                na = _settle(np.asarray(res), nothing, nothing, nothing, True, active, na, oa, da, t, face,
                             self.lx, self.ly, prim, u, v, o, seg_origin)
            else:
                res = self._scene.run(o32[:na], d32[:na], dists=dist[:na], output=1)
                na = _settle(res["primID"], res["u"], res["v"], res["tfar"], False, active, na, oa, da, t, face,
                             self.lx, self.ly, prim, u, v, o, seg_origin)
        return prim, u, v, o, seg_origin

    def intersect(self, origins: np.ndarray, directions: np.ndarray, stats: dict | None = None) -> Hits:
        """First hit of each ray (``Hits.prim`` >= 0: the triangle index).

        ``stats["queries"]`` (if given) is increased by the Embree queries issued (one per
        wrapped segment): the rays-per-second figure of the bench.
        """
        prim, u, v, pos, seg = self._loop(origins, directions, False, stats)
        return Hits(prim, u, v, pos, seg)

    def visible(self, origins: np.ndarray, directions: np.ndarray, stats: dict | None = None) -> np.ndarray:
        """True where a ray from ``origins`` along ``directions`` escapes upward unblocked.

        A shadow ray that leaves through the bottom plane, or wraps for ever, is not visible.
        """
        prim, _, _, _, _ = self._loop(origins, directions, True, stats)
        return prim == ESCAPED_UP

    @property
    def top(self) -> float:
        """Z of the plane rays start from and escape through upward."""
        return self.z_hi

    @property
    def bottom(self) -> float:
        """Z of the plane below the fabric: rays that reach it leave through the bottom."""
        return self.z_lo
