r"""Light returned from inside the fabric: the fiber layers below the visible one (docs/physics.md section 6.3).

The visible layer (:mod:`simulate.fabric.fiberlayer`) loses the light it sends towards a neighbour (masked)
or downwards. In a fabric that light is not lost: it enters the neighbours and the fibers below,
which are the same fibers, and part of it comes back out -- coloured by every further passage
through a dyed fiber. This module closes the energy balance with the classical adding of identical
layers (Stokes 1862; the Kubelka-Munk theory of sheets and fabrics is its continuous limit).

For one layer (touching fibers) and a beam from ``w_i`` (per unit layer irradiance), the exit table
and the masking geometry give, per wavelength, the fraction leaving UP unmasked ``u(w_i)``, DOWN
unmasked ``d(w_i)`` and the fraction the lit fibers send out at all ``e(w_i)`` (volume and
surface; the surface's energy is the exact Fresnel reflectance of the lit points, shared between
up, down and masked as the Cook-Torrance lobe shares it -- the lobe alone loses the light its
V-cavities shadow, up to 15 % on a cylinder's grazing sides, which in the closure would act as an
absorption at every layer); the rest of ``e``, ``k = e - u - d``, meets a neighbour. The layer is symmetric about its
mid-plane, so light arriving from below behaves as light from above, mirrored. Averaged over
diffuse (cosine-weighted) incidence they give the layer's diffuse ``r``, ``t``, ``k``. Masked
light re-enters the same layer, from either side with equal weight, so each unit of it leaves
``(r + t) / (1 - k)`` in total, half up and half down: the effective diffuse layer is::

    r' = r + k (r + t) / (2 (1 - k))            t' = t + k (r + t) / (2 (1 - k))

``N`` such layers on a black backing add up by Stokes' recursion (symmetric layers)::

    R_1 = r',   R_{n+1} = r' + t'^2 R_n / (1 - r' R_n)

The fabric's top layer under the beam: its unmasked upward light is the resolved BRDF ``G``; its
masked light returns ``k(w_i) (r + t) / (2 (1 - k))`` upwards at once and sends as much down; what
goes down, ``X = d(w_i) + k(w_i) (r + t) / (2 (1 - k)) + g(w_i)`` (``g`` the light passing between the
fibers of a layer whose spacing exceeds their diameter; it counts in ``t`` too), meets the ``N - 1`` layers below
(``R_b = R_{N-1}``) and comes back through the top layer::

    A_ret(w_i) = k(w_i) (r + t) / (2 (1 - k)) + X R_b t' / (1 - r' R_b)

and leaves as a Lambertian lobe: ``G_ret = A_ret(w_i) (w_i . m)(w_o . m) / pi`` is added to the
layer's ``G``. ``N`` is the fabric's thickness in fiber layers: ``2 h / (2 R)`` for a woven fabric of
yarn height ``h`` (two yarn systems), or the config's ``layers``.

Limits, stated: the returned light is diffuse (a Lambertian lobe) and the re-injected masked light
is diffuse too; the layers below are flat, identical and touching (no yarn-scale gaps, no backing
reflectance); light transmitted through the whole fabric is lost (black backing).

References
----------
Stokes, G. G. (1862). On the intensity of the light reflected from or transmitted through a pile of
plates. *Proc. R. Soc. Lond.* 11, 545-556. Kubelka, P. & Munk, F. (1931). Ein Beitrag zur Optik
der Farbanstriche. *Z. Techn. Physik* 12, 593-601. Kubelka, P. (1948). New contributions to the
optics of intensely light-scattering materials. *JOSA* 38(5), 448-457 (the layer form used here).
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulate.fabric.fiberlayer import cell_fractions, surface_Q, visibility, visibility_any
from simulate.fiber.farfield import ExitTable
from simulate.optics import microfacet
from simulate.optics.fresnel import reflectance_from_cos

__all__ = ["Interior", "exit_classes", "layer_energy", "interior", "stack_reflectance"]


def exit_classes(table: ExitTable, spacing: float, n_sub: int = 3) -> np.ndarray:
    """``[n_psi, n_mu, n_phi, 2]``: fraction of each exit bin's light leaving UP / DOWN unmasked.

    Uniform in the bin's projected solid angle (``mu^2`` and ``phi``), ``n_sub`` points per side
    in direction and per cell width in azimuth.
    """
    n_mu, n_phi = table.bins
    n = table.n_psi
    s = (np.arange(n_sub) + 0.5) / n_sub
    mu_e = np.linspace(0.0, 1.0, n_mu + 1)
    mu = np.sqrt(mu_e[:-1, None] ** 2 + (mu_e[1:, None] ** 2 - mu_e[:-1, None] ** 2) * s[None, :])   # [n_mu, sub]
    phi = -math.pi + (np.arange(n_phi)[:, None] + s[None, :]) * 2.0 * math.pi / n_phi                  # [n_phi, sub]
    psi = (np.arange(n)[:, None] + s[None, :] - 0.5) * table.dpsi                                     # [n, sub]
    out = np.zeros((n, n_mu, n_phi, 2))
    M, P = np.meshgrid(mu.ravel(), phi.ravel(), indexing="ij")
    st = np.sqrt(1.0 - M ** 2)
    loc_t, loc_b, loc_n = st * np.cos(P), st * np.sin(P), M
    for c in range(n):
        for p in psi[c]:
            # local (t, b, n) -> fiber frame: b = (0, cos p, sin p), n = (0, -sin p, cos p)
            w = np.stack([loc_t, loc_b * math.cos(p) - loc_n * math.sin(p), loc_b * math.sin(p) + loc_n * math.cos(p)],
                         axis=-1).reshape(-1, 3)
            vis = visibility_any(w, np.array([p]), spacing)[:, 0]
            up = (vis * (w[:, 2] > 0)).reshape(n_mu, n_sub, n_phi, n_sub).mean(axis=(1, 3))
            down = (vis * (w[:, 2] < 0)).reshape(n_mu, n_sub, n_phi, n_sub).mean(axis=(1, 3))
            out[c, :, :, 0] += up / n_sub
            out[c, :, :, 1] += down / n_sub
    return out


def _sphere(n_mu: int) -> tuple[np.ndarray, float]:
    z = (np.arange(2 * n_mu) + 0.5) / n_mu - 1.0
    a = (np.arange(4 * n_mu) + 0.5) / (4 * n_mu) * 2.0 * math.pi
    Z, A = np.meshgrid(z, a, indexing="ij")
    s = np.sqrt(1.0 - Z ** 2)
    w = np.stack([s * np.cos(A), s * np.sin(A), Z], axis=-1).reshape(-1, 3)
    return w, 4.0 * math.pi / w.shape[0]


def layer_energy(table: ExitTable, fiber: Any, w_in: np.ndarray, classes: np.ndarray, *, spacing_ratio: float = 1.0,
                 n_sub: int = 8, n_psi_surface: int = 72, n_mu_surface: int = 8,
                 radiance: np.ndarray | None = None) -> np.ndarray:
    """Where a beam's light goes in one fiber layer, per unit layer irradiance.

    The four rows are the light leaving the lit fibers up (unmasked), down (unmasked) and in all, and the
    light passing between the fibers (spacing ratio > 1); each is the volume part (the exit table's
    radiance through :func:`exit_classes`) plus the fibers' surface reflection.

    Parameters
    ----------
    table : ExitTable
        The fiber's exit table.
    fiber : Fiber
        The fiber (its surface roughness and index).
    w_in : numpy.ndarray
        The beam's direction in the layer frame, ``[3]``.
    classes : numpy.ndarray
        The exit cells' up and down classes (:func:`exit_classes`).
    spacing_ratio : float
        The fibers' centre spacing over their diameter.
    n_sub : int
        Passed to :func:`simulate.fabric.fiberlayer.cell_fractions` (not used there).
    n_psi_surface, n_mu_surface : int
        The surface reflection's quadrature: cells around the fiber and exit polar steps.
    radiance : numpy.ndarray, optional
        The beam's :func:`simulate.fabric.fiberlayer.lit_radiance` when the caller has it (with masking).

    Returns
    -------
    numpy.ndarray
        ``[4, L]``: up, down, all leaving, passing between, per wavelength.
    """
    w_in = np.asarray(w_in, float).reshape(3)
    spacing = 2.0 * spacing_ratio
    d = spacing * table.radius_um
    norm = d * w_in[2]
    lit, lit_width = cell_fractions(table, w_in[None], spacing, n_sub, table.radius_um)
    gap = max(0.0, 1.0 - float(lit_width.sum()) / norm)   # passes between the fibers (spacing ratio > 1)
    rad = (table.exit_radiance(w_in, lit[0]) if radiance is None else radiance) * table.omega()[None, :, None, None]
    width = table.radius_um * table.dpsi
    vol = np.stack([np.einsum("bmp,bmpl->l", classes[..., 0], rad), np.einsum("bmp,bmpl->l", classes[..., 1], rad),
                    rad.sum(axis=(0, 1, 2))]) * width
    surf = np.array(_surface_energy(float(w_in[0]), float(w_in[1]), float(w_in[2]), spacing, float(fiber.roughness),
                                    float(fiber.n_host), n_psi_surface, n_mu_surface)) * table.radius_um
    return np.concatenate([(vol + surf[:, None]) / norm, np.full((1, vol.shape[1]), gap)])


_SURFACE_LOCK = threading.Lock()


def _surface_energy(wx: float, wy: float, wz: float, spacing: float, roughness: float, n_host: float, n_psi: int,
                    n_mu: int) -> tuple[float, float, float]:
    """:func:`_surface_energy_of`, cached, computed once per key under a lock.

    The fit's walk builds two layer tables at once on threads (:mod:`simulate.structwalk.threads`) over the
    same beams, which would both miss.
    """
    with _SURFACE_LOCK:
        return _surface_energy_of(wx, wy, wz, spacing, roughness, n_host, n_psi, n_mu)


@functools.lru_cache(maxsize=4096)
def _surface_energy_of(wx: float, wy: float, wz: float, spacing: float, roughness: float, n_host: float, n_psi: int,
                       n_mu: int) -> tuple[float, float, float]:
    """Surface reflection (unit radius) leaving up unmasked, down unmasked and in all, for a beam ``w`` (cached)."""
    from simulate.fiber import Fiber
    from simulate.media.medium import HGMedium

    fiber = Fiber(radius_um=1.0, n_host=n_host, medium=HGMedium(mu_s=0.0, mu_a=0.0, g=0.0), roughness=roughness)
    w_in = np.array([wx, wy, wz])
    w, dw = _sphere(n_mu)
    up, down = w[:, 2] > 0, w[:, 2] < 0
    seen = surface_Q(fiber, w_in, w, spacing, spacing, n_psi) * dw
    every = float((surface_Q(fiber, w_in, w, spacing, None, n_psi) * dw).sum())
    # energy: the exact Fresnel reflectance of the lit points (the single-scattering Cook-Torrance lobe
    # loses the light its V-cavities shadow, up to 15 % of it on a cylinder's grazing sides; in the
    # closure that loss would act as an absorption at every layer), shared as the lobe shares it
    psi = (np.arange(4 * n_psi) + 0.5) * (2.0 * math.pi / (4 * n_psi)) - math.pi
    cos = np.clip(-wy * np.sin(psi) + wz * np.cos(psi), 0.0, 1.0)
    lit = visibility(w_in[None], psi, spacing)[0]
    fresnel = float(np.sum(reflectance_from_cos(cos, 1.0, n_host) * cos * lit) * (2.0 * math.pi / (4 * n_psi)))
    scale = fresnel / every if every > 0 else 0.0
    return float(seen[up].sum()) * scale, float(seen[down].sum()) * scale, fresnel


def stack_reflectance(r: np.ndarray, t: np.ndarray, n_layers: int) -> np.ndarray:
    """Diffuse reflectance of ``n_layers`` identical symmetric layers on a black backing (Stokes' recursion)."""
    R = np.zeros_like(np.asarray(r, float))
    for _ in range(int(n_layers)):
        R = r + t * t * R / (1.0 - r * R)
    return R


@dataclass
class Interior:
    """The diffuse layer (``r``, ``t``, ``k``, effective ``r'``, ``t'``) and the stack below the top layer."""

    r: np.ndarray
    t: np.ndarray
    k: np.ndarray
    r_eff: np.ndarray
    t_eff: np.ndarray
    n_layers: int
    R_below: np.ndarray
    classes: np.ndarray

    def returned(self, energy: np.ndarray) -> np.ndarray:
        """``A_ret [L]`` for a beam's ``layer_energy`` ``[4, L]`` (module docstring)."""
        u, d, e, gap = energy
        k = np.clip(e - u - d, 0.0, None)
        share = k * (self.r + self.t) / (2.0 * (1.0 - self.k))
        X = d + share + gap
        return share + X * self.R_below * self.t_eff / (1.0 - self.r_eff * self.R_below)

    def returned_for_beam(self, table: ExitTable, fiber: Any, w_in: np.ndarray, *, spacing_ratio: float = 1.0,
                          n_sub: int = 8, radiance: np.ndarray | None = None) -> np.ndarray:
        """``A_ret [L]``, the light the layers below return, for a beam on the top layer.

        The beam's :func:`layer_energy`, then :meth:`returned`.

        Parameters
        ----------
        table : ExitTable
            The fiber's exit table.
        fiber : Fiber
            The fiber (its surface roughness and index).
        w_in : numpy.ndarray
            The beam's direction in the layer frame, ``[3]``.
        spacing_ratio : float
            The fibers' centre spacing over their diameter.
        n_sub : int
            Passed to :func:`layer_energy`.
        radiance : numpy.ndarray, optional
            The beam's lit radiance when the caller has it.

        Returns
        -------
        numpy.ndarray
            ``A_ret [L]`` per unit layer irradiance.
        """
        return self.returned(layer_energy(table, fiber, w_in, self.classes, spacing_ratio=spacing_ratio, n_sub=n_sub,
                                          radiance=radiance))


def interior(table: ExitTable, fiber: Any, n_layers: int, *, spacing_ratio: float = 1.0, n_theta: int = 6,
             n_phi: int = 4, tick: Callable[[], None] | None = None) -> Interior:
    """Diffuse layer properties by cosine-weighted quadrature over the incident quadrant (mirrors give the rest).

    ``tick``: called before each incident direction (an interrupted caller stops there).
    """
    if int(n_layers) < 1:
        raise ValueError(f"interior: n_layers must be >= 1, got {n_layers!r}")
    classes = exit_classes(table, 2.0 * spacing_ratio)
    u2 = (np.arange(n_theta) + 0.5) / n_theta          # sin^2 theta: uniform in projected solid angle
    ph = (np.arange(n_phi) + 0.5) / n_phi * 0.5 * math.pi
    acc = np.zeros((4, table.T.shape[-1]))
    for s2 in u2:
        for p in ph:
            if tick is not None:
                tick()
            w = microfacet.direction(math.asin(math.sqrt(s2)), p)
            acc += layer_energy(table, fiber, w, classes, spacing_ratio=spacing_ratio)
    u, d, e, gap = acc / (n_theta * n_phi)
    k = np.clip(e - u - d, 0.0, None)
    d = d + gap                                         # diffuse light through the gaps reaches the next layer
    share = k * (u + d) / (2.0 * (1.0 - k))
    r_eff, t_eff = u + share, d + share
    return Interior(u, d, k, r_eff, t_eff, int(n_layers), stack_reflectance(r_eff, t_eff, int(n_layers) - 1), classes)
