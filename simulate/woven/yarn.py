"""The fiber's BSSRDF as a yarn table: the exits the woven-fabric tracer samples (package docstring).

Built with the fiber's public Monte Carlo (:mod:`simulate.fiber.bssrdf`, :mod:`simulate.fiber.spectral`):
white walks per wavelength group, rows for a grid of axial incidences, ``v`` offsets kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulate.fiber.bssrdf import bssrdf_rows, lit_rows
from simulate.fiber.model import as_wavelengths
from simulate.fiber.spectral import group_walk, spectral_optics, wavelength_groups
from simulate.montecarlo.transport import make_control
from simulate.optics.fresnel import reflectance_from_cos

__all__ = ["YarnTable", "yarn_table"]


@dataclass(frozen=True)
class YarnTable:
    """The fiber BSSRDF by offset for a grid of axial incidences (rows ``[w_t node, k >= 0]``).

    ``T[j, k, cell, lambda]``: mean exit weight per photon entering cell A with launch weight
    ``max(w . n, 0)`` (:func:`simulate.fiber.bssrdf_table`), ``cell`` the flat index of
    ``(psi offset, v bin, mu bin, phi bin)``; ``c_bar[j, k]`` the mean launch weight, so that
    ``T / c_bar`` is per unit power arriving at a point of A; ``tau[j, k]`` the mean smooth-
    interface transmission ``1 - F`` of that light (taken out again for light that is inside a
    yarn already: the interpenetration rule).
    """

    T: np.ndarray
    u_T: np.ndarray
    c_bar: np.ndarray
    tau: np.ndarray
    w_t_nodes: np.ndarray
    dpsi: float
    n_psi: int
    n_v: int
    n_mu: int
    n_phi: int
    v_max_R: float
    radius_um: float
    wavelengths_nm: np.ndarray
    photons: int
    seconds: float

    @property
    def exit_fraction(self) -> np.ndarray:
        """``e[j, k, lambda] = sum_cells T / c_bar`` (the energy that comes out again)."""
        return self.T.sum(axis=2) / self.c_bar[:, :, None]


def yarn_table(fiber: Any, wavelengths_nm: Any, *, w_t_nodes: Any = (0.0, 0.25, 0.5, 0.75, 0.95),
               n_v: int = 3, v_max_R: float = 2.0, n_mu: int = 5, n_phi: int = 10,
               photons_per_row: int = 20_000, seed: int = 0, threads: int | None = None) -> YarnTable:
    """Build the BSSRDF rows the woven-fabric tracer samples exits from (white Monte Carlo).

    Only ``w_t >= 0`` and azimuths ``k dpsi >= 0`` are walked (the mirror symmetries of the
    module docstring give the rest). Each row costs ``photons_per_row`` photons per
    wavelength group of the medium.
    """
    wl = as_wavelengths(wavelengths_nm)
    n_psi = fiber.cell_count("yarn table")
    dpsi = 2.0 * math.pi / n_psi
    ks = list(range(0, lit_rows(dpsi) + 1))
    nodes = np.asarray(w_t_nodes, float)
    if nodes.ndim != 1 or nodes[0] != 0.0 or np.any(np.diff(nodes) <= 0) or nodes[-1] >= 1.0:
        raise ValueError("yarn table: w_t_nodes must increase from 0 and stay below 1")
    v_max = v_max_R * fiber.radius_um
    optics = spectral_optics(fiber, wl)
    control = make_control()
    n_cells = n_psi * n_v * n_mu * n_phi
    T = np.zeros((nodes.size, len(ks), n_cells, wl.size))
    u_T = np.zeros_like(T)
    photons = 0
    seconds = 0.0
    for j, w_t in enumerate(nodes):
        for group in wavelength_groups(optics):
            medium, walk_phase, targets = group_walk(fiber, optics, group, white=True)
            t, u, p, s = bssrdf_rows(fiber, float(w_t), ks, (n_psi, n_v, v_max, n_mu, n_phi), medium,
                                        walk_phase, targets, control, photons_per_row, seed + 104729 * j, threads)
            T[j][..., group] = t.reshape(len(ks), n_cells, group.size)
            u_T[j][..., group] = u.reshape(len(ks), n_cells, group.size)
            photons += p
            seconds += s
    # mean launch weight max(w . n, 0) over a cell at azimuth k dpsi: rho <cos(a + x)>_x
    x = np.linspace(-dpsi / 2, dpsi / 2, 4001)
    rho = np.sqrt(1.0 - nodes ** 2)
    cos = np.maximum(rho[:, None, None] * np.cos(np.array(ks)[None, :, None] * dpsi + x[None, None, :]), 0.0)
    c_bar = np.trapezoid(cos, x, axis=2) / dpsi
    # the mean smooth-interface transmission of light entering the row's cell (weighted by w . n)
    transmitted = np.trapezoid(cos * (1.0 - reflectance_from_cos(cos, 1.0, fiber.n_host)), x, axis=2) / dpsi
    tau = np.where(c_bar > 0, transmitted / np.where(c_bar > 0, c_bar, 1.0), 1.0)
    return YarnTable(T, u_T, c_bar, tau, nodes, dpsi, n_psi, n_v, n_mu, n_phi, float(v_max_R),
                     float(fiber.radius_um), wl, photons, seconds)
