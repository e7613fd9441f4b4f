"""Monte Carlo photon transport (docs/physics.md section 3): compiled kernel, geometries, tallies.

Public API: :func:`run_slab`, :func:`run_cylinder` and their result classes. The compiled
pieces (:mod:`.kernel`, :mod:`.geometry`, :mod:`.tallies`, :mod:`.rng`) are implementation
details that other estimators extend.
"""

from simulate.montecarlo.numba_start import preload_blas_check

preload_blas_check()  # before any kernel runs: numba's BLAS check without scipy.linalg

from simulate.montecarlo.cylinder import run_cylinder  # noqa: E402
from simulate.montecarlo.results import (  # noqa: E402
    CylinderAngular,
    CylinderResult,
    EnergyBalance,
    SlabAngular,
    SlabResult,
)
from simulate.montecarlo.slab import run_slab  # noqa: E402
from simulate.montecarlo.transport import DEFAULT_BATCH_SIZE, DEFAULT_MAX_EVENTS, ParameterError  # noqa: E402

__all__ = [
    "DEFAULT_BATCH_SIZE",
    "DEFAULT_MAX_EVENTS",
    "CylinderAngular",
    "CylinderResult",
    "EnergyBalance",
    "ParameterError",
    "SlabAngular",
    "SlabResult",
    "run_cylinder",
    "run_slab",
]
