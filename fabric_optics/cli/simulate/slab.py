"""``simulate slab``: diffuse reflectance and total transmittance of a slab by Monte Carlo.

``--json`` prints one object (:meth:`simulate.montecarlo.SlabResult.as_dict`, non-finite values as null);
the garbage collector is off during the run: it makes no cyclic garbage, and numba's registries, loaded
by the first kernel call, would make each collection slow.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
from typing import Any

from fabric_optics.cli.common import (
    add_threads,
    int_in,
)
from fabric_optics.cli.simulate.options import (
    angle_deg,
    g_float,
    nonneg_float,
    pos_float,
)

__all__ = ["add_arguments", "run"]


def _json_safe(obj: Any) -> Any:
    """Replace non-finite floats by None (JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate slab``."""
    p.add_argument("--mua", type=nonneg_float, required=True, help="absorption coefficient mu_a (1/length)")
    p.add_argument("--mus", type=nonneg_float, required=True, help="scattering coefficient mu_s (1/length)")
    p.add_argument("--g", type=g_float, default=0.0, help="Henyey-Greenstein anisotropy g (default 0)")
    p.add_argument("--n", type=pos_float, default=1.0, help="refractive index of the slab (outside 1; default 1)")
    p.add_argument("--thickness", type=pos_float, required=True, help="slab thickness d (same length unit)")
    p.add_argument("--photons", type=int_in(1, 10**12), default=1_000_000, help="photons (default 1e6)")
    p.add_argument("--seed", type=int_in(0, 2**63 - 1), default=0, metavar="N", help="random seed (default: 0)")
    add_threads(p)
    p.add_argument("--theta-i", type=angle_deg, default=0.0, dest="theta_i", help="incidence angle in degrees [0, 90)")
    p.add_argument("--max-events", type=int_in(1, 2**52), default=None, help="event cap per photon (a guard)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    """Run ``simulate slab``; return the exit status."""
    collecting = gc.isenabled()
    gc.disable()  # one run that makes no cyclic garbage; its first kernel call loads numba's registries (main)
    try:
        from simulate.montecarlo import DEFAULT_MAX_EVENTS, run_slab

        result = run_slab(
            args.mua, args.mus, g=args.g, n=args.n, thickness=args.thickness, photons=args.photons,
            seed=args.seed, theta_i_deg=args.theta_i, threads=args.threads or None,
            max_events=args.max_events or DEFAULT_MAX_EVENTS,
        )
    finally:
        if collecting:
            gc.enable()
    if args.json:
        print(json.dumps(_json_safe(result.as_dict())))
    else:
        print(f"Rd  = {result.Rd:.6f} +- {result.u_Rd:.6f}   (diffuse reflectance, without Rsp = {result.Rsp:.6f})")
        print(f"Tt  = {result.Tt:.6f} +- {result.u_Tt:.6f}   (total transmittance; unscattered {result.Tu:.6f})")
        print(f"A   = {result.absorbed:.6f}   capped photons: {result.capped}")
        print(
            f"{result.photons} photons in {result.seconds:.3f} s "
            f"({result.photons / max(result.seconds, 1e-12) / 1e6:.2f} M photons/s, "
            f"{result.events_per_photon:.2f} events/photon)"
        )
    return 0
