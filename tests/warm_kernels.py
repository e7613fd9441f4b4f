"""Compile the cached numba kernels the suite uses into numba's on-disk cache, beside the first tests.

Started by the root ``conftest.py`` in the xdist controller (``-n 2`` or more) as ``python warm_kernels.py
GROUP``, one process per group, the groups at once and beside the workers: each group runs tiny versions of
the routes whose kernels it compiles, while the workers run the tests that need no kernel (the suite's first
files). A kernel is compiled by one process only: :mod:`simulate.kernelcache` takes a per-kernel lock around
numba's compilation, so a worker or the other group that needs a kernel being compiled waits for it and loads
it from the cache. When the user's kernel cache already holds them (any clone of the same sources filled it)
the groups only load. Nothing is written but numba's cache: the table cache is off and the outputs go to a
temporary directory. The script prints the seconds it took.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
import tempfile
import time
from pathlib import Path


def _monte_carlo(tmp: Path) -> None:
    """The slab command, the slab and cylinder routes and the fiber's volume BRDF methods: the routes of the
    kernel-cache probe (``simulate/mc/cache_probe.py``), run from there."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("cache_probe", Path(__file__).parent / "simulate" / "mc" /
                                                  "cache_probe.py")
    assert spec is not None and spec.loader is not None
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    probe._routes()


def _yarn_table(tmp: Path) -> None:
    """The fiber Monte Carlo kernels both groups use: a yarn's exit table (rows of the white walk), tiny."""
    from simulate import raytrace as W
    from simulate.fiber import Fiber
    from simulate.media.medium import HGMedium

    fiber = Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), roughness=0.3,
                  cell_width_deg=10.0)
    W.yarn_table(fiber, [550.0], photons_per_row=50, seed=1, threads=1, cache=False)


def _structure(tmp: Path) -> None:
    """The structured walk of the fit (green felt, one wavelength) and a fiber's exit table and interior closure."""
    import numpy as np

    from simulate.config import load_config
    from simulate.fabric import interior as IN
    from simulate.fiber import Fiber
    from simulate.fiber import farfield as FF
    from simulate.fiber.absorption import absorption_nodes
    from simulate.media.medium import HGMedium
    from simulate.structwalk import walk as fit_structure

    wl = np.array([550.0])
    config = load_config("green-felt")
    fit_structure.walk_structure(config.fiber(wl), config, wl, absorption_nodes(1.0, 3), target_rel_err=0.3, seed=1,
                                 threads=1, cache=False)
    fiber = Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=0.4, mu_a=0.0, g=0.5), roughness=0.3,
                  cell_width_deg=10)
    table = FF.exit_table(fiber, [550.0], w_t=[0.0, 0.9], photons_per_row=200, seed=1, threads=1)
    inner = IN.interior(table, fiber, 200)
    IN.layer_energy(table, fiber, np.array([math.sin(0.4), 0.0, math.cos(0.4)]), inner.classes)


WOVEN_CONFIG = """
seed = 4
[fiber]
radius_um = 10.0
n_host = 1.5
[medium]
mu_s = 0.8
mu_a = 0.01
g = 0.5
[surface]
rms_slope = 0.35
[weave]
preset = "plain"
spacing_um = 300
width_um = 250
height_um = 100
points_per_span = 6
sides = 12
"""

PLAN = """
[sample]
name = "tiny"
[wavelengths]
list_nm = [550]
[geometry]
incidence_deg = [0, 45]
in_plane_deg = [-30, 0, 30]
"""


def _woven_files(tmp: Path) -> tuple[Path, Path, Path]:
    """The tiny plain weave's config, the same with a [structure] section, and the plan, written into ``tmp``."""
    cfg, structured, plan = tmp / "woven.toml", tmp / "structured.toml", tmp / "plan.toml"
    cfg.write_text(WOVEN_CONFIG)
    structured.write_text(WOVEN_CONFIG + "[structure]\nwarp_twist_deg = 20\n")
    plan.write_text(PLAN)
    return cfg, structured, plan


def _woven_summation(tmp: Path) -> None:
    """The structured summation of a tiny plain weave, through the command line."""
    from fabric_optics.cli.simulate import main

    _, structured, plan = _woven_files(tmp)
    with contextlib.redirect_stdout(io.StringIO()):
        main(["fabric", str(structured), "--method", "summation", "--plan", str(plan), "--out", str(tmp / "sum"),
              "--target-rel-err", "0.3", "--no-progress"])


def _woven_mc(tmp: Path) -> None:
    """The woven Monte Carlo of a tiny plain weave, through the command line (its yarn table walks the fiber)."""
    from fabric_optics.cli.simulate import main

    cfg, _, plan = _woven_files(tmp)
    with contextlib.redirect_stdout(io.StringIO()):
        main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(tmp / "mc"),
              "--target-rel-err", "0.3", "--no-progress"])


#: the groups, one process each: the Monte Carlo kernels and the fit's walk; the woven scene and shading (its yarn
#: table walks the fiber with the Monte Carlo group's kernels: whichever group meets one first compiles it)
GROUPS = {"monte-carlo": (_yarn_table, _monte_carlo, _structure),
          "fabric": (_woven_mc, _woven_summation)}


def main(argv: list[str]) -> int:
    (group,) = argv
    start = time.perf_counter()
    os.environ["FABRIC_OPTICS_NO_CACHE"] = "1"
    with tempfile.TemporaryDirectory(prefix="warm-kernels-") as tmp:
        for route in GROUPS[group]:
            route(Path(tmp))
    print(f"{group}: {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
