"""``simulate fabric``: a fabric model's radiance-coefficient dataset at a plan's geometries.

The output replaces ``--out`` as one folder (:mod:`simulate.outdir`); the work is :func:`fabric_optics.api.simulate`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fabric_optics import api
from fabric_optics.cli.common import (
    UsageError,
    add_force,
    add_plan,
    progress,
)
from fabric_optics.cli.simulate.options import (
    check_cost,
    nonneg_float,
    run_settings_arguments,
)
from gonio.data.outputs import prepare_folder

__all__ = ["add_arguments", "run"]


def _prepare_fabric_out(out: Path, force: bool) -> None:
    """The output rule (:func:`gonio.data.outputs.prepare_folder`) for ``simulate fabric``.

    Its output replaces ``out`` as one folder (:mod:`simulate.outdir`): a killed run's folders are cleaned
    first, and a previous output holding anything besides the dataset's files is refused (the swap would
    delete it).
    """
    from gonio.data.dataset import CSV_NAME, META_NAME, remove_stale_temp_files
    from simulate.outdir import recover
    from simulate.virtual import is_previous_output

    try:
        recover(out)
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot clean up after an earlier killed run ({exc.strerror})") from None
    prepare_folder(out, writer="simulate fabric", force=force, previous=is_previous_output, exclusive=True)
    try:
        remove_stale_temp_files(out)         # a killed per-file write of an older version
        others = sorted(e.name for e in out.iterdir() if e.name not in (CSV_NAME, META_NAME))
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot read the directory ({exc.strerror})") from None
    if others:
        raise UsageError(f"--out {out}: holds {others[0]!r} besides a dataset; the new output replaces the "
                          f"whole directory, so move that elsewhere or choose a new directory")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate fabric``."""
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("--method", choices=("classic", "summation", "mc", "auto"), required=True,
                   help="fabric model: summation over warp and weft, the classic Lambert + Cook-Torrance, "
                        "mc (Monte Carlo ray tracing of the woven micro-element of the config's [weave]), or "
                        "auto (per geometry the cheapest whose error against mc is within the target)")
    p.add_argument("--max-seconds", type=nonneg_float, default=0.0, dest="max_seconds",
                   help="mc: time budget per incidence in seconds (0 = none); the output says which stop ended it")
    p.add_argument("--out", type=Path, required=True, help="output dataset directory (radiance.csv, meta.json)")
    add_force(p, "a previous `simulate fabric` output in --out (a folder holding anything else is never replaced: "
                 "the output replaces the whole folder)")
    add_plan(p, what="whose geometries and wavelengths are simulated")
    p.add_argument("--measurable-only", action="store_true", dest="measurable_only",
                   help="skip the plan's beam-blocked geometries as the measurement does "
                        "(default: simulate them; the normal/normal value is the normalisation point)")
    run_settings_arguments(p)


def run(args: argparse.Namespace) -> int:
    """Run ``simulate fabric``; return the exit status."""
    from simulate.outdir import OutputError, write_dataset_dir

    config = api.load_config(args.config)
    try:
        plan = api.load_plan(args.plan)
    except api.InputError as exc:
        raise UsageError(f"--plan: {exc}") from None
    from simulate.config import ConfigError
    from simulate.products import check_blend
    try:
        check_blend(config, args.method)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    check_cost("fabric", config, plan.wavelengths_nm, args.target_rel_err, args.max_photons)
    _prepare_fabric_out(args.out, args.force)
    dataset = api.simulate(config, plan, args.method, target_rel_err=args.target_rel_err, seed=args.seed,
                           threads=args.threads, max_photons=args.max_photons,
                           measurable_only=args.measurable_only, progress=progress(args),
                           max_seconds=args.max_seconds)
    try:
        write_dataset_dir(dataset, args.out)
    except OutputError as exc:
        raise UsageError(str(exc)) from None
    prov = dataset.meta["provenance"]
    err_text = f"{prov['rel_err']:.2%} (rms of u / each direction's spectral peak)"
    print(f"wrote {args.out} ({len(dataset)} rows: {prov['geometries']} geometries x "
          f"{len(dataset.wavelengths_nm)} wavelengths; {args.method}; relative error {err_text}; "
          f"{prov['seconds']:.1f} s)")
    return 0
