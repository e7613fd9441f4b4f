r"""The yarn's volume as the pile of its fibers: the medium the woven Monte Carlo's yarn table is walked in.

A yarn table that is the FIBER's BSSRDF (radius ``R``, the fiber's medium) with its offsets
scaled to the yarn would let light that entered a yarn 100-250 um across meet the scatterers
and the dye of ONE 20 um fiber -- a yarn as translucent as a single fiber. A yarn is tens of
fibers across. Here its volume is the pile of those fibers, homogenised (the volumetric cloth
models: Schroeder, Zhao & Zwicker 2011; Zhao, Jakob, Marschner & Bala 2011; Khungurn et al. 2015):

* a cylinder of the yarn's radius ``r_yarn = sqrt(a b)`` (the tracer's similar-cylinder mapping,
  :mod:`simulate.raytrace`), filled with the fiber material at the yarn's packing fraction
  ``phi`` (``[structure] packing_fraction``, default the touching layer's 0.9069): per unit yarn
  volume ``phi`` times the fiber's scatterers (Mie: ``phi`` times their volume fraction or number
  density, the same particles in the same host; HG: ``phi mu_s``) and ``phi`` times its host
  absorption (the dye);
* the boundary keeps the fiber's host index: light enters and leaves the pile through the top
  fibers' surfaces (the entry's Fresnel is the lit fiber point's, :class:`FiberSurface` with
  ``surface="fibers"``; the exit's that of the yarn boundary taken as a fiber's).

Neglected, stated: the scattering by the fibers' own air-cellulose boundaries inside the pile
(about ``phi / 2R`` = 0.045 /um for red cotton, against the scatterers' ``phi mu_s`` of 0.6-0.9 /um:
under 7 %); the pile's anisotropy (its fibers run along the yarn); the total internal reflection
at the yarn's boundary is a smooth cylinder's, where a real yarn's boundary is the fibers' curved
surfaces. The pile's table holds the scattering per narrow wavelength group (:data:`HELD_LOG_MU_S`):
the white Monte Carlo's re-weighting of the scattering has heavy tails over a pile's hundreds of events
per path. The red cotton's fabric colour with it: docs/physics.md 6 (woven Monte Carlo, "Yarn made of
fibers").
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from simulate.media.medium import HGMedium, MieMedium, Spectrum

__all__ = ["pile_fiber", "pile_medium", "HELD_LOG_MU_S"]

#: The pile's table holds the scattering of wavelengths within this of the walked one in ``log mu_s``
#: (:func:`simulate.raytrace.yarn.yarn_table`'s ``held_log_mu_s``): a bias of at most 5 % in ``mu_s`` where
#: re-weighting the scattering over a thick pile's hundreds of events per path has heavy-tailed weights.
HELD_LOG_MU_S = 0.05


def _scaled(value: Any, phi: float) -> Any:
    if isinstance(value, Spectrum):
        return Spectrum(value.wavelength_nm, phi * np.asarray(value.values, float), value.name)
    return phi * float(value)


def pile_medium(medium: Any, packing_fraction: float) -> Any:
    """``medium`` diluted to ``packing_fraction``: ``phi`` times its scatterers and its host absorption."""
    phi = float(packing_fraction)
    if not 0.0 < phi <= 1.0:
        raise ValueError(f"pile_medium: packing_fraction must be in (0, 1], not {packing_fraction!r}")
    if isinstance(medium, HGMedium):
        return dataclasses.replace(medium, mu_s=phi * medium.mu_s, mu_a=phi * medium.mu_a)
    if isinstance(medium, MieMedium):
        if medium.volume_fraction is not None:
            particles: dict[str, Any] = {"volume_fraction": phi * float(medium.volume_fraction)}
        else:
            particles = {"number_density_per_um3": phi * float(medium.number_density_per_um3 or 0.0)}
        return dataclasses.replace(medium, mu_a_host_per_um=_scaled(medium.mu_a_host_per_um, phi), **particles)
    raise TypeError(f"pile_medium: no pile of a {type(medium).__name__}")


def pile_fiber(fiber: Any, radius_um: float, packing_fraction: float) -> Any:
    """The "fiber" whose BSSRDF is the yarn's.

    Radius ``radius_um`` (the yarn's), the fiber's host index, roughness and cells, its medium diluted to
    ``packing_fraction`` (module docstring).
    """
    return dataclasses.replace(fiber, radius_um=float(radius_um), medium=pile_medium(fiber.medium, packing_fraction))
