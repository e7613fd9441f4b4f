"""Fabric models over the fiber BRDF: the summation and the classic model, the structured summation, the ``auto`` choice.

Modules: :mod:`.summation` (fabric frames, the summation of the fiber BRDF over the two
families), :mod:`.classic` (Cook-Torrance + Lambert), :mod:`.structure` (the summation over the fabric's visible fiber layers; :mod:`.fiberlayer`,
:mod:`.interior` and :mod:`.structtable` its layer, inner layers and table), :mod:`.auto` (the ``--method auto`` choice from the method-errors study).
The geometry of a woven micro-element and of a felt is :mod:`simulate.geometry`; their Monte Carlo
ray tracer is :mod:`simulate.raytrace`.
"""

from simulate.fabric.classic import classic_beta
from simulate.fabric.summation import (
    M_WARP,
    M_WEFT,
    SUMMATION_GRAZING_LIMIT_DEG,
    FabricError,
    FiberPairs,
    canonical_pairs,
    directions_deg,
    fiber_frame_pairs,
    hemisphere_grid,
    rotation_z,
    summation_albedo,
    summation_beta,
    summation_from_table,
    summation_hemispherical_albedo,
)

__all__ = [
    "classic_beta",
    "M_WARP",
    "M_WEFT",
    "SUMMATION_GRAZING_LIMIT_DEG",
    "FabricError",
    "FiberPairs",
    "canonical_pairs",
    "directions_deg",
    "fiber_frame_pairs",
    "hemisphere_grid",
    "rotation_z",
    "summation_albedo",
    "summation_beta",
    "summation_from_table",
    "summation_hemispherical_albedo",
]
