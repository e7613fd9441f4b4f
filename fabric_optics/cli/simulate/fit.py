"""The ``simulate`` console script (docs/architecture.md, command line contract).

Subcommands are registered in :data:`PROGRAM` (:mod:`fabric_optics.cli.registry`): each is a
:class:`~fabric_optics.cli.registry.Command` of two functions, ``add_arguments(parser)`` and
``run(args) -> int``; a new subcommand is one more entry. Exit codes: 0 success, 1 failed check, 2 usage or input error
(one line on stderr naming the flag, no traceback), 3 ``simulate fit`` whose fitted colour is left off
(``fabric_optics.fitting.outputs.EXIT_COLOUR_OFF``: outputs written, fit.json ``verdict.passed`` false).

``simulate slab --mua X --mus X --g X --n X --thickness X --photons N [--seed N] [--threads N] --json``
    prints ONE JSON object ``{"Rd", "Tt", "u_Rd", "u_Tt", "photons", "seconds",
    "events_per_photon", ...}``; ``Rd`` excludes the specular surface reflection ``Rsp``.
``simulate bench --out DIR [--quick]``
    kernel benchmark: DIR/bench.json, DIR/bench.png and a markdown table on stdout.
``simulate fabric CONFIG --method classic|summation|mc|auto --out DIR [--plan PLAN] [--target-rel-err X] [--seed N] [--threads N]``
    a radiance-coefficient dataset at the plan's geometries (:mod:`simulate.virtual`); CONFIG
    is a TOML path or a preset name (``red-cotton``), PLAN likewise (default ``red-cotton``). A
    non-empty DIR is replaced only with ``--force`` and only if it holds a previous ``simulate fabric``
    output and nothing else, as one folder (:mod:`simulate.outdir`: a kill or a full disk leaves the old output).
    Every run-making command (fabric, fiber, fit, sweep) first estimates its cost
    (:mod:`simulate.budget`): refused beyond a day, announced beyond ten minutes. ``--threads 0``
    means all threads numba allows, as ``threads = 0`` in a config.
``simulate fiber CONFIG --out DIR [--route nee|beam|bssrdf] [--step-deg 30] [--phi-step-deg 45]``
    the fiber BRDF table (:mod:`simulate.fiber.tables`: npz + JSON sidecar).
``simulate fit CONFIG MEASURED --free NAME[=LOW:HIGH],... --out DIR [--method summation|classic|mc]``
    fits config parameters to a measurement (:mod:`fabric_optics.fitting.search`, ``mc``: :mod:`fabric_optics.fitting.spacemapping`): fitted.toml,
    datasets, report.
``simulate sweep CONFIG [MEASURED] --param NAME=v1,v2,... --out DIR [--scheduler tls://HOST:PORT [--tls-ca-file F --tls-cert F --tls-key F]] [--workers N]``
    a parameter study on dask.distributed (:mod:`fabric_optics.sweep.runner`): one dataset per point, summary.csv;
    exit 1 when a task still fails after its retries (the others are kept).

The names, syntax and defaults of the options are those of :mod:`fabric_optics.cli.common`;
the work is done by :mod:`fabric_optics.api` where it has the function (fabric, fit, export).
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import math
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

from fabric_optics import api, validate
from fabric_optics.cli import common, registry
from fabric_optics.cli.common import (
    UsageError,
    add_force,
    add_no_progress,
    add_plan,
    add_seed,
    add_target_rel_err,
    add_threads,
    add_wavelengths,
    refuse_existing,
)
from gonio.data.outputs import prepare_folder
from simulate.montecarlo import ParameterError

__all__ = ["PROGRAM", "main", "build_parser"]

log = logging.getLogger("simulate")

_UsageError = UsageError


# ------------------------------------------------------------------------------------------
# argument types (their messages name the flag through argparse: "argument --mua: ...")
# ------------------------------------------------------------------------------------------


_float = common.finite_number


def _nonneg_float(text: str) -> float:
    value = _float(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def _pos_float(text: str) -> float:
    value = _float(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _g_float(text: str) -> float:
    value = _float(text)
    if not -1.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"anisotropy must be in (-1, 1), got {text!r}")
    return value


def _angle_deg(text: str) -> float:
    value = _float(text)
    if not 0.0 <= value < 90.0:
        hint = " (90 is grazing incidence: no light enters)" if value == 90.0 else ""
        raise argparse.ArgumentTypeError(f"incidence angle must be in [0, 90) degrees, got {text!r}{hint}")
    return value


_int_in = common.int_in
MAX_SEED = common.MAX_SEED


def _json_safe(obj: Any) -> Any:
    """Replace non-finite floats by None (JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


# ------------------------------------------------------------------------------------------
# simulate slab
# ------------------------------------------------------------------------------------------


def _slab_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mua", type=_nonneg_float, required=True, help="absorption coefficient mu_a (1/length)")
    p.add_argument("--mus", type=_nonneg_float, required=True, help="scattering coefficient mu_s (1/length)")
    p.add_argument("--g", type=_g_float, default=0.0, help="Henyey-Greenstein anisotropy g (default 0)")
    p.add_argument("--n", type=_pos_float, default=1.0, help="refractive index of the slab (outside 1; default 1)")
    p.add_argument("--thickness", type=_pos_float, required=True, help="slab thickness d (same length unit)")
    p.add_argument("--photons", type=_int_in(1, 10**12), default=1_000_000, help="photons (default 1e6)")
    p.add_argument("--seed", type=_int_in(0, 2**63 - 1), default=0, metavar="N", help="random seed (default: 0)")
    add_threads(p)
    p.add_argument("--theta-i", type=_angle_deg, default=0.0, dest="theta_i", help="incidence angle in degrees [0, 90)")
    p.add_argument("--max-events", type=_int_in(1, 2**52), default=None, help="event cap per photon (a guard)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _slab_run(args: argparse.Namespace) -> int:
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


# ------------------------------------------------------------------------------------------
# simulate bench
# ------------------------------------------------------------------------------------------


def _bench_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="output directory (bench.json, bench.png)")
    add_force(p)
    p.add_argument("--quick", action="store_true", help="smoke test: small runs, a few seconds")
    from fabric_optics.bench.studies import STUDIES

    p.add_argument("--study", choices=sorted(STUDIES), help="run this documented study instead of the benchmark: "
                   + "; ".join(f"{k}: {v[0]}" for k, v in sorted(STUDIES.items())) + " (OUT/NAME.json)")


def _bench_run(args: argparse.Namespace) -> int:
    from fabric_optics.bench.suite import markdown_table, run_bench

    out: Path = args.out
    prepare_folder(out, writer="simulate bench", force=args.force)
    if args.study:
        from fabric_optics.bench.studies import run_study

        print("\n".join(run_study(args.study, out, quick=args.quick)) + f"\n\nwrote {out / (args.study + '.json')}")
        return 0
    report = run_bench(out, quick=args.quick)
    print(markdown_table(report))
    print(f"\nwrote {out / 'bench.json'} and {out / 'bench.png'}")
    return 0


# ------------------------------------------------------------------------------------------
# simulate fabric / simulate fiber
# ------------------------------------------------------------------------------------------


_rel_err = common.rel_err_arg
_threads_arg = common.threads_arg


def _run_settings_arguments(p: argparse.ArgumentParser) -> None:
    add_target_rel_err(p, "of the fiber Monte Carlo, relative to each curve's spectral peak")
    p.add_argument("--max-photons", type=_int_in(1, 10**15), default=None, dest="max_photons", metavar="N",
                   help="photon budget (default: the config's; none)")
    add_seed(p)
    add_threads(p)
    add_no_progress(p)


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
        raise _UsageError(f"--out {out}: cannot clean up after an earlier killed run ({exc.strerror})") from None
    prepare_folder(out, writer="simulate fabric", force=force, previous=is_previous_output, exclusive=True)
    try:
        remove_stale_temp_files(out)         # a killed per-file write of an older version
        others = sorted(e.name for e in out.iterdir() if e.name not in (CSV_NAME, META_NAME))
    except OSError as exc:
        raise _UsageError(f"--out {out}: cannot read the directory ({exc.strerror})") from None
    if others:
        raise _UsageError(f"--out {out}: holds {others[0]!r} besides a dataset; the new output replaces the "
                          f"whole directory, so move that elsewhere or choose a new directory")


def _is_fiber_output(out: Path) -> bool:
    from simulate.fiber.tables import FORMAT, JSON_NAME

    try:
        meta = json.loads((out / JSON_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("format") == FORMAT


def _check_cost(command: str, config: Any, wavelengths: Any, target: float | None, max_photons: int | None,
                runs: int = 1) -> None:
    """Refuse a run estimated beyond a day, warn beyond ten minutes (:mod:`simulate.budget`)."""
    from fabric_optics.errors import InputError

    try:        # the estimate the Python interface applies too (fabric_optics.validate.cost)
        warning = validate.cost(config, wavelengths, target, max_photons, runs=runs)
    except InputError as exc:
        raise _UsageError(str(exc.__cause__ or exc)) from None
    if warning:
        print(f"simulate {command}: warning: {warning}", file=sys.stderr)


def _write_failed(out: Path, exc: OSError) -> str:
    """One line for an output that could not be written (a full disk): the file and the reason."""
    return f"{exc.filename or out}: cannot write ({exc.strerror or exc})"


_progress = common.progress


def _fabric_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("--method", choices=("classic", "summation", "mc", "auto"), required=True,
                   help="fabric model: summation over warp and weft, the classic Lambert + Cook-Torrance, "
                        "mc (Monte Carlo ray tracing of the woven micro-element of the config's [weave]), or "
                        "auto (per geometry the cheapest whose error against mc is within the target)")
    p.add_argument("--max-seconds", type=_nonneg_float, default=0.0, dest="max_seconds",
                   help="mc: time budget per incidence in seconds (0 = none); the output says which stop ended it")
    p.add_argument("--out", type=Path, required=True, help="output dataset directory (radiance.csv, meta.json)")
    add_force(p, "a previous `simulate fabric` output in --out (a folder holding anything else is never replaced: "
                 "the output replaces the whole folder)")
    add_plan(p, what="whose geometries and wavelengths are simulated")
    p.add_argument("--measurable-only", action="store_true", dest="measurable_only",
                   help="skip the plan's beam-blocked geometries as the measurement does "
                        "(default: simulate them; the normal/normal value is the normalisation point)")
    _run_settings_arguments(p)


def _fabric_run(args: argparse.Namespace) -> int:
    from simulate.outdir import OutputError, write_dataset_dir

    config = api.load_config(args.config)
    try:
        plan = api.load_plan(args.plan)
    except api.InputError as exc:
        raise _UsageError(f"--plan: {exc}") from None
    from simulate.config import ConfigError
    from simulate.products import check_blend
    try:
        check_blend(config, args.method)
    except ConfigError as exc:
        raise _UsageError(str(exc)) from None
    _check_cost("fabric", config, plan.wavelengths_nm, args.target_rel_err, args.max_photons)
    _prepare_fabric_out(args.out, args.force)
    dataset = api.simulate(config, plan, args.method, target_rel_err=args.target_rel_err, seed=args.seed,
                           threads=args.threads, max_photons=args.max_photons,
                           measurable_only=args.measurable_only, progress=_progress(args),
                           max_seconds=args.max_seconds)
    try:
        write_dataset_dir(dataset, args.out)
    except OutputError as exc:
        raise _UsageError(str(exc)) from None
    prov = dataset.meta["provenance"]
    err_text = f"{prov['rel_err']:.2%} (rms of u / each direction's spectral peak)"
    print(f"wrote {args.out} ({len(dataset)} rows: {prov['geometries']} geometries x "
          f"{len(dataset.wavelengths_nm)} wavelengths; {args.method}; relative error {err_text}; "
          f"{prov['seconds']:.1f} s)")
    return 0


def _fiber_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("--out", type=Path, required=True, help="output directory (fiber-table.npz, fiber-table.json)")
    add_force(p)
    p.add_argument("--route", choices=("nee", "beam", "bssrdf"), default=None,
                   help="fiber route of the Monte Carlo (default: the config's)")
    p.add_argument("--step-deg", type=_pos_float, default=30.0, dest="step_deg",
                   help="polar grid step in degrees, dividing 90 (default 30)")
    p.add_argument("--phi-step-deg", type=_pos_float, default=45.0, dest="phi_step_deg",
                   help="azimuth grid step in degrees, dividing 90 (default 45)")
    _run_settings_arguments(p)


#: Bound on a fiber table's size, direction pairs x wavelengths (``simulate fiber``): 10 million
#: values, about 0.6 GiB for the table's five arrays and the Monte Carlo tallies behind them (~64
#: bytes a value). A 5 deg x 10 deg grid at 33 wavelengths has 7.7 million; the default 432 pairs x 33.
MAX_TABLE_VALUES = 10_000_000


def _check_table_size(step_deg: float, phi_step_deg: float, n_wavelengths: int) -> None:
    """Refuse a table grid over :data:`MAX_TABLE_VALUES` from its step sizes alone (nothing allocated)."""
    pairs = (180.0 / step_deg) * (90.0 / phi_step_deg + 1) * (90.0 / step_deg) * (360.0 / phi_step_deg)
    values = pairs * n_wavelengths
    if values > MAX_TABLE_VALUES:
        raise _UsageError(f"--step-deg {step_deg:g} / --phi-step-deg {phi_step_deg:g}: the table would have "
                          f"{pairs:,.0f} direction pairs x {n_wavelengths} wavelengths = {values:.3g} values "
                          f"(about {values * 64 / 2**30:,.3g} GiB); at most {MAX_TABLE_VALUES:,} (about "
                          f"{MAX_TABLE_VALUES * 64 / 2**30:.1f} GiB): use a coarser step")


def _fiber_run(args: argparse.Namespace) -> int:
    import numpy as np

    from simulate.fiber.tables import TableGrid, fiber_table, is_fiber_table_dir, write_fiber_table

    config = api.load_config(args.config)
    wavelengths = np.asarray(config.wavelengths_nm, float)
    _check_table_size(args.step_deg, args.phi_step_deg, wavelengths.size)
    try:
        grid = TableGrid(args.step_deg, args.phi_step_deg)
    except ValueError as exc:
        raise _UsageError(f"--step-deg/--phi-step-deg: {exc}") from None
    target = config.target_rel_err if args.target_rel_err is None else args.target_rel_err
    from simulate.config import ConfigError, require_single_population
    try:
        require_single_population(config, "simulate fiber")
    except ConfigError as exc:
        raise _UsageError(str(exc)) from None
    _check_cost("fiber", config, wavelengths, target, args.max_photons)
    prepare_folder(args.out, writer="simulate fiber", force=args.force, previous=is_fiber_table_dir)
    arrays, sidecar = fiber_table(
        config.fiber(wavelengths), wavelengths, grid, method=args.route or config.route,
        target_rel_err=target, seed=config.seed if args.seed is None else args.seed,
        threads=args.threads or None,
        max_photons=config.max_photons if args.max_photons is None else args.max_photons,
        progress=_progress(args), config_provenance=config.provenance())
    try:
        write_fiber_table(args.out, arrays, sidecar)
    except OSError as exc:
        raise _UsageError(_write_failed(args.out, exc)) from None
    prov = sidecar["provenance"]
    print(f"wrote {args.out} ({math.prod(grid.shape)} direction pairs x {arrays['wavelength_nm'].size} "
          f"wavelengths; {prov['method']}; {prov['photons']} photons in {prov['seconds']:.1f} s)")
    return 0


# ------------------------------------------------------------------------------------------
# simulate fit
# ------------------------------------------------------------------------------------------


def _fit_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="start config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("measured", metavar="MEASURED", type=Path, help="measured radiance-coefficient dataset (folder)")
    p.add_argument("--free", action="append", required=True, metavar="NAME[=LOW:HIGH],...",
                   help="free config parameters (dotted paths or aliases volume_fraction, radius, rms_slope, "
                        "dye, dye-peaks; a blend's populations.NAME.dye, populations.NAME.share; repeatable or "
                        "comma-separated); see fabric_optics.fitting.spec")
    p.add_argument("--out", type=Path, required=True,
                   help="output directory (fitted.toml, initial/, fitted/, report/, fit.json, fit-state.json)")
    add_force(p, "an existing --out (start the fit afresh there; --resume continues it instead)")
    from fabric_optics.fitting.methods import DEFAULT_METHOD, METHODS

    p.add_argument("--method", choices=tuple(METHODS), default=DEFAULT_METHOD,
                   help=f"fabric model to fit (default {DEFAULT_METHOD}); "
                        + "; ".join(f"{m.name}: {m.summary}" for m in METHODS.values())
                        + " (from CONFIG, e.g. a summation fit's fitted.toml)")
    p.add_argument("--colour-weight", type=_nonneg_float, default=1.0, dest="colour_weight",
                   help="weight w_c of (dh^2 + ds^2) beside NRMSE^2 in the objective (default 1)")
    p.add_argument("--no-colour-hold", action="store_false", dest="colour_hold",
                   help="classic and summation fits: do not hold the colour within the tolerance (the objective's "
                        "colour hold, beyond 0.7 of |dh| 0.02 turn, |ds| 0.03); the colour then weighs by "
                        "--colour-weight only")
    p.add_argument("--absolute", action="store_true",
                   help="an absolutely calibrated measurement: fit its level too, (ln k_Y)^2 added to the objective "
                        "(k_Y: the normalisation's luminance factor at the colour geometry, 1 at the measured level)")
    p.add_argument("--max-evaluations", type=_int_in(1, 10**6), default=None, dest="max_evaluations", metavar="N",
                   help="summation and classic fits: model evaluations of the search in all, steps and Jacobian "
                        f"columns of every start (default {METHODS['classic'].default_budget}; the uncertainty "
                        "propagation afterwards is counted apart)")
    p.add_argument("--max-runs", type=_int_in(1, 10**4), default=None, dest="max_runs", metavar="N",
                   help=f"--method mc: Monte Carlo runs, the start's included (default {METHODS['mc'].default_budget}, "
                        "at least 2)")
    p.add_argument("--mc-trend", action="append", default=None, dest="mc_trend", metavar="NAME,...",
                   help="--method mc: free parameters whose trend the surrogate takes from Monte Carlo runs (one more "
                        "run per parameter and step) instead of the summation -- where the two models' trends "
                        "disagree; the boundary's slopes for transmitted light always are (see fabric_optics.fitting.spacemapping)")
    p.add_argument("--mc-retrace", action="store_true", dest="mc_retrace",
                   help="--method mc: trace every Monte Carlo run (by default, with only dye parameters free, a run "
                        "after a traced one re-weights its rays to the new dye while that is as accurate as a trace)")
    p.add_argument("--starts", type=_int_in(1, 1000), default=1,
                   help="least-squares starts: the config's values plus Latin-hypercube points (default 1)")
    add_wavelengths(p, "model wavelengths for an RGB measurement")
    p.add_argument("--dye", choices=("config", "knots"), default="config",
                   help="knots: replace the config's dye by 8 knots of log10 absorption (any colour; free them "
                        "with --free dye; a blend: each population its own knots), started from the measured colour "
                        "(default: the config's dye)")
    p.add_argument("--resume", action="store_true", help="continue from DIR/fit-state.json (last accepted point; "
                   "--method mc: from DIR/mc-state.json, the finished Monte Carlo runs)")
    add_target_rel_err(p, "of the first Monte Carlo walk; later walks reuse its photons")
    add_seed(p)
    add_threads(p)
    add_no_progress(p)


def _fit_left_behind(out: Path, walk_parts_before: int = 0) -> str:
    """What an interrupted fit left in ``out`` that ``--resume`` can use (only what exists).

    The structured walk's parts it stored in the table cache (``walk_parts_before``: the process's count when the
    fit began).
    """
    from fabric_optics.fitting.state import STATE_NAME, WALKS_DIR

    if (out / STATE_NAME).is_file():
        return f"the last accepted point is in {out / STATE_NAME} (continue with --resume)"
    walks = out / WALKS_DIR
    runs = len(list(walks.glob("*.npz"))) if walks.is_dir() else 0
    if runs:
        return (f"no point was evaluated yet; {runs} finished Monte Carlo runs are in {walks} "
                "(--resume continues the walk from them)")
    from simulate.fiber import tablecache

    parts = tablecache.stored("structwalk") - walk_parts_before
    if parts > 0:   # the structured walk keeps each finished (half, chunk) part in the table cache, not in DIR
        return (f"no point was evaluated yet; {parts} finished part{'s' if parts > 1 else ''} of the structured walk "
                f"{'are' if parts > 1 else 'is'} in the table cache {tablecache.cache_dir()} (running the same "
                "command again, without --resume, reads them)")
    return "no Monte Carlo run had finished: nothing was saved (run again without --resume)"


def _fit_interrupted(args: argparse.Namespace, walk_parts_before: int) -> str:
    """What an interrupted fit left for ``--resume`` (only what exists)."""
    if args.method == "mc":
        from fabric_optics.fitting.state import left_behind
        return left_behind(args.out)
    return _fit_left_behind(args.out, walk_parts_before)


def _fit_run(args: argparse.Namespace) -> int:
    if args.method == "mc" and args.max_evaluations is not None:
        raise _UsageError(f"--max-evaluations {args.max_evaluations}: --method mc counts Monte Carlo runs; "
                          "give --max-runs N instead")
    if args.max_runs is not None and args.max_runs < 2:
        raise _UsageError(f"--max-runs {args.max_runs}: --method mc needs at least 2 Monte Carlo runs (the start's "
                          "and one more)")
    if args.max_runs is not None and args.method != "mc":
        raise _UsageError(f"--max-runs counts the Monte Carlo runs of --method mc; the {args.method} fit counts "
                          "--max-evaluations")
    if args.mc_retrace and args.method != "mc":
        raise _UsageError("--mc-retrace is for --method mc (the other fits make no Monte Carlo runs)")
    if args.mc_trend and args.method != "mc":
        raise _UsageError(f"--mc-trend is for --method mc (the {args.method} fit has no Monte Carlo runs); "
                          "drop it or fit with --method mc")
    mc_trend = tuple(n.strip() for n in ",".join(args.mc_trend or ()).split(",") if n.strip())
    config = api.load_config(args.config)
    try:
        measured = api.read_dataset(args.measured)
        validate.measurement_rows(f"MEASURED {args.measured}", len(measured))
    except api.InputError as exc:
        raise _UsageError(f"MEASURED: {exc}") from None
    if args.out.exists() and not args.out.is_dir():
        raise _UsageError(f"--out {args.out}: exists and is not a directory; choose a directory path")
    return _fit_claimed(args, config, measured, mc_trend)


def _fit_claimed(args: argparse.Namespace, config: Any, measured: Any, mc_trend: tuple[str, ...]) -> int:
    """The fit once its arguments are checked (its --out claimed by the registry for the whole run)."""
    if not (args.resume or args.force):
        refuse_existing(args.out, False)
    from fabric_optics.fitting import reuse

    key = reuse.fit_key(vars(args), config, measured, args.out)
    found = None if args.resume else reuse.lookup(key)
    if found is not None:
        prepare_folder(args.out, writer="simulate fit", force=args.force, resume=False)
        lines, status = reuse.restore(found, args.out)
        print(f"simulate fit: this fit (its inputs, options and code unchanged) finished before; its outputs are "
              f"restored from the table cache into {args.out} (--no-cache fits again)")
        for stream, text in lines:
            print(text, file=sys.stderr if stream == "stderr" else sys.stdout)
        return status
    job = api.prepare_fit(config, measured, args.free, args.out, method=args.method, dye=args.dye,
                          max_evaluations=args.max_evaluations, max_runs=args.max_runs,
                          target_rel_err=args.target_rel_err, seed=args.seed, threads=args.threads,
                          colour_weight=args.colour_weight, wavelengths_nm=args.wavelengths, mc_trend=mc_trend,
                          mc_retrace=args.mc_retrace,
                          starts=args.starts, resume=args.resume, force=args.force, absolute=args.absolute,
                          colour_hold=args.colour_hold)
    _check_cost("fit", config, job.problem.wavelengths_nm, job.problem.target_rel_err, None)
    prepare_folder(args.out, writer="simulate fit", force=args.force, resume=args.resume)
    from simulate.fiber import tablecache

    walk_parts_before = tablecache.stored("structwalk")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", api.FitWarning)   # said below, as the verdict and the warnings
            outcome = job.run(progress=_progress(args))
    except KeyboardInterrupt:
        if getattr(job, "phase", "") == "writing":
            print(f"simulate fit: interrupted while writing the outputs, which are unchanged in {args.out}; "
                  f"{_fit_interrupted(args, walk_parts_before)}", file=sys.stderr)
        else:
            print(f"simulate fit: interrupted; {_fit_interrupted(args, walk_parts_before)}", file=sys.stderr)
        return 130
    except OSError as exc:
        raise _UsageError(_write_failed(args.out, exc) + " (the fit state is kept: --resume)") from None
    from fabric_optics.fitting.verdict import COLOUR_LEFT_OFF, uncertainty_text

    said: list[tuple[str, str]] = []

    def say(text: str, stream: str = "stdout") -> None:
        print(text, file=sys.stderr if stream == "stderr" else sys.stdout)
        said.append((stream, text))

    doc = outcome.summary
    for p in doc["parameters"]:
        u = p["u"] if p.get("u") is not None else float("nan")
        say(f"{p['name']} = {p['value']:.6g} {uncertainty_text(u, p.get('u_status', ''))}   (start "
            f"{p['start']:.6g}, bounds [{p['low']:g}, {p['high']:g}])")
    for key_ in ("start", "fitted"):
        c = doc[key_]
        colour = f", dh {c['dh']:+.4f}, ds {c['ds']:+.4f}" if "dh" in c else ""
        level = f", level k_Y {c['level_k']:.3g}" if c.get("level_k") is not None else ""
        say(f"{key_:>7}: NRMSE {c['nrmse']:.4f}{colour}{level}")
    for w in outcome.warnings:
        if not w.startswith(COLOUR_LEFT_OFF):    # said once, as the verdict, below
            say(f"warning: {w}", "stderr")
    info = outcome.result.info
    if args.method == "mc":
        say(f"wrote {args.out} ({info['mc_runs']} Monte Carlo runs ({info['mc_runs_done']} run now), "
            f"{info['summation_walks']} summation walks, {info['surrogate_evaluations']} surrogate evaluations, "
            f"{info['seconds']:.1f} s; {info['stop']})")
    else:
        say(f"wrote {args.out} ({info['evaluations']} evaluations, {info['walks']} Monte Carlo walks, "
            f"{info['reweighted']} re-weighted passes"
            + (f", {info['walks_from_cache']} of them read from the table cache" if info.get("walks_from_cache")
               else "") + f", {info['seconds']:.1f} s)")
    verdict = doc.get("verdict") or {}
    status = 0
    if not outcome.passed:
        # the outputs are written and labelled failing (fit.json verdict, fitted.toml header); exit 3
        say(f"simulate fit: FAILED, {verdict.get('why', 'colour left off')}", "stderr")
        status = int(verdict.get("exit_status") or 3)
    if not args.resume:   # a resumed fit's folder holds what an earlier process left: not a pure function of the key
        reuse.keep(key, args.out, said, status)
    return status


# ------------------------------------------------------------------------------------------

# ------------------------------------------------------------------------------------------
# simulate weave CONFIG --out MESH.ply|obj [--force]
#   the triangulated yarn tubes of the config's woven micro-element (simulate.geometry.weave); registered
#   after COMMANDS so that this section stays self-contained
# ------------------------------------------------------------------------------------------


def _weave_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name); its [weave] "
                                                     "table (default: a plain weave)")
    p.add_argument("--out", type=Path, required=True, help="mesh file to write, .ply or .obj")
    add_force(p, "an existing --out file")


def _weave_run(args: argparse.Namespace) -> int:
    from simulate.config import ConfigError, weave_from_config
    from simulate.geometry.mesh import mesh
    from simulate.geometry.weave import WeaveError

    out: Path = args.out
    if out.suffix.lower() not in (".ply", ".obj"):
        raise _UsageError(f"--out {out}: unknown mesh format {out.suffix or '(no suffix)'!r}; use .ply or .obj")
    if out.is_dir():
        raise _UsageError(f"--out {out}: is a directory; give a mesh file name (.ply or .obj)")
    refuse_existing(out, args.force)
    config = api.load_config(args.config)
    try:
        weave = weave_from_config(config)
        m = mesh(weave)
        m.export(out)
    except (ConfigError, WeaveError) as exc:
        raise _UsageError(str(exc)) from None
    print(f"wrote {out} ({len(m.vertices)} vertices, {len(m.faces)} faces; {weave.n_warp} warp x "
          f"{weave.n_weft} weft yarns, micro-element {m.Lx:g} x {m.Ly:g} um, z {m.z_min:g}..{m.z_max:g} um)")
    return 0




# ------------------------------------------------------------------------------------------
# simulate sweep CONFIG --param NAME=v1,v2,... --out DIR [--scheduler tls://HOST:PORT [--tls-ca-file F --tls-cert F --tls-key F]] [--workers N]
#   a parameter study on dask.distributed (fabric_optics.sweep.runner)
# ------------------------------------------------------------------------------------------


def _sweep_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("measured", metavar="MEASURED", type=Path, nargs="?", default=None,
                   help="measured dataset (optional, right after CONFIG): add compare's NRMSE, dh and ds of every point "
                        "to summary.csv")
    p.add_argument("--param", action="append", required=True, metavar="NAME=v1,v2,...",
                   help="a swept config field (dotted path or alias volume_fraction, radius, rms_slope) and its "
                        "values; repeat for a grid (every combination)")
    p.add_argument("--out", type=Path, required=True,
                   help="sweep directory (sweep.json, tasks/, points/<name>=<value>/, summary.csv)")
    add_force(p, "an existing --out sweep (computed afresh; --resume continues it instead)")
    p.add_argument("--method", choices=("summation", "classic", "mc"), default="summation",
                   help="fabric model (default summation)")
    add_plan(p, what="whose geometries and wavelengths are simulated")
    p.add_argument("--measurable-only", action="store_true", dest="measurable_only",
                   help="skip the plan's beam-blocked geometries as the measurement does")
    p.add_argument("--scheduler", metavar="tls://HOST:PORT", default=None,
                   help="address of a running dask scheduler (default: a local cluster of --workers processes, "
                        "behind TLS with temporary credentials)")
    p.add_argument("--tls-ca-file", default=None, dest="tls_ca_file", metavar="FILE",
                   help="--scheduler: CA certificate (PEM); without the three TLS files dask's "
                        "distributed.comm.tls configuration applies")
    p.add_argument("--tls-cert", default=None, dest="tls_cert", metavar="FILE",
                   help="--scheduler: client certificate (PEM)")
    p.add_argument("--tls-key", default=None, dest="tls_key", metavar="FILE",
                   help="--scheduler: client private key (PEM)")
    p.add_argument("--workers", type=_int_in(1, 1024), default=None,
                   help="local cluster: worker processes, one thread each (default: the number of CPUs)")
    add_threads(p, default=1, note=" per task: the workers are the parallelism")
    p.add_argument("--retries", type=_int_in(0, 100), default=2,
                   help="retries of a failing task before it is reported (default 2)")
    p.add_argument("--resume", action="store_true",
                   help="continue the sweep in --out (it must hold the same sweep)")
    add_target_rel_err(p)
    p.add_argument("--max-photons", type=_int_in(1, 10**15), default=None, dest="max_photons", metavar="N",
                   help="photon budget per task (default: the config's; none)")
    add_seed(p, what="sweep seed; each task's seed is derived from it, the point and the wavelength")
    add_no_progress(p)


def _sweep_client(args: argparse.Namespace) -> tuple[Any, Any]:
    """``(client, cluster)``: a client of the named scheduler (cluster None) or of a new local cluster.

    Both behind TLS (:mod:`fabric_optics.sweep.cluster`): a local cluster with temporary credentials, a named
    scheduler with the user's certificates.
    """
    from fabric_optics.sweep.cluster import ClusterError, local_cluster, remote_client

    try:
        if args.scheduler:
            return remote_client(args.scheduler, ca_file=args.tls_ca_file, cert=args.tls_cert,
                                 key=args.tls_key), None
        if args.tls_ca_file or args.tls_cert or args.tls_key:
            raise ClusterError("--tls-ca-file/--tls-cert/--tls-key go with --scheduler (a local cluster makes "
                               "its own temporary credentials)")
        return local_cluster(args.workers or os.cpu_count() or 1)
    except ClusterError as exc:
        raise _UsageError(str(exc)) from None


def _check_sweep_cost(args: argparse.Namespace, spec: Any) -> None:
    """:func:`_check_cost` of the costliest of up to 9 evenly spaced points, times the points per worker."""
    from simulate.budget import estimate_cost

    wl, target = spec.wavelengths_nm, float(spec.target_rel_err)
    sample = spec.points[::max(1, len(spec.points) // 8)]
    worst = max(sample, key=lambda p: estimate_cost(p.config, wl, target, spec.max_photons).seconds)
    workers = 1 if args.scheduler else (args.workers or os.cpu_count() or 1)
    _check_cost("sweep", worst.config, wl, target, spec.max_photons, runs=max(1, -(-len(spec.points) // workers)))


def _sweep_spec(args: argparse.Namespace) -> tuple[Any, Any]:
    """The sweep's spec from the arguments, its cost checked, and the measurement to compare each point with."""
    from fabric_optics.sweep.runner import SweepError, SweepSpec, parse_params

    config = api.load_config(args.config)
    try:
        plan = api.load_plan(args.plan)
    except api.InputError as exc:
        raise _UsageError(f"--plan: {exc}") from None
    try:
        spec = SweepSpec(config, plan, parse_params(args.param, config), method=args.method,
                         target_rel_err=args.target_rel_err, seed=args.seed, max_photons=args.max_photons,
                         measurable_only=args.measurable_only, threads=args.threads)
    except SweepError as exc:
        raise _UsageError(str(exc)) from None
    _check_sweep_cost(args, spec)
    measured = None
    if args.measured is not None:
        try:
            measured = api.read_dataset(args.measured)
        except api.InputError as exc:
            raise _UsageError(f"MEASURED: {exc}") from None
    return spec, measured


def _sweep_folder(args: argparse.Namespace, spec: Any) -> bool:
    """Prepare the sweep's folder (cleared with ``--force``); whether it resumes a sweep already there."""
    from fabric_optics.sweep.runner import SweepError, clear_sweep, prepare_out

    try:
        if args.force and not args.resume:
            clear_sweep(args.out)
        resumed = prepare_out(args.out, spec, resume=args.resume)
    except SweepError as exc:
        raise _UsageError(str(exc)) from None
    if resumed and not args.resume:
        raise _UsageError(f"--out {args.out}: holds this sweep already; pass --resume to continue it (finished "
                          "tasks are reused) or --force to compute it afresh")
    return resumed


def _print_sweep(args: argparse.Namespace, spec: Any, result: Any, n_tasks: int, resumed: bool) -> None:
    """Print each point's status and figures, the failures, and the line naming what was written."""
    summary = result.summary
    names = [p.name for p in spec.params]
    for row in summary.to_dict("records"):
        figures = f"{row['seconds']:.1f} s, rel_err {row['rel_err']:.2%}"
        if "nrmse" in row:
            figures += f", NRMSE {row['nrmse']:.4g}, dh {row['dh']:+.4f}, ds {row['ds']:+.4f}"
        values = ", ".join(f"{n}={row[n]:g}" for n in names)
        print(f"  {values}: {row['status']}" + (f" ({figures})" if row["status"] == "complete" else
                                                 f" ({row['tasks_done']} of {row['tasks']} tasks)"))
    for line in result.failures.values():
        print(f"simulate sweep: {line}", file=sys.stderr)
    shape = (f"{len(spec.points)} points (all {len(spec.wavelengths_nm)} wavelengths a task)" if spec.per_point else
             f"{len(spec.points)} points x {len(spec.wavelengths_nm)} wavelengths")
    print(f"wrote {args.out} ({shape} = {n_tasks} tasks: "
          f"{result.computed} computed, {result.reused} reused{', resumed' if resumed else ''}, "
          f"{len(result.failures)} failed; summary in {args.out / 'summary.csv'})")


def _sweep_run(args: argparse.Namespace) -> int:
    """``simulate sweep``: the spec, the folder, the tasks on the cluster, then the points' summary."""
    from fabric_optics.sweep.runner import SweepError, finished_tasks, run_sweep

    spec, measured = _sweep_spec(args)
    resumed = _sweep_folder(args, spec)
    if not args.verbose:
        # distributed's own logs (cluster start/stop, each failed attempt's traceback, in the
        # workers too: they inherit the environment) are not for users; failures are reported below
        os.environ["DASK_LOGGING__DISTRIBUTED"] = "critical"
    n_tasks = len(spec.tasks())
    client = cluster = None
    try:
        if len(finished_tasks(args.out, spec)) < n_tasks:  # a finished sweep is only assembled again
            client, cluster = _sweep_client(args)
        result = run_sweep(spec, args.out, client, retries=args.retries, progress=_progress(args), measured=measured)
    except SweepError as exc:
        raise _UsageError(str(exc)) from None
    except KeyboardInterrupt:
        print(f"simulate sweep: interrupted; finished tasks are kept in {args.out / 'tasks'} (run the same command "
              "with --resume to continue)", file=sys.stderr)
        return 130
    finally:
        if client is not None:
            client.close()
            if cluster is not None:
                cluster.close()
    _print_sweep(args, spec, result, n_tasks, resumed)
    return 1 if result.failures else 0




# ---- simulate export: one self-contained block ------------------------------------------------------
def _export_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("--method", choices=("classic", "summation", "mc"), required=True, help="fabric model")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.bsdf", help="RGL .bsdf file to write")
    add_force(p, "FILE.bsdf if it exists")
    p.add_argument("--rgb", action="store_true", help="linear sRGB (D65) values instead of spectra "
                   "(Mitsuba's RGB variants read only RGB files, its spectral variants only spectral ones)")
    add_wavelengths(p, "spectral bands")
    p.add_argument("--resolution", type=_int_in(4, 256), default=64, help="values per axis of the warped grid, "
                   "4..256 (64)")
    p.add_argument("--incidences", type=_int_in(2, 64), default=16, help="incidence nodes 0..90 deg, uniform in cos, "
                   "2..64 (16)")
    p.add_argument("--anisotropic", type=int, choices=(1, 2, 4), default=0, metavar="REDUCTION",
                   help="keep the anisotropy: incidence azimuths over 360/REDUCTION deg, the rest mirrored "
                        "(4: mirror symmetric in x and y, as warp/weft summation; 1: none)")
    p.add_argument("--azimuths", type=_int_in(3, 64), default=5, help="incidence azimuths with --anisotropic (5)")
    p.add_argument("--check", type=_int_in(0, 10**6), default=0, metavar="N",
                   help="measure the tabulation error at N random direction pairs (more model evaluations)")
    _run_settings_arguments(p)


def _export_run(args: argparse.Namespace) -> int:
    import time

    config = api.load_config(args.config)
    refuse_existing(args.out, args.force)
    started = time.perf_counter()
    result = api.export_bsdf(config, args.out, method=args.method, wavelengths_nm=args.wavelengths, rgb=args.rgb,
                             resolution=args.resolution, incidences=args.incidences,
                             target_rel_err=args.target_rel_err, seed=args.seed, threads=args.threads,
                             max_photons=args.max_photons, check_pairs=args.check, anisotropic=args.anisotropic,
                             azimuths=args.azimuths, force=args.force, progress=_progress(args))
    err = result.error
    check = ("" if err is None else f"; tabulation error at {err['pairs']} pairs (theta <= 80 deg): "
             f"{err['rms']:.2%} rms, {err['p95']:.2%} p95, {err['max']:.2%} max")
    print(f"wrote {args.out} ({args.method}; {result.evaluations} model evaluations; "
          f"{time.perf_counter() - started:.1f} s{check})")
    return 0


# ---- end simulate export ----------------------------------------------------------------------


#: Commands that may build woven yarn tables or structured-summation walks, i.e. use the table cache
#: (simulate.fiber.tablecache; the fit's walks: simulate.structwalk.walk.walk_structure).
_TABLE_CACHE_COMMANDS = ("fabric", "sweep", "bench", "export", "fit")


def _add_no_cache(command: registry.Command, p: argparse.ArgumentParser) -> None:
    """``--no-cache`` on the commands that use the table cache."""
    if command.name in _TABLE_CACHE_COMMANDS:
        p.add_argument("--no-cache", action="store_true", dest="no_cache",
                       help="neither read nor write the table cache (the yarn tables, the felts, the fit's "
                            "structured walks; default "
                            "~/.cache/fabric-optics or $FABRIC_OPTICS_CACHE_DIR, bounded by "
                            "$FABRIC_OPTICS_CACHE_MAX_BYTES, 2 GiB); also FABRIC_OPTICS_NO_CACHE=1")


def _check_cache(command: registry.Command, args: argparse.Namespace) -> None:
    """``--no-cache`` for this process and the ones it starts; a bad cache bound: exit 2 now, not after the run."""
    if getattr(args, "no_cache", False):
        os.environ["FABRIC_OPTICS_NO_CACHE"] = "1"   # inherited by the processes a sweep starts
    if command.name in _TABLE_CACHE_COMMANDS:
        from simulate.fiber import tablecache

        tablecache.max_bytes()


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def _command(name: str, help_text: str, add_arguments: Callable[[argparse.ArgumentParser], None],
             run: Callable[[argparse.Namespace], int], out: Literal["folder", "file"] | None = "folder") -> registry.Command:
    return registry.Command(name, help_text, add_arguments, run, out=out)


#: The ``simulate`` program: its commands (:mod:`fabric_optics.cli.registry`).
PROGRAM = registry.Program(
    prog="simulate",
    description="Physically based fiber and fabric BRDF simulation.",
    metavar="COMMAND",
    commands=(
        _command("slab", "Monte Carlo slab: diffuse reflectance and total transmittance", _slab_arguments, _slab_run,
                 out=None),
        _command("bench", "benchmark the Monte Carlo kernel (JSON + chart)", _bench_arguments, _bench_run),
        _command("fabric", "fabric BRDF at a plan's geometries, as a radiance-coefficient dataset", _fabric_arguments,
                 _fabric_run),
        _command("fiber", "fiber BRDF table over the incident sphere (npz + JSON)", _fiber_arguments, _fiber_run),
        _command("fit", "fit config parameters of a fabric model to a measurement", _fit_arguments, _fit_run),
        _command("weave", "woven micro-element: the yarn tubes of the config's weave as a PLY/OBJ mesh",
                 _weave_arguments, _weave_run, out="file"),
        _command("sweep", "parameter sweep of a fabric model on dask.distributed (one dataset per point)",
                 _sweep_arguments, _sweep_run),
        _command("export", "export a fabric model as an RGL .bsdf file (Mitsuba 3 / pbrt-v4 `measured`)",
                 _export_arguments, _export_run, out="file"),
    ),
    user_errors=(ParameterError,),
    setup_logging=_setup_logging,
    extend=_add_no_cache,
    before_run=_check_cache,
)


def build_parser() -> argparse.ArgumentParser:
    """The ``simulate`` argument parser with one subparser per command of :data:`PROGRAM`."""
    return registry.build_parser(PROGRAM)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``simulate`` console script; returns the exit code."""
    return registry.main(PROGRAM, argv)


if __name__ == "__main__":
    sys.exit(main())
