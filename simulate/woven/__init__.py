"""The woven fabric's Monte Carlo (``simulate fabric --method mc``): rays through the tiled micro-element.

Modules: :mod:`.scene` (the periodic Embree scene: ray queries), :mod:`.integrator` (yarn
table, materials, shading, the integrator and the plan-level estimate).
"""

from simulate.woven.integrator import (
    STOP_REASONS,
    FiberBRDFAtHit,
    FiberSurface,
    Lambert,
    MCResult,
    YarnTable,
    fabric_beta,
    flat_mesh,
    straight_yarn_mesh,
    trace,
    yarn_table,
)

__all__ = [
    "YarnTable",
    "yarn_table",
    "Lambert",
    "FiberSurface",
    "FiberBRDFAtHit",
    "MCResult",
    "flat_mesh",
    "straight_yarn_mesh",
    "trace",
    "fabric_beta",
    "STOP_REASONS",
]
