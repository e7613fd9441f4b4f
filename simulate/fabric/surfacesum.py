r"""The structured summation's surface term at fixed geometries, for any RMS slope, at the cost of its slope alone.

:func:`simulate.structwalk.walk.surface_beta` computes the layers' surface term (Cook-Torrance with masking) summed
over a structure's facets: the whole surface table on the layer grid (:func:`simulate.fabric.fiberlayer.surface_table`,
every incidence times every exit direction times ``n_psi`` points around the fiber), then the compiled facet sum
(:func:`simulate.fabric.structtable.facet_sum`). A fit that frees the RMS slope evaluates it at every point of its
slope lattice; of that work only the Beckmann distribution ``D`` depends on the slope. :class:`SurfaceSum` does the
rest once, for a fixed set of geometries, facets, host index and fiber spacing:

* **cells**: only the grid cells the facet sum's multilinear lookups reach at these geometries (a superset: each
  lookup's cell widened by one node where a coordinate lies within rounding of a node);
* **geometry**: at each of their azimuth points lit and seen, the half vector's ``tan^2``, ``4 ln cos``, the
  V-cavity ``G``, the Fresnel ``F`` and the cosines -- :func:`simulate.fabric.fiberlayer._surface_weights`'s
  quantities, by its own operations (:func:`surface_points`);

so that :meth:`SurfaceSum.beta` evaluates ``D`` and the products in the kernel's order at those points
(:func:`surface_weights_at`), sums each cell's row by numpy as :func:`~simulate.fabric.fiberlayer.surface_table`
does, places the cells in a table of zeros and runs the same facet sum. The result equals
:func:`simulate.structwalk.walk.surface_beta` bit for bit (tests/simulate/fabric/test_surfacesum.py, at several
slopes, felt and woven facets; tests/fabric_optics/fitting/test_surface_lattice.py for the fit's use of it).

What it costs (one core): on the green felt's measured plan (138 geometries, 36 facets) 6 000 of the table's
29 575 cells, 345 000 points (22 MB), formed in 0.3 s; then 4 ms per slope against ~80 ms for the table and its
facet sum (docs/data/summation-fit-cost.json). Red cotton's woven structure (944 facets) on the same plan:
20 000 cells, 1.1 million points (64 MB), 55 ms per slope. The points are at most the whole table's (about
1.8 million, 115 MB, for a plan that reaches every cell).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from simulate.fabric.fiberlayer import LayerTable, layer_grid, visibility, visibility_any
from simulate.fabric.structtable import facet_sum
from simulate.fiber.farfield import cell_frame
from simulate.optics import microfacet

__all__ = ["SurfaceSum", "facet_cells", "surface_points", "surface_weights_at"]

#: how close (in grid steps) a lookup's coordinate may come to a node before both cells around the node are kept
NODE_MARGIN = 1e-6


def _angles_deg(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polar and azimuthal angles (degrees, azimuth in [0, 360)) of directions ``[P, 3]`` (the lookup's own)."""
    r = np.sqrt(w[:, 0] * w[:, 0] + w[:, 1] * w[:, 1] + w[:, 2] * w[:, 2])
    t = np.degrees(np.arccos(np.clip(w[:, 2] / r, -1.0, 1.0)))
    p = np.degrees(np.arctan2(w[:, 1], w[:, 0]))
    return t, np.where(p < 0.0, p + 360.0, p)


def _node_range(nodes: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest lower node index of the cells a lookup at ``v`` may use.

    The lookup takes the cell ``floor((v - v0) / step)`` clipped to the grid; within :data:`NODE_MARGIN` of a
    node both cells are kept.
    """
    step = nodes[1] - nodes[0]
    x = (v - nodes[0]) / step
    top = nodes.size - 2
    lo = np.clip(np.floor(x - NODE_MARGIN), 0, top).astype(np.int64)
    hi = np.clip(np.floor(x + NODE_MARGIN), 0, top).astype(np.int64)
    return lo, hi


def facet_cells(grid: tuple, facets: Any, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """The cells of a layer table that the facet sum over ``facets`` at the given pairs may read.

    Both nodes of each coordinate's interval (one more where the coordinate lies within rounding of a node),
    for every (pair, facet) whose directions are both above the facet's layer, after the layer's mirrors
    (:func:`simulate.fabric.fiberlayer.lookup_one`).

    Parameters
    ----------
    grid : tuple of numpy.ndarray
        The layer table's four node arrays ``(th_i, ph_i, th_o, ph_o)`` (degrees).
    facets : Facets
        The visible fiber orientations.
    w_i, w_o : numpy.ndarray
        Fabric-frame incident and exit directions, ``[N, 3]``.

    Returns
    -------
    numpy.ndarray
        ``[C]`` flat indices into a table ``[Ti, Pi, To, Po]`` on ``grid``, ascending.
    """
    th_i, ph_i, th_o, ph_o = grid
    M = np.asarray(facets.M, float)
    li = np.einsum("kab,nb->nka", M, np.atleast_2d(w_i)).reshape(-1, 3)
    lo = np.einsum("kab,nb->nka", M, np.atleast_2d(w_o)).reshape(-1, 3)
    keep = (li[:, 2] > 0.0) & (lo[:, 2] > 0.0)
    li, lo = li[keep].copy(), lo[keep].copy()
    flip = li[:, 0] < 0.0
    li[flip, 0] *= -1.0
    lo[flip, 0] *= -1.0
    flip = li[:, 1] < 0.0
    li[flip, 1] *= -1.0
    lo[flip, 1] *= -1.0
    t_i, p_i = _angles_deg(li)
    t_o, p_o = _angles_deg(lo)
    ranges = [_node_range(n, v) for n, v in ((th_i, t_i), (ph_i, p_i), (th_o, t_o), (ph_o, p_o))]
    shape = (th_i.size, ph_i.size, th_o.size, ph_o.size)
    mask = np.zeros(shape, bool)
    for da in range(3):
        for db in range(3):
            for dc in range(3):
                for dd in range(3):
                    idx = []
                    ok = np.ones(t_i.size, bool)
                    for (lo_k, hi_k), off in zip(ranges, (da, db, dc, dd), strict=True):
                        # the nodes lo .. hi + 1: the lower node of each possible cell and the node above it
                        ok &= lo_k + off <= hi_k + 1
                        idx.append(np.minimum(lo_k + off, hi_k + 1))
                    mask[tuple(i[ok] for i in idx)] = True
    return np.flatnonzero(mask)


@numba.njit(cache=True)
def surface_points(li, lo, lit, seen, inc, out, n_host):
    """The slope-free quantities of :func:`simulate.fabric.fiberlayer._surface_weights` at the cells' points.

    Only the azimuth points that are lit and seen and where both cosines are positive are kept (elsewhere
    the kernel's term is 0), so that :func:`surface_weights_at` costs the Beckmann term alone per slope.
    Each quantity is computed by the kernel's operations in its order.

    Parameters
    ----------
    li : numpy.ndarray
        Cell-frame incidences ``[I, n, 3]``.
    lo : numpy.ndarray
        Cell-frame exits ``[O, n, 3]``.
    lit : numpy.ndarray
        The incidences' visibilities ``[I, n]``.
    seen : numpy.ndarray
        The exits' visibilities ``[O, n]``.
    inc : numpy.ndarray
        Each cell's incidence, an index into ``li`` and ``lit`` (``[C]``, int64).
    out : numpy.ndarray
        Each cell's exit, an index into ``lo`` and ``seen`` (``[C]``, int64).
    n_host : float
        The fiber's refractive index (Fresnel from outside, index 1).

    Returns
    -------
    flat : numpy.ndarray
        ``[P]`` the points' indices ``c n + k`` into a ``[C, n]`` array.
    q : numpy.ndarray
        ``[P, 7]``: the half vector's ``tan^2`` and ``4 ln cos`` (Beckmann), the V-cavity ``G``, the
        unpolarised Fresnel ``F``, ``4 (cos_i cos_o)``, ``cos_i`` and ``cos_o``.
    """
    n_cells = inc.size
    n = lit.shape[1]
    count = 0
    for c in range(n_cells):
        for k in range(n):
            if lit[inc[c], k] != 0.0 and seen[out[c], k] != 0.0 and li[inc[c], k, 2] > 0.0 and lo[out[c], k, 2] > 0.0:
                count += 1
    flat = np.empty(count, np.int64)
    q = np.empty((count, 7))
    same = n_host == 1.0
    eta = 1.0 / n_host
    j = 0
    for c in range(n_cells):
        a, o = inc[c], out[c]
        for k in range(n):
            ix, iy, ci = li[a, k, 0], li[a, k, 1], li[a, k, 2]
            ox, oy, co = lo[o, k, 0], lo[o, k, 1], lo[o, k, 2]
            if not (lit[a, k] != 0.0 and seen[o, k] != 0.0 and ci > 0.0 and co > 0.0):
                continue
            sx, sy, sz = ix + ox, iy + oy, ci + co
            norm = math.sqrt((sx * sx + sy * sy) + sz * sz)
            if norm > 0.0:
                hx, hy, hz = sx / norm, sy / norm, sz / norm
            else:
                hx, hy, hz = 0.0, 0.0, 1.0
            oh = (ox * hx + oy * hy) + co * hz
            if hz > 0.0:
                cs = min(hz, 1.0)
                tan2 = (1.0 - cs * cs) / (cs * cs)
                l4 = 4.0 * math.log(cs)
            else:                      # D = 0: never with both cosines positive; kept as the kernel has it
                tan2 = math.inf
                l4 = 0.0
            if hz > 0.0 and oh > 0.0:
                g = min(1.0, min(2.0 * hz * co / oh, 2.0 * hz * ci / oh))
            else:
                g = 0.0
            cf = min(max(abs(min(max(oh, 0.0), 1.0)), 0.0), 1.0)
            s = math.sqrt(max(1.0 - cf * cf, 0.0))
            es = eta * s
            sin2_t = es * es
            if same:
                f = 0.0
            elif sin2_t >= 1.0:
                f = 1.0
            else:
                cos_t = math.sqrt(max(1.0 - sin2_t, 0.0))
                rs = (1.0 * cf - n_host * cos_t) / (1.0 * cf + n_host * cos_t)
                rp = (n_host * cf - 1.0 * cos_t) / (n_host * cf + 1.0 * cos_t)
                f = 0.5 * (rs * rs + rp * rp)
            flat[j] = c * n + k
            q[j, 0] = tan2
            q[j, 1] = l4
            q[j, 2] = g
            q[j, 3] = f
            q[j, 4] = 4.0 * (ci * co)
            q[j, 5] = ci
            q[j, 6] = co
            j += 1
    return flat, q


@numba.njit(cache=True)
def surface_weights_at(flat, q, m, log_pi_m2, w):
    """Write ``f_CT cos_i cos_o`` at the points of :func:`surface_points` for one RMS slope, in place.

    :func:`simulate.fabric.fiberlayer._surface_weights`'s term, in its order (its factors ``vis_i vis_o``,
    1 at these points, leave a product unchanged).

    Parameters
    ----------
    flat : numpy.ndarray
        The points' flat indices into ``w`` (:func:`surface_points`).
    q : numpy.ndarray
        The points' slope-free quantities ``[P, 7]`` (:func:`surface_points`).
    m : float
        The RMS slope.
    log_pi_m2 : float
        ``ln(pi m^2)``.
    w : numpy.ndarray
        ``[C, n]`` weights, written at ``flat`` (elsewhere left as they are).
    """
    mm = m * m
    wf = w.reshape(-1)
    for j in range(flat.size):
        tan2 = q[j, 0]
        if tan2 == math.inf:
            d = 0.0
        else:
            d = math.exp((-tan2 / mm - log_pi_m2) - q[j, 1])
        f_ct = d * q[j, 2] * q[j, 3] / q[j, 4]
        wf[flat[j]] = f_ct * q[j, 5] * q[j, 6]


class SurfaceSum:
    """The structured summation's surface ``beta [N]`` at fixed fabric-frame pairs, for any RMS slope.

    Equal to :func:`simulate.structwalk.walk.surface_beta` of a config with that slope, ``n_host`` and a
    structure of these ``facets`` and ``spacing_ratio`` at the pairs ``w_i, w_o [N, 3]`` (module docstring).

    Built once per (facets, geometries, ``n_host``, spacing ratio); :meth:`beta` then costs the Beckmann term at
    the azimuth points the facet sum reaches, a row sum and the facet sum. ``step_deg``, ``phi_step_deg`` and
    ``n_psi`` are the layer grid's and the table's azimuth points
    (:func:`simulate.fabric.structure.surface_layer_table`'s: 7.5, 15 and 180).
    """

    def __init__(self, facets: Any, w_i: np.ndarray, w_o: np.ndarray, n_host: float, spacing_ratio: float,
                 step_deg: float = 7.5, phi_step_deg: float = 15.0, n_psi: int = 180) -> None:
        self.facets = facets
        self.w_i = np.ascontiguousarray(np.atleast_2d(np.asarray(w_i, float)))
        self.w_o = np.ascontiguousarray(np.atleast_2d(np.asarray(w_o, float)))
        self.n_host = float(n_host)
        self.spacing_ratio = float(spacing_ratio)
        th, ph_i, ph_o, w_out = layer_grid(step_deg, phi_step_deg)
        self.grid = (th, ph_i, th, ph_o)
        self.shape = (th.size, ph_i.size, th.size, ph_o.size)
        cells = facet_cells(self.grid, facets, self.w_i, self.w_o)
        a, b, c, d = np.unravel_index(cells, self.shape)
        # as surface_table: an incidence at the horizon has no irradiance, the pole's row is its phi_i = 0 row,
        # an exit at the horizon is 0
        w_in_all = microfacet.direction(np.radians(th)[a], np.radians(ph_i)[np.where(th[a] == 0.0, 0, b)])
        o = c * ph_o.size + d
        up = w_out[:, 2] > 0
        keep = (w_in_all[:, 2] >= 1e-12) & up[o]
        self.cells = cells[keep]
        a, b, o = a[keep], np.where(th[a[keep]] == 0.0, 0, b[keep]), o[keep]
        spacing = 2.0 * self.spacing_ratio
        dpsi = 2.0 * math.pi / n_psi
        psi = (np.arange(n_psi) + 0.5) * dpsi - math.pi
        self._dpsi = dpsi
        # the exit directions' frames and visibility over ALL exits above the layer, then the rows used (the
        # arrays surface_table forms, value for value)
        up_index = np.cumsum(up) - 1
        lo_all = cell_frame(w_out[up][:, None, :], psi[None, :])
        seen_all = visibility_any(w_out[up], psi, spacing)
        exits, out = np.unique(up_index[o], return_inverse=True)
        lo = np.ascontiguousarray(lo_all[exits])
        seen = np.ascontiguousarray(seen_all[exits])
        incidences, inc = np.unique(a * ph_i.size + b, return_inverse=True)
        li = np.empty((incidences.size, n_psi, 3))
        lit = np.empty((incidences.size, n_psi))
        for r, flat_in in enumerate(incidences):
            ai, bi = divmod(int(flat_in), ph_i.size)
            w_in = microfacet.direction(math.radians(th[ai]), math.radians(ph_i[bi]))
            li[r] = cell_frame(w_in[None, :], psi)
            lit[r] = visibility(w_in[None], psi, spacing)[0]
        self._flat, self._q = surface_points(li, lo, lit, seen, inc.astype(np.int64).ravel(),
                                             out.astype(np.int64).ravel(), self.n_host)
        self._n_psi = n_psi

    @property
    def points(self) -> int:
        """The azimuth points evaluated per slope."""
        return int(self._flat.size)

    def table(self, rms_slope: float) -> LayerTable:
        """The surface layer table at one RMS slope, at the cells the facet sum reaches.

        Parameters
        ----------
        rms_slope : float
            The fiber surface's RMS slope, a finite number > 0.

        Returns
        -------
        LayerTable
            :func:`simulate.fabric.fiberlayer.surface_table`'s values at the cells the facet sum reaches,
            0 elsewhere.

        Raises
        ------
        ValueError
            If ``rms_slope`` is not a finite number > 0.
        """
        m = float(rms_slope)
        if not (math.isfinite(m) and m > 0.0):
            raise ValueError(f"SurfaceSum: the RMS slope must be a finite number > 0, not {rms_slope!r}")
        w = np.zeros((self.cells.size, self._n_psi))
        surface_weights_at(self._flat, self._q, m, float(np.log(np.pi * np.asarray(m) * np.asarray(m))), w)
        G = np.zeros(self.shape)
        # surface_table's row: radius (1) x dpsi x the azimuth sum, over d / R = 2 x the spacing ratio
        G.flat[self.cells] = 1.0 * self._dpsi * w.sum(axis=1) / (2.0 * self.spacing_ratio)
        return LayerTable(*self.grid, np.ascontiguousarray(G[..., None]), True, self.spacing_ratio)

    def beta(self, rms_slope: float) -> np.ndarray:
        """``beta [N]`` of the surface term at ``rms_slope`` (:func:`simulate.structwalk.walk.surface_beta`'s)."""
        S = facet_sum(self.table(rms_slope), self.facets, self.w_i, self.w_o)
        return (math.pi * S / (self.w_i[:, 2] * self.w_o[:, 2])[:, None])[:, 0]
