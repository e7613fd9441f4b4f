r"""Monte Carlo ray tracing of a fibre assembly (a woven fabric or a felt): the virtual goniophotometer.

docs/physics.md section 6. The geometry is a :class:`simulate.geometry.mesh.FabricMesh` (a weave's
yarn tubes or a felt's fibres, :mod:`simulate.geometry`). Rays of a parallel beam from ``w_in``
strike the periodic cell uniformly (their targets are uniform over it) and are followed through the
yarn geometry (:class:`simulate.raytrace.scene.PeriodicScene`, Embree) until they leave upward (reflected),
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
fibers"; :func:`simulate.raytrace.estimate.yarn_model`): its surface term is reflected from the
top layer of fibers along the twisted fiber direction (``FiberSurface(surface="fibers")``: the
point of a fiber's cross-section the ray meets, shadowing and masking by the neighbours) and its
table is walked in the pile of its fibers (:mod:`.pile`), not in one fiber.

The ray reflects with probability ``p = a_s / (a_s + e_bar)`` (``e_bar`` the exit fraction
averaged over the ray's spectral weight) and enters otherwise, and is re-weighted by
``a_s / p`` or ``e(lambda) / (1 - p)``: the expected response is ``R_surf + R_vol`` as in the
fiber model, i.e. the same (slightly non-conservative, see docs) split of energy.

The decisions of mapping the fiber table onto a yarn are in :mod:`.yarn`; the estimators and
the accuracy control in :mod:`.integrator`.

Modules: :mod:`.scene` (the periodic Embree scene: ray queries), :mod:`.yarn` (the yarn
table), :mod:`.materials`, :mod:`.shading` (compiled: a ray at a yarn hit),
:mod:`.integrator` (:func:`trace`), :mod:`.estimate` (:func:`fabric_beta`: the plan-level
entry), :mod:`.pile` (the yarn's volume as its fibers' pile). A felt is traced like a weave, each
fibre a "yarn" walked with the fibre's own table (:mod:`simulate.geometry.felt`).
"""

from simulate.raytrace.estimate import FELT_ROTATIONS, fabric_beta, table_photons, twist_of
from simulate.raytrace.integrator import STOP_REASONS, MCResult, trace
from simulate.raytrace.materials import FiberBRDFAtHit, FiberSurface, Lambert
from simulate.raytrace.yarn import YarnTable, blend_halves, mix_tables, table_halves, yarn_table

__all__ = [
    "YarnTable",
    "yarn_table",
    "table_halves",
    "blend_halves",
    "mix_tables",
    "Lambert",
    "FiberSurface",
    "FiberBRDFAtHit",
    "MCResult",
    "trace",
    "fabric_beta",
    "FELT_ROTATIONS",
    "table_photons",
    "twist_of",
    "STOP_REASONS",
]
