r"""A fiber seen as part of a surface: the visible-surface average with masking (docs/physics.md section 6.1).

Model. The fiber lies in a LAYER of parallel, identical fibers: layer frame x = the fiber axis
``t``, z = the layer normal ``m``, y = ``m x t``; the fibers' axes lie in the plane ``z = 0`` at
``y = j d`` (``d = s 2R``, ``s >= 1`` the spacing ratio; ``s = 1`` touching fibers, the default:
the surface layer of a yarn or a felt is a closely packed layer of fibers). A point of the central
fiber at azimuth ``psi`` (``p = R n(psi)``, ``n = (0, -sin psi, cos psi)``) is LIT from ``w_i`` when it
faces it and the ray towards the source misses the neighbours ``j = +-1``, and SEEN from ``w_o``
likewise. The cross-section is the same all along the axis, so the test is two-dimensional: the ray
``p + s (w_y, w_z)`` against the circles of radius ``R`` at ``(+-d, 0)``. For directions above the
layer (``w_z > 0``) only the nearest neighbours can block; directions below it see nothing (the
layer stands on the fabric's interior).

The layer's BRDF per unit LAYER area (``E_perp`` the beam irradiance; ``Q`` the intensity per unit
length that leaves the lit parts of the fiber through its seen parts)::

    f_layer(w_i, w_o) = Q(w_i, w_o) / (d (w_i . m) (w_o . m))                       G := Q / d  [1/sr]

    Q_vol  = sum_B  W_o(B) R_B,vis(w_o)            W_o(B) = int_B vis_o(psi) (w_o . n)_+ R dpsi
    R_B,vis = sum_{A lit} l_i(A) T(A -> B, bin) / Omega_bin     (the exit table, simulate.fiber.farfield)
    Q_surf = int vis_i vis_o (w_i . n)_+ (w_o . n)_+ f_CT(local) R dpsi

``l_i(A)`` is the fraction of cell A's irradiance that reaches it (shadowing: the light a
neighbour intercepts is the neighbour's, counted when the neighbour is the central fiber).
Without masking (``masking=False``) every point facing ``w_i`` is lit and every point facing
``w_o`` seen: the plain visible average of the far field (``Q = S`` of docs/physics.md 5.1).

Limits, stated: (1) light that is masked (leaves towards a neighbour) or leaves downwards is lost
to this single layer -- in a real fabric it enters the neighbours and the fibers below; (2) a
partly shadowed entry cell keeps the exit distribution of a fully lit one (its weight is the lit
fraction); (3) the cells are the exit table's (10 deg): visibility is resolved within a cell by
``n_sub`` points; (4) the surface term is single-bounce Cook-Torrance with the masked part removed.

Speed. :class:`LayerTable` tabulates ``G`` on a grid over the layer-frame hemisphere pairs (by the
mirrors ``x -> -x`` and ``y -> -y`` of both directions, ``w_i`` only in the quadrant
``x, y >= 0``) and :func:`layer_lookup` interpolates it multilinearly in
``(theta_i, phi_i, theta_o, phi_o)`` in compiled code.

References
----------
Ashikhmin, M., Premoze, S. & Shirley, P. (2000). A microfacet-based BRDF generator. *SIGGRAPH*,
65-74 (visibility-weighted averages of a surface's BRDF). Irawan, P. & Marschner, S. (2012).
Specular reflection from woven cloth. *ACM TOG* 31(1), 11. d'Eon et al. (2011), see
:mod:`simulate.fiber.farfield`.
"""

from __future__ import annotations

import functools
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from simulate.fiber.farfield import ExitTable, cell_frame
from simulate.optics import microfacet
from simulate.optics.fresnel import OpticsDomainWarning

__all__ = ["LayerTable", "layer_table", "surface_table", "layer_lookup", "visibility", "visibility_any", "layer_G", "surface_Q", "layer_grid"]


def visibility(w: np.ndarray, psi: np.ndarray, spacing: float | None) -> np.ndarray:
    """``[P, n]``: 1 where the point at ``psi`` (radius 1) faces ``w [P, 3]`` and no neighbour blocks the ray.

    ``spacing`` is ``d / R`` (2 for touching fibers); None: no masking (facing is enough).
    """
    w = np.atleast_2d(np.asarray(w, float))
    psi = np.asarray(psi, float)
    ny, nz = -np.sin(psi)[None, :], np.cos(psi)[None, :]
    facing = (w[:, 1:2] * ny + w[:, 2:3] * nz) > 0
    if spacing is None:
        return facing.astype(float)
    above = w[:, 2:3] > 0
    norm = np.hypot(w[:, 1], w[:, 2])
    uy = np.where(norm > 0, w[:, 1] / np.where(norm > 0, norm, 1.0), 0.0)[:, None]
    uz = np.where(norm > 0, w[:, 2] / np.where(norm > 0, norm, 1.0), 1.0)[:, None]
    free = np.ones(facing.shape, bool)
    for c in (-spacing, spacing):
        qy, qz = ny - c, nz
        b = qy * uy + qz * uz
        disc = b * b - (qy * qy + qz * qz - 1.0)
        free &= ~((b < 0) & (disc > 0))
    return (facing & above & free).astype(float)


def visibility_any(w: np.ndarray, psi: np.ndarray, spacing: float | None) -> np.ndarray:
    """:func:`visibility` for directions above OR below the layer (the layer is symmetric about z = 0).

    Below (``w_z < 0``): the mirror image, ``w -> (w_x, w_y, -w_z)`` and ``psi -> pi - psi``.
    """
    w = np.atleast_2d(np.asarray(w, float))
    out = visibility(w, psi, spacing)
    down = w[:, 2] < 0
    if spacing is not None and down.any():
        out[down] = visibility(w[down] * np.array([1.0, 1.0, -1.0]), math.pi - np.asarray(psi, float), spacing)
    return out


def cell_fractions(table: ExitTable, w: np.ndarray, spacing: float | None, n_sub: int = 0, radius: float = 1.0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Per cell, exactly: the unshadowed fraction of its irradiance from ``w`` and its unmasked width towards ``w``.

    Projected along ``w`` onto the cross-section, a point at ``psi`` has the coordinate
    ``s = R sin(psi - beta)`` across the beam (``n(beta)`` along ``w_perp``) and receives ``E_perp |w_perp| ds``.
    The neighbour ``j = +-1`` that lies towards ``w`` (``j d w_y > 0``) covers ``s`` in
    ``[-j d cos(beta) - R, -j d cos(beta) + R]`` (two disjoint disks: a line of constant ``s`` meets
    the nearer one first); the other neighbours are behind it. Directions below the layer see
    nothing (``spacing`` given).

    Parameters
    ----------
    table : ExitTable
        The fiber's exit table (its cells: ``n_psi``, ``dpsi``).
    w : numpy.ndarray
        Directions in the layer frame, ``[P, 3]`` (or one ``[3]``).
    spacing : float or None
        The fibers' centre spacing over their radius; None: a lone fiber, no neighbour shadows.
    n_sub : int
        Not used (kept for the signature).
    radius : float
        The fiber's radius (um).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The unshadowed fraction ``[P, n_psi]`` and the unmasked projected width ``[P, n_psi]`` (um).
    """
    del n_sub
    w = np.atleast_2d(np.asarray(w, float))
    n, dpsi = table.n_psi, table.dpsi
    wp = np.hypot(w[:, 1], w[:, 2])
    beta = np.arctan2(-w[:, 1], w[:, 2])
    centre = (np.arange(n) * dpsi)[None, :] - beta[:, None]
    centre = (centre + math.pi) % (2.0 * math.pi) - math.pi
    lo = np.clip(centre - dpsi / 2.0, -math.pi / 2.0, math.pi / 2.0)
    hi = np.clip(centre + dpsi / 2.0, -math.pi / 2.0, math.pi / 2.0)
    s_lo, s_hi = radius * np.sin(lo), radius * np.sin(hi)
    full = np.clip(s_hi - s_lo, 0.0, None)
    free = full.copy()
    if spacing is not None:
        d = spacing * radius
        j = np.sign(w[:, 1])                                  # the neighbour towards w
        mid = (-j * d * np.cos(beta))[:, None]
        overlap = np.clip(np.minimum(s_hi, mid + radius) - np.maximum(s_lo, mid - radius), 0.0, None)
        free = np.where((j != 0)[:, None], np.clip(full - overlap, 0.0, None), full)
        free = np.where((w[:, 2] > 0)[:, None], free, 0.0)
    frac = np.where(full > 0, free / np.where(full > 0, full, 1.0), 0.0)
    return frac, wp[:, None] * free


def layer_G(table: ExitTable, fiber: Any, w_in: np.ndarray, w_out: np.ndarray, *, masking: bool = True,
            spacing_ratio: float = 1.0, n_sub: int = 8, n_psi_surface: int = 180, surface: bool = True,
            radiance: np.ndarray | None = None) -> np.ndarray:
    """``G(w_i, w_o) = Q / d`` ``[O, L]`` (1/sr) for ONE incident direction and ``O`` exit directions (layer frame).

    ``f_layer = G / ((w_i . m)(w_o . m))``; 0 where either direction is below the layer. ``radiance``:
    :func:`lit_radiance` of this beam when the caller has it (:func:`layer_table` shares it with the
    interior's :func:`simulate.fabric.interior.layer_energy`).
    """
    w_in = np.asarray(w_in, float).reshape(3)
    w_out = np.atleast_2d(np.asarray(w_out, float))
    L = table.T.shape[-1]
    out = np.zeros((w_out.shape[0], L))
    if w_in[2] <= 0:
        return out
    spacing = 2.0 * spacing_ratio if masking else None
    if radiance is None:
        radiance = lit_radiance(table, w_in, spacing, n_sub)
    R, _ = table.lookup(radiance, w_out)
    _, width = cell_fractions(table, w_out, spacing, n_sub, table.radius_um)
    up = w_out[:, 2] > 0
    out[up] = np.einsum("ok,okl->ol", width[up], R[up])
    if surface:
        out[up] += surface_Q(fiber, w_in, w_out[up], spacing, spacing, n_psi_surface)[:, None]
    d = 2.0 * spacing_ratio * table.radius_um
    return out / d


def lit_radiance(table: ExitTable, w_in: np.ndarray, spacing: float | None, n_sub: int = 8) -> np.ndarray:
    """The exit radiance of every cell and bin for the beam ``w_in``, entry cells weighted by their lit fraction."""
    lit, _ = cell_fractions(table, np.asarray(w_in, float).reshape(1, 3), spacing, n_sub, table.radius_um)
    return table.exit_radiance(w_in, lit[0])


def surface_Q(fiber: Any, w_in: np.ndarray, w_out: np.ndarray, spacing_in: float | None, spacing_out: float | None,
              n_psi: int) -> np.ndarray:
    """Surface part of ``Q`` ``[O]`` (um/sr): lit with masking ``spacing_in``, seen with ``spacing_out`` (None: facing only)."""
    dpsi = 2.0 * math.pi / n_psi
    psi = (np.arange(n_psi) + 0.5) * dpsi - math.pi
    li = cell_frame(w_in[None, :], psi)                                  # [n, 3]
    lo = cell_frame(w_out[:, None, :], psi[None, :])                     # [O, n, 3]
    ok = (li[None, :, 2] > 0) & (lo[..., 2] > 0)
    li_b = np.broadcast_to(li[None], lo.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpticsDomainWarning)  # grazing points: finite, vanishing weight
        f = microfacet.cook_torrance(np.where(ok[..., None], li_b, [0.0, 0.0, 1.0]),
                                     np.where(ok[..., None], lo, [0.0, 0.0, 1.0]), fiber.roughness, fiber.n_host)
    weight = np.where(ok, f * li_b[..., 2] * lo[..., 2], 0.0)
    weight = weight * visibility(w_in[None], psi, spacing_in) * visibility_any(w_out, psi, spacing_out)
    return fiber.radius_um * dpsi * weight.sum(axis=1)


@dataclass
class LayerTable:
    """``G`` on the grid ``theta_i [Ti] x phi_i [Pi] x theta_o [To] x phi_o [Po]`` (degrees), ``[..., L]``.

    ``phi_i`` covers 0..90 (the mirrors give the rest), ``phi_o`` 0..360 (the last node = the first).
    """

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    G: np.ndarray
    masking: bool
    spacing_ratio: float
    seconds: float = 0.0
    interior: Any = None

    def __call__(self, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
        """``G [P, L]`` at layer-frame pairs ``w_in, w_out [P, 3]`` (0 below the layer)."""
        return layer_lookup(self, w_in, w_out)


def layer_grid(step_deg: float, phi_step_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The angles of a :class:`LayerTable`'s grid and its exit directions.

    The incident azimuths span a quarter turn (the layer's two mirror symmetries), the exit azimuths a
    whole turn; exit directions at 90 degrees are clipped onto the layer's plane.

    Parameters
    ----------
    step_deg : float
        The polar step (degrees), from 0 to 90.
    phi_step_deg : float
        The azimuth step (degrees).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray, numpy.ndarray)
        Polar angles ``[T]``, incident azimuths ``[Pi]`` and exit azimuths ``[Po]`` (degrees), and the exit
        directions ``[T * Po, 3]`` (polar-major).
    """
    th = np.arange(0.0, 90.0 + 1e-9, step_deg)
    ph_i = np.arange(0.0, 90.0 + 1e-9, phi_step_deg)
    ph_o = np.arange(0.0, 360.0 + 1e-9, phi_step_deg)
    tt, pp = np.meshgrid(np.radians(th), np.radians(ph_o), indexing="ij")
    w_out = microfacet.direction(tt.ravel(), pp.ravel())
    w_out[:, 2] = np.clip(w_out[:, 2], 0.0, None)
    return th, ph_i, ph_o, w_out


@functools.lru_cache(maxsize=8)
def surface_table(roughness: float, n_host: float, masking: bool, spacing_ratio: float, step_deg: float = 7.5,
                  phi_step_deg: float = 15.0, n_psi: int = 180) -> np.ndarray:
    """The surface part of ``G`` on the :class:`LayerTable` grid ``[Ti, Pi, To, Po]``, cached.

    It is independent of the exit table and of the fiber radius: ``Q_surf`` and ``d`` both scale with ``R``.

    Each incidence's row is :func:`surface_Q` of every exit direction above the layer, computed in compiled code
    (:func:`_surface_weights`: the same operations in the same order, summed by numpy as there; equal to
    :func:`surface_Q`'s table bit for bit, tests/fabric_optics/fitting/test_surface_table.py; about a tenth of its
    CPU); the exit directions' cell frames and visibility, which do not depend on the incidence, are formed once.

    Parameters
    ----------
    roughness : float
        The fiber surface's RMS slope (Beckmann).
    n_host : float
        The fiber's refractive index.
    masking : bool
        Whether neighbouring fibers shadow and mask the surface.
    spacing_ratio : float
        The fibers' centre spacing over twice their radius.
    step_deg, phi_step_deg : float
        The grid's polar and azimuth steps (degrees; :func:`layer_grid`).
    n_psi : int
        Surface cells around the fiber in the azimuth sum.

    Returns
    -------
    numpy.ndarray
        ``G_surf [Ti, Pi, To, Po]``, read-only (shared by the cache).
    """
    from simulate.fiber import Fiber
    from simulate.media.medium import HGMedium

    # refuses a slope or index that is not a finite number > 0 (cook_torrance's own checks)
    fiber = Fiber(radius_um=1.0, n_host=n_host, medium=HGMedium(mu_s=0.0, mu_a=0.0, g=0.0), roughness=roughness)
    m = float(fiber.roughness)
    th, ph_i, ph_o, w_out = layer_grid(step_deg, phi_step_deg)
    spacing = 2.0 * spacing_ratio if masking else None
    out = np.zeros((th.size, ph_i.size, th.size, ph_o.size))
    dpsi = 2.0 * math.pi / n_psi
    psi = (np.arange(n_psi) + 0.5) * dpsi - math.pi
    up = w_out[:, 2] > 0
    lo = np.ascontiguousarray(cell_frame(w_out[up][:, None, :], psi[None, :]))          # [O, n, 3]
    seen = np.ascontiguousarray(visibility_any(w_out[up], psi, spacing))                # [O, n]
    log_pi_m2 = float(np.log(np.pi * np.asarray(m) * np.asarray(m)))
    for a, t_i in enumerate(th):
        for b, p_i in enumerate(ph_i):
            w_in = microfacet.direction(math.radians(t_i), math.radians(p_i))
            if w_in[2] < 1e-12:
                continue
            li = np.ascontiguousarray(cell_frame(w_in[None, :], psi))                   # [n, 3]
            lit = np.ascontiguousarray(visibility(w_in[None], psi, spacing)[0])          # [n]
            q = np.zeros(w_out.shape[0])
            weights = _surface_weights(li, lo, lit, seen, m, float(fiber.n_host), log_pi_m2)
            q[up] = fiber.radius_um * dpsi * weights.sum(axis=1)
            out[a, b] = q.reshape(th.size, ph_o.size) / (2.0 * spacing_ratio)
            if t_i == 0.0:
                out[a, 1:] = out[a, 0]
                break
    out.flags.writeable = False
    return out


@numba.njit(cache=True, error_model="numpy")
def _surface_weights(li, lo, lit, seen, m, n_host, log_pi_m2):
    """``f_CT (w_i . n)(w_o . n) vis_i vis_o`` ``[O, n]``, the terms of :func:`surface_Q`'s azimuth sum.

    From the cell-frame incidence ``li [n, 3]``, exits ``lo [O, n, 3]``, visibilities ``lit [n]`` and ``seen [O, n]``:
    :func:`simulate.optics.microfacet.cook_torrance` (Beckmann ``D``, V-cavity ``G``, unpolarised Fresnel ``F``
    from outside, index 1, into ``n_host``) written out per point, its operations in numpy's order.
    """
    n_out, n = seen.shape
    w = np.zeros((n_out, n))
    same = n_host == 1.0
    eta = 1.0 / n_host
    mm = m * m
    for o in range(n_out):
        for k in range(n):
            ix, iy, ci = li[k, 0], li[k, 1], li[k, 2]
            ox, oy, co = lo[o, k, 0], lo[o, k, 1], lo[o, k, 2]
            if not (ci > 0.0 and co > 0.0):
                continue
            sx, sy, sz = ix + ox, iy + oy, ci + co
            norm = math.sqrt((sx * sx + sy * sy) + sz * sz)
            if norm > 0.0:
                hx, hy, hz = sx / norm, sy / norm, sz / norm
            else:
                hx, hy, hz = 0.0, 0.0, 1.0
            oh = (ox * hx + oy * hy) + co * hz
            # Beckmann D (microfacet._beckmann_d)
            if hz > 0.0:
                cs = min(hz, 1.0)
                tan2 = (1.0 - cs * cs) / (cs * cs)
                d = math.exp((-tan2 / mm - log_pi_m2) - 4.0 * math.log(cs))
            else:
                d = 0.0
            # V-cavity G (microfacet.vcavity_g)
            if hz > 0.0 and oh > 0.0:
                g = min(1.0, min(2.0 * hz * co / oh, 2.0 * hz * ci / oh))
            else:
                g = 0.0
            # unpolarised Fresnel (fresnel.reflectance_from_cos of clip(oh, 0, 1))
            c = min(max(abs(min(max(oh, 0.0), 1.0)), 0.0), 1.0)
            s = math.sqrt(max(1.0 - c * c, 0.0))
            es = eta * s
            sin2_t = es * es
            if same:
                f = 0.0
            elif sin2_t >= 1.0:
                f = 1.0
            else:
                cos_t = math.sqrt(max(1.0 - sin2_t, 0.0))
                rs = (1.0 * c - n_host * cos_t) / (1.0 * c + n_host * cos_t)
                rp = (n_host * c - 1.0 * cos_t) / (n_host * c + 1.0 * cos_t)
                f = 0.5 * (rs * rs + rp * rp)
            f_ct = d * g * f / (4.0 * (ci * co))
            w[o, k] = f_ct * ci * co * lit[k] * seen[o, k]
    return w


def layer_table(table: ExitTable, fiber: Any, *, masking: bool = True, spacing_ratio: float = 1.0,
                step_deg: float = 7.5, phi_step_deg: float = 15.0, n_sub: int = 8, surface: bool = True,
                interior: Any = None, tick: Callable[[], None] | None = None) -> LayerTable:
    """Tabulate :func:`layer_G` on the layer-frame grid (module docstring).

    The surface part comes from :func:`surface_table` (cached). ``interior`` (a
    :class:`simulate.fabric.interior.Interior`, with ``masking``): add the light returned from inside the
    fabric, ``A_ret(w_i) (w_i . m)(w_o . m) / pi`` (docs/physics.md section 6.3). ``tick``: called before each
    incident direction (the fit's walk stops there when interrupted: :mod:`simulate.structwalk.threads`).
    """
    t0 = time.perf_counter()
    th, ph_i, ph_o, w_out = layer_grid(step_deg, phi_step_deg)
    G = np.zeros((th.size, ph_i.size, th.size, ph_o.size, table.T.shape[-1]))
    for a, t_i in enumerate(th):
        for b, p_i in enumerate(ph_i):
            if tick is not None:
                tick()
            w_in = microfacet.direction(math.radians(t_i), math.radians(p_i))
            if w_in[2] < 1e-12:
                continue  # grazing incidence on the layer: no irradiance
            radiance = lit_radiance(table, w_in, 2.0 * spacing_ratio if masking else None, n_sub)
            g = layer_G(table, fiber, w_in, w_out, masking=masking, spacing_ratio=spacing_ratio, n_sub=n_sub,
                        surface=False, radiance=radiance)
            if interior is not None:   # interior needs masking: the same lit radiance
                ret = interior.returned_for_beam(table, fiber, w_in, spacing_ratio=spacing_ratio, n_sub=n_sub,
                                                 radiance=radiance)
                g += ret[None, :] * w_in[2] * w_out[:, 2:3] / math.pi
            G[a, b] = g.reshape(th.size, ph_o.size, -1)
            if t_i == 0.0:
                G[a, 1:] = G[a, 0]   # the pole: one direction for every phi_i
                break
    if surface:
        G += surface_table(float(fiber.roughness), float(fiber.n_host), bool(masking), float(spacing_ratio),
                           float(step_deg), float(phi_step_deg))[..., None]
    return LayerTable(th, ph_i, th, ph_o, G, masking, float(spacing_ratio), time.perf_counter() - t0, interior)


@numba.njit(cache=True)
def _angles(x, y, z):
    r = math.sqrt(x * x + y * y + z * z)
    t = math.degrees(math.acos(min(1.0, max(-1.0, z / r))))
    p = math.degrees(math.atan2(y, x))
    if p < 0.0:
        p += 360.0
    return t, p


@numba.njit(cache=True)
def _locate(nodes, v):
    n = nodes.size
    step = nodes[1] - nodes[0]
    x = (v - nodes[0]) / step
    i = int(math.floor(x))
    if i < 0:
        return 0, 0.0
    if i >= n - 1:
        return n - 2, 1.0
    return i, x - i


#: symmetry modes of :func:`lookup_one`: the layer's two mirrors (``w_i`` in the quadrant ``x, y >= 0``)
#: or a fabric's turn by 180 deg about the normal (``w_i`` with ``y >= 0``, or ``y = 0`` and ``x >= 0``)
MIRRORS, HALF_TURN = 0, 1


@numba.njit(cache=True, inline="always")
def lookup_one(G, ti, pi_, to, po, ix, iy, iz, ox, oy, oz, scale, sym, out_row):
    """``out_row += scale * G(w_i, w_o)`` by multilinear interpolation (nothing below the plane)."""
    if iz <= 0.0 or oz <= 0.0:
        return
    if sym == MIRRORS:
        if ix < 0.0:
            ix, ox = -ix, -ox
        if iy < 0.0:
            iy, oy = -iy, -oy
    elif iy < 0.0 or (iy == 0.0 and ix < 0.0):
        ix, iy, ox, oy = -ix, -iy, -ox, -oy
    t_i, p_i = _angles(ix, iy, iz)
    t_o, p_o = _angles(ox, oy, oz)
    a, fa = _locate(ti, t_i)
    b, fb = _locate(pi_, p_i)
    c, fc = _locate(to, t_o)
    d, fd = _locate(po, p_o)
    n_l = G.shape[4]
    for da in range(2):
        wa = scale * (fa if da else 1.0 - fa)
        if wa == 0.0:
            continue
        for db in range(2):
            wb = wa * (fb if db else 1.0 - fb)
            if wb == 0.0:
                continue
            for dc in range(2):
                wc = wb * (fc if dc else 1.0 - fc)
                if wc == 0.0:
                    continue
                for dd in range(2):
                    wd = wc * (fd if dd else 1.0 - fd)
                    if wd == 0.0:
                        continue
                    for k in range(n_l):
                        out_row[k] += wd * G[a + da, b + db, c + dc, d + dd, k]


@numba.njit(cache=True, parallel=True)
def lookup_many(G, ti, pi_, to, po, w_in, w_out, sym, out):
    """:func:`lookup_one` for every pair ``[P, 3]`` into ``out [P, L]`` (parallel over pairs)."""
    for p in numba.prange(w_in.shape[0]):
        lookup_one(G, ti, pi_, to, po, w_in[p, 0], w_in[p, 1], w_in[p, 2], w_out[p, 0], w_out[p, 1], w_out[p, 2],
                   1.0, sym, out[p])


def layer_lookup(lt: LayerTable, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
    """Multilinear interpolation of ``lt.G`` at layer-frame pairs ``[P, 3]`` -> ``[P, L]``."""
    w_in = np.ascontiguousarray(np.atleast_2d(w_in), dtype=float)
    w_out = np.ascontiguousarray(np.atleast_2d(w_out), dtype=float)
    out = np.zeros((w_in.shape[0], lt.G.shape[-1]))
    lookup_many(lt.G, lt.theta_i, lt.phi_i, lt.theta_o, lt.phi_o, w_in, w_out, MIRRORS, out)
    return out
