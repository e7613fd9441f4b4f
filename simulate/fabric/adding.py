r"""Directional light from below: the top fiber layer added, angle by angle, over the layer under it (docs/physics.md 6.3).

The interior closure (:mod:`simulate.fabric.interior`) returns everything the top layer sends down as a
Lambertian lobe. Light that crosses a nearly clear fiber (its transmission TT, strongly forward) keeps
its direction: the layer below reflects it (its white Fresnel lobe and its own volume light) and it
crosses the top layer again -- coloured twice, and near the top layer's own mirror direction. This
module resolves that path in angle; the rest stays with the closure.

Operators of ONE layer (layer frame: x the fiber axis, z the layer normal; per unit area and unit
incident power, ``[1/sr]``; ``w_i`` the direction towards the source, ``v`` the direction the light goes):

    P_refl(w_i -> w_o) = G(w_i, w_o) / (w_i . z)                       the layer's unmasked reflection (6.1)
    P_down(w_i -> v)   = Q_down(w_i, v) / (d (w_i . z)),  v . z < 0     its unmasked downward exits
    P_up(w -> w_o)     = P_down(M(-w) -> M(w_o))                        light from below (mirror M: z -> -z)

``Q_down`` is ``Q`` of :mod:`simulate.fabric.fiberlayer` with the exit cells seen from below: the layer is
symmetric about its mid-plane, so the cell at ``psi`` seen along ``v`` is the cell at ``pi - psi`` seen
along ``M v`` (the same masking test). Light passing between the fibers (spacing ratio > 1) goes
straight on: ``g(w) delta(v + w)`` with ``g`` the gap fraction of :func:`simulate.fabric.interior.layer_energy`.
The layer below is the same layer turned uniformly about the normal (a felt; for a woven fabric the
next layer's fibers are as oriented as the top one's, a stated approximation):
``P_b(w -> w_o) = <P_refl(R_a w -> R_a w_o)>_a``.

The first order of the adding method (van de Hulst 1980, ch. 4; Hansen & Travis 1974, sec. 3) --
down through the top layer, reflected once by the layer below, up through the top layer::

    D(w_i -> w_o) = int int P_down(w_i -> v) P_b(-v -> w) P_up(w -> w_o) dv dw
                  + g(w_i) int P_b(w_i -> w) P_up(w -> w_o) dw + g_up(w_o) int P_down(w_i -> v) P_b(-v -> w_o) dv
                  + g(w_i) P_b(w_i -> w_o) g_up(w_o)

is added to the top layer's ``G`` as ``(w_i . z) D``, and its energy ``E_D = int D dw_o`` is taken out of the
closure's Lambertian lobe: ``A_ret -> A_ret - s E_D``, ``D -> s D`` with ``s = min(1, A_ret / E_D)`` per channel.
The closure keeps the total (a white stack returns exactly what it returned: tests), the adding decides
where the first order goes; every other order (masked light, multiple reflections between the layers, the
layers further down) stays diffuse. The closure's own estimate of the same path, ``C(w_i) = X_u(w_i) r t``
(``X_u = d(w_i) + g(w_i)``; :meth:`simulate.fabric.interior.Interior.first_order`), is one positive term of its
expansion; ``E_D`` differs from it by the angular correlations ``C`` averages out (touching white layers:
within 10 %; a sparse layer: 0.66-1.5, docs/physics.md 6.3) -- which the closure's totals do not see.

Quadrature: ``n_mu`` rings uniform in ``cos theta`` times ``n_phi`` azimuths (offset half a step, so the grid
is closed under the layer's mirrors and the half turn ``v -> -v`` maps it onto itself). Limits, stated:
one reflection between the two layers resolved; the layer below's surface at the walk's RMS slope (a fit
re-evaluates only the top layer's surface); the layer below is not shadowed by the top one beyond what
``P_down`` lets through; quadrature of ``12 x 24`` directions per hemisphere (rings 5 deg wide at the
horizon, 24 deg at the pole; 15 deg in azimuth) smooths lobes narrower than that.

References
----------
van de Hulst, H. C. (1980). *Multiple Light Scattering: Tables, Formulas and Applications*, vol. 1,
ch. 4 (the adding and doubling method). Academic Press. Hansen, J. E. & Travis, L. D. (1974). Light
scattering in planetary atmospheres. *Space Sci. Rev.* 16, 527-610 (sec. 3.3, adding). Stokes (1862),
see :mod:`simulate.fabric.interior`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulate.fabric.fiberlayer import LayerTable, cell_fractions, lit_radiance, lookup_many, surface_Q, MIRRORS

__all__ = ["Hemisphere", "hemisphere", "down_operator", "gap_fraction", "orientation_average", "Adding"]

#: the layer's two mirrors (x -> -x, y -> -y), applied to both directions of a pair, and their product
MIRROR_SIGNS = (np.array([1.0, 1.0, 1.0]), np.array([-1.0, 1.0, 1.0]), np.array([1.0, -1.0, 1.0]),
                np.array([-1.0, -1.0, 1.0]))
FLIP_Z = np.array([1.0, 1.0, -1.0])


@dataclass(frozen=True)
class Hemisphere:
    """Upper-hemisphere quadrature: ``w [n_mu * n_phi, 3]`` (ring-major), each of solid angle ``d_omega``."""

    n_mu: int
    n_phi: int
    w: np.ndarray
    d_omega: float

    def index(self, ring: np.ndarray, j: np.ndarray) -> np.ndarray:
        return ring * self.n_phi + (j % self.n_phi)

    def mirrored(self, m: int) -> np.ndarray:
        """Index map of mirror ``m`` (:data:`MIRROR_SIGNS`): direction ``k`` -> the direction ``MIRROR_SIGNS[m] * w_k``."""
        ring, j = np.divmod(np.arange(self.w.shape[0]), self.n_phi)
        n = self.n_phi
        jj = [j, n // 2 - 1 - j, n - 1 - j, j + n // 2][m]
        return self.index(ring, jj)

    def opposite(self) -> np.ndarray:
        """Index map ``k -> (-w_x, -w_y, w_z)`` (the half turn about z)."""
        return self.mirrored(3)


def hemisphere(n_mu: int = 12, n_phi: int = 24) -> Hemisphere:
    """Rings at the midpoints of ``n_mu`` equal steps in ``cos theta``, azimuths ``(j + 1/2) 2 pi / n_phi``."""
    if n_phi % 4:
        raise ValueError(f"hemisphere: n_phi must be a multiple of 4 (the mirrors), got {n_phi}")
    mu = (np.arange(n_mu) + 0.5) / n_mu
    phi = (np.arange(n_phi) + 0.5) * 2.0 * math.pi / n_phi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - M ** 2)
    w = np.stack([s * np.cos(P), s * np.sin(P), M], axis=-1).reshape(-1, 3)
    return Hemisphere(n_mu, n_phi, w, 2.0 * math.pi / (n_mu * n_phi))


def gap_fraction(table: Any, w: np.ndarray, spacing_ratio: float) -> np.ndarray:
    """``g [P]``: the fraction of a beam from ``w [P, 3]`` (above the layer) that passes between the fibers."""
    w = np.atleast_2d(np.asarray(w, float))
    if spacing_ratio <= 1.0:
        return np.zeros(w.shape[0])
    d = 2.0 * spacing_ratio * table.radius_um
    _, width = cell_fractions(table, w, 2.0 * spacing_ratio, 0, table.radius_um)
    return np.clip(1.0 - width.sum(axis=1) / (d * np.clip(w[:, 2], 1e-12, None)), 0.0, 1.0)


def down_operator(table: Any, fiber: Any, w_in: np.ndarray, v: np.ndarray, spacing_ratio: float, *,
                  radiance: np.ndarray | None = None, n_psi_surface: int = 90, surface: bool = True) -> np.ndarray:
    """``P_down(w_in -> v) [V, L]`` (1/sr) for ONE beam ``w_in`` (above) and directions ``v [V, 3]`` below the layer.

    Unmasked downward exits of the volume (exit table) and of the surface (Cook-Torrance), per unit
    incident power; the light between the fibers (:func:`gap_fraction`) is not in it.
    """
    w_in = np.asarray(w_in, float).reshape(3)
    v = np.atleast_2d(np.asarray(v, float))
    spacing = 2.0 * spacing_ratio
    if radiance is None:
        radiance = lit_radiance(table, w_in, spacing)
    R, _ = table.lookup(radiance, v)
    _, width_m = cell_fractions(table, v * FLIP_Z, spacing, 0, table.radius_um)
    n = table.n_psi
    width = width_m[:, (n // 2 - np.arange(n)) % n]         # the cell at psi seen along v is pi - psi seen along M v
    q = np.einsum("ok,okl->ol", width, R)
    if surface:
        q += surface_Q(fiber, w_in, v, spacing, spacing, n_psi_surface)[:, None]
    return q / (spacing * table.radius_um * w_in[2])


def orientation_average(single: LayerTable, w_a: np.ndarray, w_b: np.ndarray, n_alpha: int = 12) -> np.ndarray:
    """``P_b(w_a -> w_b) [P, L]``: the layer's reflection ``G / (w_a . z)`` averaged over its fiber's azimuth in the plane.

    The layer is unchanged by a half turn, so ``n_alpha`` azimuths over ``[0, pi)`` suffice.
    """
    w_a = np.atleast_2d(np.asarray(w_a, float))
    w_b = np.atleast_2d(np.asarray(w_b, float))
    P = w_a.shape[0]
    out = np.zeros((P, single.G.shape[-1]))
    for a in (np.arange(n_alpha) + 0.5) * math.pi / n_alpha:
        c, s = math.cos(a), math.sin(a)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        lookup_many(single.G, single.theta_i, single.phi_i, single.theta_o, single.phi_o,
                    np.ascontiguousarray(w_a @ rot.T), np.ascontiguousarray(w_b @ rot.T), MIRRORS, out)
    return out / (n_alpha * np.clip(w_a[:, 2], 1e-12, None))[:, None]


@dataclass
class Adding:
    """The first-order adding term on a layer table's grid (module docstring)."""

    hemi: Hemisphere
    spacing_ratio: float

    def up_operator(self, table: Any, fiber: Any, w_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``P_up(w -> w_out) [W, O, L]`` for every quadrature direction ``w`` (light going up) and ``w_out [O, 3]``,
        and ``t_up [W, L]``, all the light from ``w`` that crosses the layer upwards (``int P_up dw_o + g``).

        ``P_up(w -> w_o) = P_down(M(-w) -> M w_o)``; ``M(-w)`` runs over the whole upper grid, computed for
        the quadrant ``x, y > 0`` and mirrored (a mirror of both directions leaves ``P_down`` unchanged).
        """
        h = self.hemi
        W, O = h.w.shape[0], w_out.shape[0]
        out: np.ndarray | None = None
        t_up: np.ndarray | None = None
        ring, j = np.divmod(np.arange(W), h.n_phi)
        quadrant = np.flatnonzero(j < h.n_phi // 4)
        src_of = h.opposite()                  # M(-w_k) = grid direction src_of[k]; an involution
        below = h.w * FLIP_Z
        gaps = gap_fraction(table, h.w, self.spacing_ratio)
        for q in quadrant:
            rad = lit_radiance(table, h.w[q], 2.0 * self.spacing_ratio)
            total = down_operator(table, fiber, h.w[q], below, self.spacing_ratio, radiance=rad).sum(axis=0) * h.d_omega
            for m, sign in enumerate(MIRROR_SIGNS):
                # P_down(mirror_m w_q -> M w_o) = P_down(w_q -> mirror_m M w_o)
                p = down_operator(table, fiber, h.w[q], (w_out * FLIP_Z) * sign, self.spacing_ratio, radiance=rad)
                if out is None or t_up is None:
                    out = np.zeros((W, O, p.shape[-1]))
                    t_up = np.zeros((W, p.shape[-1]))
                k = src_of[h.mirrored(m)[q]]
                out[k] = p
                t_up[k] = total + gaps[q]
        assert out is not None and t_up is not None
        return out, t_up

    def term(self, table: Any, fiber: Any, single: LayerTable, w_in: np.ndarray, down: np.ndarray,
             w_out: np.ndarray, up: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """``D [I, O, L]`` for beams ``w_in [I, 3]`` with their ``P_down`` on the grid ``down [I, V, L]`` (``v`` the
        grid mirrored below: ``v_k = M w_k``), exits ``w_out [O, 3]`` and ``up = up_operator(w_out)``; and its
        energy ``E_D [I, L] = int D dw_o`` from the operators' totals (independent of the exit grid)."""
        p_up, t_up = up
        h = self.hemi
        W = h.w.shape[0]
        dw = h.d_omega
        L = down.shape[-1]
        # the layer below on the grid: P_b(-v_k -> w_l); -v_k = (-x, -y, z) of w_k; rotation invariance:
        # rows of the first ring's first azimuth suffice, the others are shifts in azimuth
        ring, j = np.divmod(np.arange(W), h.n_phi)
        firsts = h.index(np.arange(h.n_mu), np.zeros(h.n_mu, int))
        a_idx = np.repeat(firsts, W)
        b_idx = np.tile(np.arange(W), h.n_mu)
        rows = orientation_average(single, h.w[a_idx], h.w[b_idx]).reshape(h.n_mu, W, L)   # [ring_a, (ring_b, j_b)]
        # P_b(w_(ra, ja) -> w_(rb, jb)) = rows[ra, (rb, jb - ja)]
        Pb = np.empty((W, W, L))
        for k in range(W):
            ra, ja = ring[k], j[k]
            Pb[k] = rows[ra, h.index(ring, j - ja)]
        Pb = Pb[h.opposite()]                  # row k: from -v_k
        # D = down @ Pb @ up, per channel (batched matmul over L)
        dn = np.moveaxis(down, -1, 0)          # [L, I, V]
        pb = np.moveaxis(Pb, -1, 0)            # [L, V, W]
        upl = np.moveaxis(p_up, -1, 0)         # [L, W, O]
        mid = dn @ pb                          # [L, I, W]: light leaving the layer below towards w, per sr
        D = mid @ upl * (dw * dw)              # [L, I, O]
        tu = np.moveaxis(t_up, -1, 0)[:, :, None]    # [L, W, 1]
        E = (mid @ tu)[..., 0] * (dw * dw)     # [L, I]
        g_in = gap_fraction(table, w_in, self.spacing_ratio)
        if np.any(g_in > 0):
            g_out = np.where(w_out[:, 2] > 1e-9,
                             gap_fraction(table, w_out * np.array([-1.0, -1.0, 1.0]), self.spacing_ratio), 0.0)
            I, O = w_in.shape[0], w_out.shape[0]
            b_in = orientation_average(single, np.repeat(w_in, W, axis=0), np.tile(h.w, (I, 1))).reshape(I, W, L)
            b_out = orientation_average(single, np.repeat(h.w[h.opposite()], O, axis=0),
                                        np.tile(w_out, (W, 1))).reshape(W, O, L)    # from -v_k to w_o
            b_io = orientation_average(single, np.repeat(w_in, O, axis=0), np.tile(w_out, (I, 1))).reshape(I, O, L)
            D += g_in[None, :, None] * (np.moveaxis(b_in, -1, 0) @ upl) * dw
            D += (dn @ np.moveaxis(b_out, -1, 0)) * dw * g_out[None, None, :]
            D += np.moveaxis(b_io, -1, 0) * g_in[None, :, None] * g_out[None, None, :]
            # the energy: light through the gap reflected towards w, then across the top layer
            E += g_in[None, :] * (np.moveaxis(b_in, -1, 0) @ tu)[..., 0] * dw
        return np.moveaxis(D, 0, -1), np.moveaxis(E, 0, -1)
