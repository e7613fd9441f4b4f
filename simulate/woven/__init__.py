r"""Monte Carlo ray tracing of a woven fabric: the virtual goniophotometer (docs/physics.md section 6).

Rays of a parallel beam from ``w_in`` strike the micro-element of the weave uniformly (their
targets are uniform over the periodic cell) and are followed through the yarn geometry
(:class:`simulate.woven.scene.PeriodicScene`, Embree) until they leave upward (reflected),
downward (transmitted) or are absorbed (Russian roulette). What happens at a yarn hit is the
fiber model of docs/physics.md sections 4-5, applied to the yarn taken locally as a straight
cylinder about its tangent ``t``:

* **rough-surface reflection**: Cook-Torrance with the host index and the RMS slope, carrying
  its directional albedo ``a_s(cos_i)`` (sampled from the Beckmann distribution);
* **transport through the volume**: the BSSRDF table of the fiber (:func:`yarn_table`, built
  with :mod:`simulate.fiber` and its ``v`` offsets kept) is, for the local incidence, a
  discrete distribution over the exit cell (``d_psi``, ``d_v``) and the exit direction bin; its
  total is the exit fraction ``e(lambda)`` (it contains the smooth-interface transmission
  ``1 - F``). An exit is sampled from it and the ray moves to that point of the yarn tube --
  light that crosses a yarn comes out on its far side.

With a woven ``[structure]`` the yarn is made of fibers (docs/physics.md 6, "Yarn made of
fibers"; :func:`simulate.woven.estimate.yarn_model`): its surface term is reflected from the
top layer of fibers along the twisted fiber direction (``FiberSurface(surface="fibers")``: the
point of a fiber's cross-section the ray meets, shadowing and masking by the neighbours) and its
table is walked in the pile of its fibers (:mod:`.pile`), not in one fiber.

The ray reflects with probability ``p = a_s / (a_s + e_bar)`` (``e_bar`` the exit fraction
averaged over the ray's spectral weight) and enters otherwise, and is re-weighted by
``a_s / p`` or ``e(lambda) / (1 - p)``: the expected response is ``R_surf + R_vol`` as in the
fiber model, i.e. the same (slightly non-conservative, see docs) split of energy.

Mapping the fiber table onto a yarn (the decisions, docs/physics.md section 6)
-----------------------------------------------------------------------------
* The table is the fiber's (radius ``R``); the yarn uses it as a similar cylinder: angular
  offsets are kept (``d_psi`` rotates the exit point about the yarn's axis through the same
  angle, as the cross-section's parametric angle), axial offsets ``v`` are scaled by
  ``r_yarn / R`` with ``r_yarn = sqrt(a b)`` (the cross-section's semi-axes).
* Local incidence ``(w_t, a)`` (``w_t = w_in . t``, ``a`` its azimuth about ``t`` from the
  normal) selects the table row by *stochastic* linear interpolation between the nodes of the
  ``w_t`` grid and the cell-multiple azimuths (unbiased for the linear interpolant). Mirror
  symmetries halve the table: ``w_t -> -w_t`` flips ``v`` and the exit direction's ``t``
  component, ``a -> -a`` flips the cell offset and the ``b`` component.
* Interpenetrating yarns: a ray that starts inside another yarn hits that yarn's surface from
  inside first (a back face); it is moved to that point and processed as entering it (the
  light is in its volume already: no surface reflection), its incidence mirrored about the
  tangent plane.

Estimators
----------
*Next-event* (the camera of the virtual measurement): at every event the light that would leave
straight towards each detector direction ``w_o`` of the plan is scored, if a shadow ray towards
``w_o`` escapes (periodic wrap included). With rays of power ``E cos(theta_i) A / N`` on the
micro-element of area ``A``::

    f(w_in, w_o) = 1 / (N cos theta_o) sum_rays sum_events c(w_o),        beta = pi f

where ``c`` is the radiant intensity per unit incident power of the event: ``f_CT cos_o'`` for
the surface, ``T_bin / (c_bar p_cell) cos_o' / Omega_proj,bin`` for a sampled volume exit
(``'`` = local frame). *Direction bins*: escaping rays binned in ``(cos theta, phi)``:
``f_bin = sum w / (N Omega_proj,bin)``. The energy budget (reflected, transmitted, the rest
absorbed) is tallied per wavelength.

Accuracy control: rays are traced in chunks of fixed size with fixed seeds; after every round
of chunks the RMS over detectors and wavelengths of the standard error relative to each
detector's spectral peak (as :func:`simulate.fiber.volume_brdf`) is compared with the target;
the run stops at the target, or at the ray or time budget, and says which. :func:`trace`'s
standard error is that of the ray tracing *given* the BSSRDF table; :func:`fabric_beta` (the
plan-level entry of ``simulate fabric --method mc``) builds the table as two independent halves
(``table_photons`` per row in all, scaling with the target) and adds the table's own noise,
estimated from the difference of the two halves' traces, to ``u_beta``. A felt (a random
realisation of its fibers) is traced at :data:`FELT_ROTATIONS` azimuths per incidence, each half on
its own realisation: the difference of the halves then holds the spread between realisations too
(:mod:`.estimate`).

Modules: :mod:`.scene` (the periodic Embree scene: ray queries), :mod:`.yarn` (the yarn
table), :mod:`.materials`, :mod:`.shading` (compiled: a ray at a yarn hit),
:mod:`.integrator` (:func:`trace`), :mod:`.estimate` (:func:`fabric_beta`: the plan-level
entry), :mod:`.pile` (the yarn's volume as its fibers' pile), :mod:`.meshes` (validation meshes).
"""

from simulate.woven.estimate import FELT_ROTATIONS, fabric_beta, table_photons, twist_of
from simulate.woven.integrator import STOP_REASONS, MCResult, trace
from simulate.woven.materials import FiberBRDFAtHit, FiberSurface, Lambert
from simulate.woven.meshes import flat_mesh, straight_yarn_mesh
from simulate.woven.yarn import YarnTable, table_halves, yarn_table

__all__ = [
    "YarnTable",
    "yarn_table",
    "table_halves",
    "Lambert",
    "FiberSurface",
    "FiberBRDFAtHit",
    "MCResult",
    "flat_mesh",
    "straight_yarn_mesh",
    "trace",
    "fabric_beta",
    "FELT_ROTATIONS",
    "table_photons",
    "twist_of",
    "STOP_REASONS",
]
