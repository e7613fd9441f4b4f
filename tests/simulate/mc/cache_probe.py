"""Run the Monte Carlo kernel variants of the slab and fiber routes once; print numba's cache statistics.

Run as a script in a fresh process (``NUMBA_CACHE_DIR`` set by the caller) by
``test_kernel_cache.py``: prints one JSON object mapping every numba dispatcher of
:mod:`simulate.montecarlo` (and :mod:`simulate.fresnel`, whose kernels it inlines) that was
compiled or loaded in this process to ``{"hits": ..., "misses": ...}``: the counts numba's
dispatcher keeps in ``stats`` (a miss is a compilation; a hit a load from the cache), and under
``"simulate"`` the file the package was imported from (the caller checks it ran the tree it meant).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import sys

import numpy as np
from numba.core.registry import CPUDispatcher


def _routes() -> None:
    from fabric_optics.cli.simulate import main
    from simulate.fiber import Fiber, point_outputs, range_outputs, volume_brdf
    from simulate.media.medium import HGMedium
    from simulate.montecarlo import run_cylinder, run_slab

    with contextlib.redirect_stdout(io.StringIO()):  # the slab command, exactly as a user runs it
        main(["slab", "--mua", "1", "--mus", "9", "--g", "0.75", "--n", "1.4", "--thickness", "1",
              "--photons", "1000", "--json"])
    run_slab(1.0, 9.0, g=0.75, n=1.4, thickness=1.0, photons=500, angular_bins=(3, 4))
    run_cylinder(0.1, 1.0, g=0.7, n=1.5, radius=1.0, photons=500)
    fiber = Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=1.0, mu_a=0.05, g=0.7), roughness=0.3,
                  cell_width_deg=20.0)
    w_in = np.array([[0.3, -0.2, math.sqrt(1 - 0.13)]])
    w_out = np.array([[0.1, 0.4, math.sqrt(1 - 0.17)]])
    ranged = range_outputs([0.5], [1.0], [-math.pi / 3], [math.pi / 3], fiber.half_width)  # a (2, 3)-grid cell
    for method, outputs in (("nee", point_outputs(w_out, fiber.half_width)), ("nee", ranged), ("beam", ranged),
                            ("bssrdf", ranged)):
        volume_brdf(fiber, w_in, None, [450.0, 550.0, 650.0], method=method, outputs=outputs, target_rel_err=0.5,
                    max_photons=2000, seed=1, bssrdf_bins=(2, 3))


def _stats() -> dict[str, object]:
    import simulate

    report: dict[str, object] = {"simulate": simulate.__file__}
    seen = set()
    for name, module in sorted(sys.modules.items()):
        if not (name.startswith("simulate.montecarlo") or name == "simulate.fresnel"):
            continue
        for attr, value in vars(module).items():
            # each dispatcher once, under the module that defines it
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == name and id(value) not in seen:
                seen.add(id(value))
                if value.signatures:
                    report[f"{name}.{attr}"] = {"hits": sum(value.stats.cache_hits.values()),
                                                "misses": sum(value.stats.cache_misses.values())}
    return report


if __name__ == "__main__":
    _routes()
    print(json.dumps(_stats()))
