r"""The structured fabric BRDF tabulated over fabric-frame directions, for bulk evaluation.

:func:`simulate.fabric.structure.fabric_beta_from_G` costs one layer-table lookup per facet and geometry
(a woven surface has ~10^3 facets): right for a plan of tens of geometries, slow for millions (fits,
sweeps, renderers). :func:`fabric_table` evaluates the facet sum ONCE on a grid of fabric-frame
pairs -- ``theta_i, theta_o`` every 7.5 deg on [0, 90], ``phi_i`` every 15 deg on [0, 180] (a weave,
twisted or not, is unchanged by a turn of 180 deg about its normal: ``(x, y) -> (-x, -y)``),
``phi_o`` every 15 deg on [0, 360] -- in compiled code (parallel over pairs); it stores
``S = sum_k a_k / (m_k . z) G_k`` (finite everywhere, unlike ``f``, which grows as
``1 / cos theta`` towards the horizon), and :meth:`FabricTable.beta` interpolates it multilinearly
and returns ``beta = pi S / (cos theta_i cos theta_o)``. The interpolation error against the direct
facet sum is measured in the tests (it is that of the 7.5 / 15 deg grid).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba
import numpy as np

from simulate.fabric.fiberlayer import HALF_TURN, LayerTable, lookup_many, lookup_one
from simulate.optics import microfacet

__all__ = ["FabricTable", "fabric_table"]


@numba.njit(cache=True, parallel=True)
def _facet_sum(G, ti, pi_, to, po, M, weight, w_i, w_o, out):
    """``out[p] = sum_k weight_k G(M_k w_i[p], M_k w_o[p])`` (layer mirrors inside the lookup)."""
    for p in numba.prange(w_i.shape[0]):
        for k in range(M.shape[0]):
            li0 = M[k, 0, 0] * w_i[p, 0] + M[k, 0, 1] * w_i[p, 1] + M[k, 0, 2] * w_i[p, 2]
            li1 = M[k, 1, 0] * w_i[p, 0] + M[k, 1, 1] * w_i[p, 1] + M[k, 1, 2] * w_i[p, 2]
            li2 = M[k, 2, 0] * w_i[p, 0] + M[k, 2, 1] * w_i[p, 1] + M[k, 2, 2] * w_i[p, 2]
            lo0 = M[k, 0, 0] * w_o[p, 0] + M[k, 0, 1] * w_o[p, 1] + M[k, 0, 2] * w_o[p, 2]
            lo1 = M[k, 1, 0] * w_o[p, 0] + M[k, 1, 1] * w_o[p, 1] + M[k, 1, 2] * w_o[p, 2]
            lo2 = M[k, 2, 0] * w_o[p, 0] + M[k, 2, 1] * w_o[p, 1] + M[k, 2, 2] * w_o[p, 2]
            lookup_one(G, ti, pi_, to, po, li0, li1, li2, lo0, lo1, lo2, weight[k], 0, out[p])


def facet_sum(lt: LayerTable, facets, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """``S [N, L] = sum_k a_k / (m_k . z) G(M_k w_i, M_k w_o)`` in compiled code (no ``[N, K, L]`` temporaries)."""
    w_i = np.ascontiguousarray(np.atleast_2d(w_i), dtype=float)
    w_o = np.ascontiguousarray(np.atleast_2d(w_o), dtype=float)
    out = np.zeros((w_i.shape[0], lt.G.shape[-1]))
    _facet_sum(lt.G, lt.theta_i, lt.phi_i, lt.theta_o, lt.phi_o, np.ascontiguousarray(facets.M),
               np.ascontiguousarray(facets.a / facets.m_z), w_i, w_o, out)
    return out


@dataclass
class FabricTable:
    """``S`` on the grid ``theta_i x phi_i (0..180) x theta_o x phi_o (0..360)`` (degrees), ``[..., L]``."""

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    S: np.ndarray
    seconds: float = 0.0

    def beta(self, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
        """``beta [N, L]`` at fabric-frame pairs ``[N, 3]`` (0 where either direction is below the fabric)."""
        w_i = np.ascontiguousarray(np.atleast_2d(w_i), dtype=float)
        w_o = np.ascontiguousarray(np.atleast_2d(w_o), dtype=float)
        out = np.zeros((w_i.shape[0], self.S.shape[-1]))
        lookup_many(self.S, self.theta_i, self.phi_i, self.theta_o, self.phi_o, w_i, w_o, HALF_TURN, out)
        cos = w_i[:, 2] * w_o[:, 2]
        return np.where(cos[:, None] > 0, math.pi * out / np.where(cos > 0, cos, 1.0)[:, None], 0.0)


def fabric_table(lt: LayerTable, facets, step_deg: float = 7.5, phi_step_deg: float = 15.0) -> FabricTable:
    """Tabulate the facet sum (module docstring)."""
    t0 = time.perf_counter()
    th = np.arange(0.0, 90.0 + 1e-9, step_deg)
    ph_i = np.arange(0.0, 180.0 + 1e-9, phi_step_deg)
    ph_o = np.arange(0.0, 360.0 + 1e-9, phi_step_deg)
    # the horizon nodes are evaluated just above it (a facet tilted towards a grazing beam is still lit)
    a, b, c, d = np.meshgrid(np.minimum(th, 89.9), ph_i, np.minimum(th, 89.9), ph_o, indexing="ij")
    w_i = microfacet.direction(np.radians(a.ravel()), np.radians(b.ravel()))
    w_o = microfacet.direction(np.radians(c.ravel()), np.radians(d.ravel()))
    w_i[:, 2] = np.clip(w_i[:, 2], 0.0, None)
    w_o[:, 2] = np.clip(w_o[:, 2], 0.0, None)
    S = facet_sum(lt, facets, w_i, w_o).reshape(a.shape + (-1,))
    return FabricTable(th, ph_i, th, ph_o, S, time.perf_counter() - t0)
