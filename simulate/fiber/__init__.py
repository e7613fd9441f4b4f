r"""Fiber BRDF (docs/physics.md sections 4-5): volume term by Monte Carlo, surface term by Cook-Torrance.

A fiber is a smooth dielectric cylinder of radius ``R`` and host index ``n`` filled with a
scattering medium (:mod:`simulate.media.medium`). Frames: the fiber frame has x = the fiber axis
``t`` and z = the outward normal of the cell B at the top of the fiber (``psi = 0``); a fiber
lying in the fabric plane along the warp has the fabric frame. Directions point away from the
surface (``w_in`` towards the light, ``w_out`` towards the detector). Lengths in um.

What a cell's BRDF means (every route estimates exactly this)
--------------------------------------------------------------
Under a parallel beam of irradiance ``E_perp`` (on a plane normal to the beam) from ``w_in``
(anywhere on the sphere: light that entered elsewhere crosses the fiber), the radiance that
leaves the surface cell ``B = {|psi| < dpsi / 2}`` -- per unit area, per unit solid angle
around ``w_out`` measured in the local frame ``(n(psi), t, b = n x t)`` of the point where it
leaves (the cylinder's invariance makes every point's frame equivalent) -- averaged over the
cell, per unit ``E_perp``::

    R_vol,B(w_in, w_out) = <L_o> / E_perp             f = R / cos(theta_in)  (w_in above B)

For a direction RANGE (``mu = cos theta_out`` in [mu_lo, mu_hi], local azimuth
``phi = atan2(w.b, w.t)`` in [phi_lo, phi_hi]) the average is weighted by the projected solid
angle ``cos theta dOmega`` (the binned estimate of radiance). A beam photon stands for the
power ``E_perp 2 R |w_perp| l / N`` over a fiber length ``l`` and ``|B| = R dpsi l``.

Routes
------
``nee`` (next-event, the fast path)
    Parallel beam over the projected width; at every scattering vertex the photon scores the
    light that would leave B in ``w_out`` directly or after any number of internal
    reflections (:func:`simulate.montecarlo.tallies.score_vertex` derives the vertex-to-cell
    geometry through the curved interface and its Jacobian)::

        R = (2 |w_perp| / dpsi) x mean score per photon

    Light that never scatters (the bare-cylinder refraction, a delta on the cone
    ``w_out . t = w_in . t``) has no density at a point direction: it is binned for ranged
    outputs and left out for point outputs (say so where it matters: weakly scattering fibers).
``beam`` (binned)
    The same beam; exits tallied in the cell and the direction range::

        R = (2 |w_perp| / dpsi) x mean exit weight / Omega_proj,   Omega_proj = (mu_hi^2 - mu_lo^2)/2 (phi_hi - phi_lo)

``bssrdf`` (the original method)
    Photons enter ONE cell A under a parallel beam, uniformly over the cell with launch weight
    ``max(w . n, 0)`` (the irradiance on the surface element), exits registered by cell offset
    and local direction: the BSSRDF table, stored by offset (the cylinder's invariance). Then
    the summation of docs/physics.md section 5 over all cells A_i with the illumination indicator::

        R_vol,B(w_in) = sum_i T(w_in^(A_i), B - A_i, bin) / Omega_proj

    ``T`` = mean exit weight per photon (``|A| = |B|``); ``w_in^(A_i)`` is the beam in A_i's
    frame. The incident grid is the beam rotated by multiples of the cell width, so beams whose
    azimuth about the axis is a multiple of ``dpsi`` use no interpolation; other azimuths are
    interpolated linearly between the two neighbouring multiples (the original interpolated
    its incident grid too).

Spectral ("white") Monte Carlo
------------------------------
Absorption is never walked: photons walk without absorption and every score carries the
likelihood ratio of its path for each wavelength (:mod:`simulate.montecarlo.kernel`): with a
wavelength-independent scattering medium that is exactly ``exp(-mu_a(lambda) L)``. Where the
scattering spectrum changes (Mie particles) the ratio also corrects ``mu_s`` and the phase
function exactly; its variance grows with the mismatch, so wavelengths are grouped so that
``|ln(mu_s / mu_s^ref)| <= 0.25`` and ``|g - g^ref| <= 0.03`` within a group, one walk per group
(the reference is the group's middle wavelength). Re-weighting is unbiased; separate walks
would be too, but cost one walk per wavelength -- one walk per group serves the dye spectrum
for free.

Accuracy control: ``target_rel_err`` is the RMS over outputs and wavelengths of the standard
error relative to the PEAK of that output's spectrum (a 1 % target means 1 % of the brightest
wavelength of each curve: what a colour or a normalised curve is sensitive to; the dark,
dye-absorbed wavelengths of a red fabric would otherwise decide the cost alone). Outputs whose
peak is below 1e-3 of the largest are ignored. Photons are added in rounds, each sized from
the error reached, until the target or ``max_photons`` is met; the achieved value is reported.

Polarisation is ignored (unpolarised Fresnel): for a bare or weakly scattering fiber this
misstates the first internal-reflection order by about 8 % (n = 1.5); for scattering fibers the
effect is washed out.

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
