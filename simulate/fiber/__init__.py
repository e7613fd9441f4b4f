r"""Fiber BRDF (docs/physics.md sections 4-5): volume term by Monte Carlo, surface term by Cook-Torrance.

A fiber is a smooth dielectric cylinder of radius ``R`` and host index ``n`` filled with a
scattering medium (:mod:`simulate.media.medium`). Frames: the fiber frame has x = the fiber axis
``t`` and z = the outward normal of the cell B at the top of the fiber (``psi = 0``); a fiber
lying in the fabric plane along the warp has the fabric frame. Directions point away from the
surface (``w_in`` towards the light, ``w_out`` towards the detector). Lengths in um.

Every route estimates the same quantity, the radiance leaving a surface cell B per unit beam
irradiance (docs/physics.md, section 5, "What a cell's BRDF means"):

- ``nee``: a beam across the fiber; next-event scores at every scattering vertex (the fast path);
- ``beam``: the same beam, exits binned by cell and direction range;
- ``bssrdf``: the original method, a BSSRDF table summed over the lit cells.

Absorption is never walked ("white" Monte Carlo: each score carries its path's likelihood ratio per
wavelength, one walk per group of wavelengths of similar scattering); ``target_rel_err`` is the
RMS standard error relative to each output's spectral peak (:mod:`simulate.montecarlo.accuracy`).
Polarisation is ignored (unpolarised Fresnel).

Modules: :mod:`.model` (the fiber, outputs, the surface term), :mod:`.spectral` (optics per
wavelength, wavelength groups, the walk of a group, the run-seed rule), :mod:`.routes` (the
``nee`` and ``beam`` routes, :func:`volume_brdf`), :mod:`.bssrdf` (the BSSRDF table and its
route), :mod:`.absorption` (the volume term tabulated over host absorption),
:mod:`.tables` (the fiber BRDF table files). The accuracy control and the one relative error
are :mod:`simulate.montecarlo.accuracy`'s.
"""

from simulate.fiber.bssrdf import bssrdf_table
from simulate.fiber.model import METHODS, BRDFEstimate, Fiber, point_outputs, range_outputs, surface_brdf
from simulate.fiber.routes import fiber_brdf, normal_albedo, volume_brdf

__all__ = [
    "Fiber",
    "BRDFEstimate",
    "volume_brdf",
    "surface_brdf",
    "fiber_brdf",
    "normal_albedo",
    "bssrdf_table",
    "point_outputs",
    "range_outputs",
    "METHODS",
]
