"""What the rough boundary's branch (:mod:`simulate.montecarlo.rough`) costs the smooth walks.

Run it in two checkouts side by side on an otherwise idle machine (``PYTHONPATH=CHECKOUT python -m
fabric_optics.bench.kernel_branch``): process CPU time, one thread, best of 3 after a warm-up, of the two
scoring-kernel users a smooth fiber runs -- a clear HG fiber's yarn table (cylinder, exit tally) at
20 000 photons per row, and 400 000 photons of the fiber BRDF's next-event route at one direction
pair. A benchmark, not a test: nothing asserts on the times (README, "The fiber BRDF").
"""

from __future__ import annotations

import time

import numpy as np

from simulate import fiber as F
from simulate import woven as W
from simulate.media.medium import HGMedium

FIBER = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.3, 10.0)


def _table() -> None:
    W.yarn_table(FIBER, [550.0], photons_per_row=20000, seed=3, threads=1, cache=False)


def _nee() -> None:
    F.volume_brdf(FIBER, np.array([[0.0, 0.6, 0.8]]), np.array([[0.0, -0.6, 0.8]]), [550.0],
                  max_photons=400000, target_rel_err=1e-6, seed=1, threads=1)


def main() -> None:
    for name, run in (("yarn table", _table), ("next-event route", _nee)):
        run()                                   # warm-up: compile or load the kernel
        best = float("inf")
        for _ in range(3):
            start = time.process_time()
            run()
            best = min(best, time.process_time() - start)
        print(f"{name}: best CPU {best:.3f} s")


if __name__ == "__main__":
    main()
