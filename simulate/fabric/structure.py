r"""Fibers in all their orientations: the fabric's visible fiber layers and the summation over them.

docs/physics.md section 6.2. The fabric's surface is a set of facets ``k``: a layer of parallel
fibers (:mod:`simulate.fabric.fiberlayer`) with layer normal ``m_k`` and fiber direction ``t_k`` (``t_k``
perpendicular to ``m_k``), covering the fraction ``a_k`` of the fabric's projected area
(``sum a_k = 1``); its true area is ``a_k / (m_k . z)``. The fabric BRDF is the area average of the
facets' BRDFs, each lit and seen through its own normal (the microfacet form with the fiber layer as
the facet BRDF)::

    f_fabric(w_i, w_o) = 1 / (cos theta_i cos theta_o) sum_k a_k / (m_k . z) G(M_k w_i, M_k w_o)

with ``G = f_layer (w_i . m)(w_o . m)`` the layer quantity of :mod:`simulate.fabric.fiberlayer` (0 for a facet
turned away from either direction) and ``M_k`` the change to the facet's frame (rows ``t_k``,
``m_k x t_k``, ``m_k``). Facets do not mask each other at the yarn scale (limit: towards grazing
incidence the yarns' crowns shadow the valleys; the fiber-scale masking is in ``G``).

Woven (``kind = "woven"``). The top surface of the weave's micro-element (:mod:`simulate.weave`: yarn
centre lines are the periodic cubic splines of the crimp, sections ellipses of semi-axes ``w/2,
h/2``), sampled on an ``n x n`` grid over the micro-element: at each point the higher of the warp
and weft surfaces ``z = z_c(s) + (h/2) sqrt(1 - u^2)`` (``u`` the offset across the yarn over
``w/2``) gives the system, the normal ``m`` (from the surface's gradient: the crimp's inclination
``z_c'`` along the yarn and the section's curvature across it) and the yarn tangent
``T = (1, 0, z_c') / |.|`` (warp) or ``(0, 1, z_c') / |.|`` (weft), which is perpendicular to ``m``.
Points over no yarn (the corner holes of an open weave) are left out and the rest renormalised.
The fraction of the points each system wins is its visible fraction. Without a weave (a ``woven``
structure given no ``[weave]`` geometry) the yarns are flat (``m = z``; warp and weft 1/2 each).

Twist. The surface fibers of a yarn twisted with surface twist angle ``alpha`` lie on a helix about
its centre line: ``t = cos(alpha) T + s sin(alpha) (T x m)``, ``s = +1`` for Z twist (a right-handed
helix: on the yarn's face the fibers run like the middle stroke of a Z) and ``-1`` for S
(Hearle, Grosberg & Backer 1969, ch. 4: ``tan(alpha) = pi d T`` for yarn diameter ``d`` and twist
``T`` turns per length). Defaults: 24 deg, Z, both systems: a ring-spun cotton weaving yarn of
30 tex (``d`` ~ 0.2 mm) at ~700 turns/m (twist multiple ~ 4 in English count) has
``tan(alpha) = pi x 0.2 mm x 0.7 /mm = 0.44``; the literature's range for cotton singles is
roughly 15-30 deg (Morton & Hearle 2008, ch. 17; Lord 2003, ch. 3).

Nonwoven (``kind = "nonwoven"``). Felt fibers: in-plane direction uniform in ``[0, 180)`` deg and an
out-of-plane inclination ``epsilon`` normally distributed with standard deviation ``spread`` (deg),
each fiber the top of its own layer, ``m = (z - (z.t) t) / |.|``, equal projected-area weights
(Gauss-Hermite nodes in ``epsilon``, truncated to +-80 deg and renormalised).

References
----------
Hearle, J. W. S., Grosberg, P. & Backer, S. (1969). *Structural Mechanics of Fibers, Yarns, and
Fabrics*, vol. 1. Wiley. Morton, W. E. & Hearle, J. W. S. (2008). *Physical Properties of Textile
Fibres*, 4th ed. Woodhead. Lord, P. R. (2003). *Handbook of Yarn Production*. Woodhead.
Ashikhmin et al. (2000), see :mod:`simulate.fabric.fiberlayer`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["CLOSE_PACKING", "Facets", "merged", "StructureSpec", "structure_from_table", "woven_facets", "flat_facets",
           "felt_facets", "facets_for", "fabric_beta_from_G", "structured_beta", "interior_layers", "layer_table_of",
           "surface_layer_table", "mean_of_halves", "REMOVED_KEYS"]


log = logging.getLogger(__name__)

#: close packing of parallel cylinders (hexagonal): pi / (2 sqrt 3)
CLOSE_PACKING = math.pi / (2.0 * math.sqrt(3.0))


@dataclass(frozen=True)
class StructureSpec:
    """The ``[structure]`` section of a simulation config (fields: :func:`structure_from_table`)."""

    kind: str = "woven"
    layers: int = 0
    packing_fraction: float = CLOSE_PACKING
    warp_twist_deg: float = 24.0
    warp_twist: str = "Z"
    weft_twist_deg: float = 24.0
    weft_twist: str = "Z"
    felt_spread_deg: float = 20.0
    felt_normal_fraction: float = 0.0
    felt_normal_spread_deg: float = 15.0
    felt_crimp_percent: float = 0.0
    felt_crimp_per_cm: float = 4.4
    felt_crimp_plane: str = "felt"
    felt_fuzz_fraction: float = 0.0
    felt_fuzz_depth_um: float = 300.0
    samples: int = 48

    @property
    def spacing_ratio(self) -> float:
        """Fiber spacing over diameter in a layer, ``d / 2R = sqrt(close packing / packing fraction)``."""
        return math.sqrt(CLOSE_PACKING / self.packing_fraction)


#: ``[structure]`` keys that no longer exist, with what to do instead (a config that gives one is refused
#: with this line: the model they switched off is always on)
REMOVED_KEYS = {
    "cells": "the summation always uses the fiber layer's visible cells - delete the line",
    "masking": "neighbouring fibers always shadow and mask each other - delete the line",
    "yarn_surface": "a woven structure always follows the weave's yarn surface - delete the line",
    "interior": "the light returned from the fiber layers below is always included - delete the line",
    "interior_return": "the light returned from below is always the diffuse closure's - delete the line",
}


#: ``[structure]`` keys of a felt's Monte Carlo only (refused in a woven structure)
FELT_ONLY_KEYS = ("felt_normal_fraction", "felt_normal_spread_deg", "felt_crimp_percent", "felt_crimp_per_cm",
                  "felt_crimp_plane", "felt_fuzz_fraction", "felt_fuzz_depth_um")


def structure_from_table(t: Any) -> StructureSpec:
    """Validate a config's ``[structure]`` table (``t``: :mod:`simulate.config`'s checked table).

    Schema (defaults shown; every bad value is one error naming the field)::

        [structure]
        kind = "woven"              # "woven" | "nonwoven" (a felt)
        layers = 0                  # fiber layers in the fabric's thickness, >= 1; 0: 2 h / 2R (woven), 10 (felt)
        packing_fraction = 0.9069   # fibers' area fraction in the layer, (0, 0.9069]; 0.9069 = touching
        warp_twist_deg = 24         # surface twist angle of the warp yarns, [0, 60]
        warp_twist = "Z"            # "Z" | "S"
        weft_twist_deg = 24
        weft_twist = "Z"
        felt_spread_deg = 20        # nonwoven: standard deviation of the fibers' inclination, [0, 60]
        felt_normal_fraction = 0    # nonwoven, Monte Carlo: the fraction of the fiber amount driven towards
                                    # the normal (needle punching), [0, 0.9]; 0: every fiber in-plane as above
        felt_normal_spread_deg = 15 # nonwoven, Monte Carlo: standard deviation of those fibers' tilt away
                                    # from the normal, [0, 45]
        felt_crimp_percent = 0      # nonwoven, Monte Carlo: the fibers' crimp, (straightened - crimped
                                    # length) / straightened length in %, [0, 40]; 0: straight fibers.
                                    # A 2-denier polyester staple: 13 (crimp index, Texcoms Textile
                                    # Technical Handbook 2023, polyester fibre characterisation)
        felt_crimp_per_cm = 4.4     # nonwoven, Monte Carlo: crimp waves per cm of crimped fiber, (0, 20];
                                    # 11 per 25 mm for the same fiber (ibid.)
        felt_crimp_plane = "felt"   # nonwoven, Monte Carlo: the plane each fiber's crimp wave lies in:
                                    # "felt" (the wave sideways, in the felt's plane: a crimped fiber
                                    # laid and pressed flat) | "random" (turned about the fiber's axis)
        felt_fuzz_fraction = 0      # nonwoven, Monte Carlo: the fraction of the fiber amount in a loose top
                                    # layer above the compact felt (a hairy surface), [0, 0.5]; 0: none
        felt_fuzz_depth_um = 300    # nonwoven, Monte Carlo: the depth over which those fibers' lowest
                                    # points are spread above the compact felt's top, um, (0, 5000]
        samples = 48                # woven: surface samples per side of the micro-element, [4, 512]

    The keys of :data:`REMOVED_KEYS` and ``kind = "felt"`` are refused with what to write instead.
    """
    for key, instead in REMOVED_KEYS.items():
        if t.has(key):
            raise t.fail(key, f"was removed; {instead}")
    if t.has("kind") and t.raw("kind") == "felt":
        raise t.fail("kind", 'value "felt" was removed; write kind = "nonwoven" (a felt is a nonwoven)')
    spec = StructureSpec(
        kind=t.string("kind", "woven", choices=("woven", "nonwoven")),
        layers=t.integer("layers", 0, ge=0, le=10_000),
        packing_fraction=t.number("packing_fraction", CLOSE_PACKING, gt=0.0, le=round(CLOSE_PACKING, 4) + 1e-12),
        warp_twist_deg=t.number("warp_twist_deg", 24.0, ge=0.0, le=60.0),
        warp_twist=t.string("warp_twist", "Z", choices=("Z", "S")),
        weft_twist_deg=t.number("weft_twist_deg", 24.0, ge=0.0, le=60.0),
        weft_twist=t.string("weft_twist", "Z", choices=("Z", "S")),
        felt_spread_deg=t.number("felt_spread_deg", 20.0, ge=0.0, le=60.0),
        felt_normal_fraction=t.number("felt_normal_fraction", 0.0, ge=0.0, le=0.9),
        felt_normal_spread_deg=t.number("felt_normal_spread_deg", 15.0, ge=0.0, le=45.0),
        felt_crimp_percent=t.number("felt_crimp_percent", 0.0, ge=0.0, le=40.0),
        felt_crimp_per_cm=t.number("felt_crimp_per_cm", 4.4, gt=0.0, le=20.0),
        felt_crimp_plane=t.string("felt_crimp_plane", "felt", choices=("felt", "random")),
        felt_fuzz_fraction=t.number("felt_fuzz_fraction", 0.0, ge=0.0, le=0.5),
        felt_fuzz_depth_um=t.number("felt_fuzz_depth_um", 300.0, gt=0.0, le=5000.0),
        samples=t.integer("samples", 48, ge=4, le=512),
    )
    t.done()
    if spec.kind != "nonwoven":
        for key in FELT_ONLY_KEYS:
            if key in t.data:
                raise t.fail(key, 'is a felt\'s (kind = "nonwoven"); remove it from a woven structure')
    return spec


@dataclass
class Facets:
    """``a [K]`` projected-area fractions, ``M [K, 3, 3]`` fabric-to-facet rotations, ``system [K]`` (0 warp, 1 weft, 2 felt)."""

    a: np.ndarray
    M: np.ndarray
    system: np.ndarray
    info: dict

    @property
    def m_z(self) -> np.ndarray:
        """``[K]`` the fabric normal's component along each facet's normal (the cosine of its tilt)."""
        return self.M[:, 2, 2]

    def visible_fraction(self, system: int) -> float:
        """The projected-area fraction of one yarn system's facets.

        Parameters
        ----------
        system : int
            0 warp, 1 weft, 2 felt.

        Returns
        -------
        float
            The sum of that system's ``a``.
        """
        return float(self.a[self.system == system].sum())


def _frames(t: np.ndarray, m: np.ndarray) -> np.ndarray:
    t = t / np.linalg.norm(t, axis=-1, keepdims=True)
    m = m / np.linalg.norm(m, axis=-1, keepdims=True)
    return np.stack([t, np.cross(m, t), m], axis=-2)


def _twisted(T: np.ndarray, m: np.ndarray, alpha_deg: float, hand: str) -> np.ndarray:
    s = 1.0 if hand == "Z" else -1.0
    a = math.radians(alpha_deg)
    return math.cos(a) * T + s * math.sin(a) * np.cross(T, m)


def flat_facets(spec: StructureSpec) -> Facets:
    """Flat warp and weft yarns (``m = z``), half each, fibers twisted by their system's angle."""
    z = np.array([[0.0, 0.0, 1.0]])
    t_warp = _twisted(np.array([[1.0, 0.0, 0.0]]), z, spec.warp_twist_deg, spec.warp_twist)
    t_weft = _twisted(np.array([[0.0, 1.0, 0.0]]), z, spec.weft_twist_deg, spec.weft_twist)
    M = _frames(np.concatenate([t_warp, t_weft]), np.concatenate([z, z]))
    return Facets(np.array([0.5, 0.5]), M, np.array([0, 1]), {"warp": 0.5, "weft": 0.5, "holes": 0.0})


def woven_facets(weave: Any, spec: StructureSpec) -> Facets:
    """Facets of the weave's top surface sampled on ``spec.samples`` x ``spec.samples`` points (module docstring)."""
    n = int(spec.samples)
    Lx, Ly, p = weave.Lx, weave.Ly, weave.spacing_um
    a_half, b_half = weave.width_um / 2.0, weave.height_um / 2.0
    x = (np.arange(n) + 0.5) / n * Lx
    y = (np.arange(n) + 0.5) / n * Ly
    X, Y = np.meshgrid(x, y, indexing="ij")
    best = np.full(X.shape, -np.inf)
    m = np.zeros(X.shape + (3,))
    T = np.zeros(X.shape + (3,))
    system = np.full(X.shape, -1)
    for yarn in range(weave.n_yarns):
        spline = weave.centre_line(yarn)
        warp = weave.is_warp(yarn)
        along, across = (X, Y) if warp else (Y, X)
        centre = ((yarn if warp else yarn - weave.n_warp) + 0.5) * p
        period = Ly if warp else Lx
        off = (across - centre + period / 2.0) % period - period / 2.0
        u = off / a_half
        inside = np.abs(u) < 1.0
        root = np.sqrt(np.clip(1.0 - u * u, 1e-12, None))
        z = spline(along) + b_half * root
        win = inside & (z > best)
        if not win.any():
            continue
        slope_along = spline(along, 1)
        slope_across = -b_half * u / (a_half * root)
        if warp:
            gx, gy = slope_along, slope_across
            tang = np.stack([np.ones_like(X), np.zeros_like(X), slope_along], axis=-1)
        else:
            gx, gy = slope_across, slope_along
            tang = np.stack([np.zeros_like(X), np.ones_like(X), slope_along], axis=-1)
        normal = np.stack([-gx, -gy, np.ones_like(X)], axis=-1)
        best = np.where(win, z, best)
        m = np.where(win[..., None], normal, m)
        T = np.where(win[..., None], tang, T)
        system = np.where(win, 0 if warp else 1, system)
    keep = system >= 0
    m = m[keep] / np.linalg.norm(m[keep], axis=-1, keepdims=True)
    T = T[keep] / np.linalg.norm(T[keep], axis=-1, keepdims=True)
    system = system[keep]
    t = np.where((system == 0)[:, None], _twisted(T, m, spec.warp_twist_deg, spec.warp_twist),
                 _twisted(T, m, spec.weft_twist_deg, spec.weft_twist))
    a = np.full(system.size, 1.0 / system.size)
    info = {"warp": float(np.mean(system == 0)), "weft": float(np.mean(system == 1)),
            "holes": float(1.0 - keep.mean()), "samples": int(n * n),
            "max_inclination_deg": float(np.degrees(np.arccos(np.clip(m[:, 2], -1, 1))).max())}
    return Facets(a, _frames(t, m), system, info)


def felt_facets(spec: StructureSpec, n_azimuth: int = 36, n_incl: int = 9) -> Facets:
    """Nonwoven felt: fibers of uniform in-plane direction and Gaussian inclination (module docstring).

    The needle-punched population (``felt_normal_fraction``) and the crimp (``felt_crimp_percent``) are the
    Monte Carlo's felt's only (:mod:`simulate.geometry.felt`): here they are left out, and said so once per
    process.
    """
    if spec.felt_normal_fraction > 0.0 and not _NORMAL_NOTED:
        _NORMAL_NOTED.append(True)
        log.warning("the summation's felt has its fibers in the plane only: [structure] felt_normal_fraction "
                    "(%.3g) is taken by --method mc only", spec.felt_normal_fraction)
    if spec.felt_fuzz_fraction > 0.0 and not _FUZZ_NOTED:
        _FUZZ_NOTED.append(True)
        log.warning("the summation's felt has no loose top: [structure] felt_fuzz_fraction (%.3g) is taken by "
                    "--method mc only", spec.felt_fuzz_fraction)
    if spec.felt_crimp_percent > 0.0 and not _CRIMP_NOTED:
        _CRIMP_NOTED.append(True)
        log.warning("the summation's felt has straight fibers: [structure] felt_crimp_percent (%.3g) is taken by "
                    "--method mc only", spec.felt_crimp_percent)
    az = (np.arange(n_azimuth) + 0.5) * math.pi / n_azimuth
    x, w = np.polynomial.hermite_e.hermegauss(n_incl)
    eps = np.radians(spec.felt_spread_deg) * x
    keep = np.abs(eps) <= math.radians(80.0)
    eps, w = eps[keep], w[keep] / w[keep].sum()
    A, E = np.meshgrid(az, eps, indexing="ij")
    weight = np.broadcast_to(w[None, :], A.shape).ravel() / n_azimuth
    t = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)
    z = np.array([0.0, 0.0, 1.0])
    m = z[None, :] - t[:, 2:3] * t
    return Facets(weight, _frames(t, m), np.full(t.shape[0], 2),
                  {"felt": 1.0, "spread_deg": spec.felt_spread_deg, "facets": int(t.shape[0])})


_NORMAL_NOTED: list[bool] = []
_CRIMP_NOTED: list[bool] = []
_FUZZ_NOTED: list[bool] = []


def merged(facets: Facets, tolerance: float = 0.01) -> Facets:
    """Facets whose frames agree to ``tolerance`` merged: weights summed, frames averaged and re-orthonormalised.

    A woven micro-element repeats its yarns' shapes, so most sampled facets come in identical pairs; 0.01
    (~0.6 deg) merges near-identical ones too, well inside the layer table's 7.5-deg grid. Facets of
    different yarn systems are never merged.

    Parameters
    ----------
    facets : Facets
        The sampled facets.
    tolerance : float
        The agreement of each rotation-matrix entry; 0 merges exact duplicates only.

    Returns
    -------
    Facets
        The merged facets; ``info`` gains ``facets`` (merged count) and ``sampled`` (count before).
    """
    key = facets.M.reshape(-1, 9)
    if tolerance > 0:
        key = np.round(key / tolerance)
    key = np.concatenate([key, facets.system[:, None]], axis=1)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    n = int(inverse.max()) + 1
    a = np.bincount(inverse, weights=facets.a, minlength=n)
    M = np.zeros((n, 3, 3))
    np.add.at(M, inverse, facets.M * facets.a[:, None, None])
    M /= a[:, None, None]
    system = np.zeros(n, dtype=facets.system.dtype)
    system[inverse] = facets.system
    frames = _frames(M[:, 0], M[:, 2] - np.einsum("ki,ki->k", M[:, 2], M[:, 0])[:, None] * M[:, 0])
    return Facets(a, frames, system, {**facets.info, "facets": int(n), "sampled": int(facets.a.size)})


def facets_for(spec: StructureSpec, weave: Any | None) -> Facets:
    """The facets of a structure: felt, sampled weave surface, or flat yarns (near-identical ones merged)."""
    if spec.kind == "nonwoven":
        return merged(felt_facets(spec), 0.0)
    if weave is not None:
        return merged(woven_facets(weave, spec))
    return flat_facets(spec)


def fabric_beta_from_G(G: Any, facets: Facets, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """``beta [N, L]`` = ``pi f_fabric`` at fabric-frame pairs ``[N, 3]`` for a layer quantity ``G(w_in, w_out) -> [P, L]``.

    ``G`` is called once on all (pair, facet) combinations in the facets' frames.
    """
    w_i = np.atleast_2d(np.asarray(w_i, float))
    w_o = np.atleast_2d(np.asarray(w_o, float))
    from simulate.fabric.fiberlayer import LayerTable

    if isinstance(G, LayerTable):      # the compiled facet sum (simulate.fabric.structtable)
        from simulate.fabric.structtable import facet_sum

        return math.pi * facet_sum(G, facets, w_i, w_o) / (w_i[:, 2] * w_o[:, 2])[:, None]
    K, N = facets.a.size, w_i.shape[0]
    li = np.einsum("kab,nb->nka", facets.M, w_i).reshape(-1, 3)
    lo = np.einsum("kab,nb->nka", facets.M, w_o).reshape(-1, 3)
    g = np.asarray(G(li, lo), float).reshape(N, K, -1)
    weight = facets.a / facets.m_z
    total = np.einsum("k,nkl->nl", weight, g)
    return math.pi * total / (w_i[:, 2] * w_o[:, 2])[:, None]


#: photons per BSSRDF row of the exit table (both halves together) that the FIRST round of the
#: controlled tables expects to reach a 1 % relative error of beta (simulate.fiber.farfield.controlled_halves
#: then adds photons if the error measured is above the target). Calibrated on red cotton over its
#: plan, in the one definition of the error (RMS of u / each direction's spectral peak): 2 x 4000
#: photons per row gave 0.21 %, so 1 % needs ~350; twice that, because at a few hundred photons per
#: row the rare heavy weights of the spectral re-weighting make the two-halves error estimate unreliable
#: (seeds 0-2 at 400: 0.79 %, 0.66 % -- 1.12 % by comparison with a 0.21 % run --, 1.74 % -> 3 rounds)
PHOTONS_PER_ROW_AT_1PCT = 800


#: above this many geometries the facet sum is tabulated over fabric-frame pairs (simulate.fabric.structtable:
#: ~13 s to build for ~10^3 facets, then ~10^7 values/s) instead of being summed per geometry (~10^5 values/s)
BULK_GEOMETRIES = 50_000


def interior_layers(spec: StructureSpec, weave: Any, radius_um: float) -> int:
    """The interior closure's number of fiber layers.

    Parameters
    ----------
    spec : StructureSpec
        The ``[structure]`` table; its ``layers``, when set, is the answer.
    weave : Weave or None
        The weave; None, or a felt: 10 layers.
    radius_um : float
        The fiber radius (um).

    Returns
    -------
    int
        ``[structure] layers``, else 10 for a felt (or a structure without a weave), else the weave's yarn
        height over the fiber radius (two yarn systems), at least 1.
    """
    return int(spec.layers or (10 if spec.kind == "nonwoven" or weave is None
                               else max(1, round(weave.height_um / radius_um))))


def layer_table_of(spec: StructureSpec, table: Any, fiber: Any, n_layers: int, *, surface: bool = True,
                   tick: Any = None) -> Any:
    """The layer table of one exit table: the visible layer with masking plus the interior closure's return.

    The interior closure returns light from ``n_layers`` layers below (docs/physics.md 6.1, 6.3).

    Parameters
    ----------
    spec : StructureSpec
        The ``[structure]`` table (its ``spacing_ratio``).
    table : ExitTable
        The fiber's exit table.
    fiber : Fiber
        The fiber (its surface roughness and index).
    n_layers : int
        The interior closure's layers (:func:`interior_layers`).
    surface : bool
        Include the layer's surface term; False leaves it out (:func:`surface_layer_table` is that term on
        its own).
    tick : callable, optional
        Called before each incident direction (an interrupt stops there).

    Returns
    -------
    LayerTable
        ``G`` on the 7.5-degree layer grid.
    """
    from simulate.fabric.fiberlayer import layer_table
    from simulate.fabric.interior import interior

    inner = interior(table, fiber, n_layers, spacing_ratio=spec.spacing_ratio, tick=tick)
    return layer_table(table, fiber, masking=True, spacing_ratio=spec.spacing_ratio, interior=inner,
                       surface=surface, tick=tick)


def surface_layer_table(spec: StructureSpec, rms_slope: float, n_host: float) -> Any:
    """The layer table of the fiber layer's surface term alone: what :func:`layer_table_of` adds with ``surface=True``.

    Cook-Torrance with masking, analytic, cached by :func:`simulate.fabric.fiberlayer.surface_table`, on
    the same grid as :func:`layer_table_of`.

    Parameters
    ----------
    spec : StructureSpec
        The ``[structure]`` table (its ``spacing_ratio``).
    rms_slope : float
        The fiber surface's RMS slope.
    n_host : float
        The fiber's refractive index.

    Returns
    -------
    LayerTable
        ``G_surf`` with one channel.
    """
    from simulate.fabric.fiberlayer import LayerTable, layer_grid, surface_table

    th, ph_i, ph_o, _ = layer_grid(7.5, 15.0)
    G = surface_table(float(rms_slope), float(n_host), True, float(spec.spacing_ratio), 7.5, 15.0)[..., None]
    return LayerTable(th, ph_i, th, ph_o, np.ascontiguousarray(G), True, float(spec.spacing_ratio))


def mean_of_halves(beta_0: np.ndarray, beta_1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``beta`` of two independent halves and its standard error: their mean and half their difference.

    One degree of freedom per value (:func:`simulate.fiber.farfield.controlled_halves`).

    Parameters
    ----------
    beta_0, beta_1 : numpy.ndarray
        The two halves' ``beta``, of one shape.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``beta`` and ``u_beta``.
    """
    return 0.5 * (beta_0 + beta_1), 0.5 * np.abs(beta_0 - beta_1)


def structured_beta(spec: StructureSpec, fiber: Any, weave: Any, w_i: np.ndarray, w_o: np.ndarray,
                    wavelengths_nm: Any, *, target_rel_err: float = 0.01, seed: int = 0, threads: int | None = None,
                    photons_per_row: int | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """``beta, u_beta [N, L]`` of the structured summation at fabric-frame pairs, and what it took.

    Two independent exit tables (seeds ``2 seed``, ``2 seed + 1``) starting at ``PHOTONS_PER_ROW_AT_1PCT
    (0.01 / target)^2 / 2`` photons per row each, their layer tables with the interior closure
    (:func:`layer_table_of`) summed over the facets (:func:`fabric_beta_from_G`), ``beta`` their mean and
    ``u_beta = |beta_1 - beta_2| / 2`` (:func:`mean_of_halves`: the standard error of the mean of two
    independent estimates, one degree of freedom per value, so its RMS over many values is the figure to
    read); more photons are added until that error meets the target
    (:func:`simulate.fiber.farfield.controlled_halves`).

    ``photons_per_row``: the fixed-photons mode -- ONE round of exactly that many photons per row in
    each half (the first round's streams, seeds ``2 seed + h``), no accuracy loop. It is the model
    ``simulate fit --method summation`` evaluates (:mod:`simulate.structwalk.walk`, built from this
    module's steps: a fit's dye changes at every evaluation, so its photons cannot follow an error
    measured at one dye).
    """
    import time

    from simulate.fiber import farfield as FF

    t0 = time.perf_counter()
    wl = np.atleast_1d(np.asarray(wavelengths_nm, float))
    w_i = np.atleast_2d(np.asarray(w_i, float))
    w_o = np.atleast_2d(np.asarray(w_o, float))
    facets = facets_for(spec, weave)
    info: dict[str, Any] = {"structure": {k: getattr(spec, k) for k in spec.__dataclass_fields__},
                            "facets": facets.info, "spacing_ratio": spec.spacing_ratio}
    per_row = int(math.ceil(PHOTONS_PER_ROW_AT_1PCT * (0.01 / target_rel_err) ** 2 / 2.0))
    fixed = None
    if photons_per_row is not None:
        if int(photons_per_row) < FF.MIN_PHOTONS_PER_ROW:
            raise ValueError(f"structured_beta: photons_per_row must be at least {FF.MIN_PHOTONS_PER_ROW}")
        per_row = fixed = int(photons_per_row)
    fiber = FF.cached(fiber)       # the Mie optics once, not once per exit-table node
    n_layers = interior_layers(spec, weave, fiber.radius_um)

    def beta_of(table: Any) -> np.ndarray:
        lt = layer_table_of(spec, table, fiber, n_layers)
        if w_i.shape[0] > BULK_GEOMETRIES:   # many geometries: tabulate the facet sum once, then gather
            from simulate.fabric.structtable import fabric_table

            return fabric_table(lt, facets).beta(w_i, w_o)
        return fabric_beta_from_G(lt, facets, w_i, w_o)

    # the error asked for is beta's: the controller grows both tables until it is met
    beta, u_beta, ctl = FF.controlled_halves(fiber, wl, beta_of, target_rel_err, per_row=per_row, seed=seed,
                                             threads=threads, max_photons_per_row=fixed)
    info.update(ctl, layers=n_layers, seconds=time.perf_counter() - t0)
    return beta, u_beta, info
