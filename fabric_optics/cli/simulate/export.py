"""``simulate export``: a fabric model tabulated as an RGL .bsdf file (Mitsuba 3, pbrt-v4 ``measured``).

The work is :func:`fabric_optics.api.export_bsdf`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fabric_optics import api
from fabric_optics.cli.common import (
    add_force,
    add_wavelengths,
    int_in,
    progress,
    refuse_existing,
)
from fabric_optics.cli.simulate.options import (
    run_settings_arguments,
)

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate export``."""
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("--method", choices=("classic", "summation", "mc"), required=True, help="fabric model")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.bsdf", help="RGL .bsdf file to write")
    add_force(p, "FILE.bsdf if it exists")
    p.add_argument("--rgb", action="store_true", help="linear sRGB (D65) values instead of spectra "
                   "(Mitsuba's RGB variants read only RGB files, its spectral variants only spectral ones)")
    add_wavelengths(p, "spectral bands")
    p.add_argument("--resolution", type=int_in(4, 256), default=64, help="values per axis of the warped grid, "
                   "4..256 (64)")
    p.add_argument("--incidences", type=int_in(2, 64), default=16, help="incidence nodes 0..90 deg, uniform in cos, "
                   "2..64 (16)")
    p.add_argument("--anisotropic", type=int, choices=(1, 2, 4), default=0, metavar="REDUCTION",
                   help="keep the anisotropy: incidence azimuths over 360/REDUCTION deg, the rest mirrored "
                        "(4: mirror symmetric in x and y, as warp/weft summation; 1: none)")
    p.add_argument("--azimuths", type=int_in(3, 64), default=5, help="incidence azimuths with --anisotropic (5)")
    p.add_argument("--check", type=int_in(0, 10**6), default=0, metavar="N",
                   help="measure the tabulation error at N random direction pairs (more model evaluations)")
    run_settings_arguments(p)


def run(args: argparse.Namespace) -> int:
    """Run ``simulate export``; return the exit status."""
    import time

    config = api.load_config(args.config)
    refuse_existing(args.out, args.force)
    started = time.perf_counter()
    result = api.export_bsdf(config, args.out, method=args.method, wavelengths_nm=args.wavelengths, rgb=args.rgb,
                             resolution=args.resolution, incidences=args.incidences,
                             target_rel_err=args.target_rel_err, seed=args.seed, threads=args.threads,
                             max_photons=args.max_photons, check_pairs=args.check, anisotropic=args.anisotropic,
                             azimuths=args.azimuths, force=args.force, progress=progress(args))
    err = result.error
    check = ("" if err is None else f"; tabulation error at {err['pairs']} pairs (theta <= 80 deg): "
             f"{err['rms']:.2%} rms, {err['p95']:.2%} p95, {err['max']:.2%} max")
    print(f"wrote {args.out} ({args.method}; {result.evaluations} model evaluations; "
          f"{time.perf_counter() - started:.1f} s{check})")
    return 0
