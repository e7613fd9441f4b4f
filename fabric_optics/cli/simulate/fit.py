"""``simulate fit``: config parameters of a fabric model fitted to a measurement.

Checks the options that belong to one method, restores a fit that finished before with the same inputs
(:mod:`fabric_optics.fitting.reuse`), runs :func:`fabric_optics.api.prepare_fit`'s job and prints its
parameters, figures and verdict; an interrupted fit says what it left for ``--resume``.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

from fabric_optics import api, validate
from fabric_optics.cli.common import (
    UsageError,
    add_force,
    add_no_progress,
    add_seed,
    add_target_rel_err,
    add_threads,
    add_wavelengths,
    int_in,
    progress,
    refuse_existing,
)
from fabric_optics.cli.simulate.options import (
    check_cost,
    nonneg_float,
    write_failed,
)
from gonio.data.outputs import prepare_folder

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate fit``."""
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
    p.add_argument("--colour-weight", type=nonneg_float, default=1.0, dest="colour_weight",
                   help="weight w_c of (dh^2 + ds^2) beside NRMSE^2 in the objective (default 1)")
    p.add_argument("--no-colour-hold", action="store_false", dest="colour_hold",
                   help="classic and summation fits: do not hold the colour within the tolerance (the objective's "
                        "colour hold, beyond 0.7 of |dh| 0.02 turn, |ds| 0.03); the colour then weighs by "
                        "--colour-weight only")
    p.add_argument("--absolute", action="store_true",
                   help="an absolutely calibrated measurement: fit its level too, (ln k_Y)^2 added to the objective "
                        "(k_Y: the normalisation's luminance factor at the colour geometry, 1 at the measured level)")
    p.add_argument("--max-evaluations", type=int_in(1, 10**6), default=None, dest="max_evaluations", metavar="N",
                   help="summation and classic fits: model evaluations of the search in all, steps and Jacobian "
                        f"columns of every start (default {METHODS['classic'].default_budget}; the uncertainty "
                        "propagation afterwards is counted apart)")
    p.add_argument("--max-runs", type=int_in(1, 10**4), default=None, dest="max_runs", metavar="N",
                   help=f"--method mc: Monte Carlo runs, the start's included (default {METHODS['mc'].default_budget}, "
                        "at least 2)")
    p.add_argument("--mc-trend", action="append", default=None, dest="mc_trend", metavar="NAME,...",
                   help="--method mc: free parameters whose trend the surrogate takes from Monte Carlo runs (one more "
                        "run per parameter and step) instead of the summation -- where the two models' trends "
                        "disagree; the boundary's slopes for transmitted light always are (see fabric_optics.fitting.spacemapping)")
    p.add_argument("--mc-retrace", action="store_true", dest="mc_retrace",
                   help="--method mc: trace every Monte Carlo run (by default, with only dye parameters free, a run "
                        "after a traced one re-weights its rays to the new dye while that is as accurate as a trace)")
    p.add_argument("--starts", type=int_in(1, 1000), default=1,
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


def run(args: argparse.Namespace) -> int:
    """Run ``simulate fit``; return the exit status."""
    if args.method == "mc" and args.max_evaluations is not None:
        raise UsageError(f"--max-evaluations {args.max_evaluations}: --method mc counts Monte Carlo runs; "
                          "give --max-runs N instead")
    if args.max_runs is not None and args.max_runs < 2:
        raise UsageError(f"--max-runs {args.max_runs}: --method mc needs at least 2 Monte Carlo runs (the start's "
                          "and one more)")
    if args.max_runs is not None and args.method != "mc":
        raise UsageError(f"--max-runs counts the Monte Carlo runs of --method mc; the {args.method} fit counts "
                          "--max-evaluations")
    if args.mc_retrace and args.method != "mc":
        raise UsageError("--mc-retrace is for --method mc (the other fits make no Monte Carlo runs)")
    if args.mc_trend and args.method != "mc":
        raise UsageError(f"--mc-trend is for --method mc (the {args.method} fit has no Monte Carlo runs); "
                          "drop it or fit with --method mc")
    mc_trend = tuple(n.strip() for n in ",".join(args.mc_trend or ()).split(",") if n.strip())
    config = api.load_config(args.config)
    try:
        measured = api.read_dataset(args.measured)
        validate.measurement_rows(f"MEASURED {args.measured}", len(measured))
    except api.InputError as exc:
        raise UsageError(f"MEASURED: {exc}") from None
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a directory; choose a directory path")
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
    check_cost("fit", config, job.problem.wavelengths_nm, job.problem.target_rel_err, None)
    prepare_folder(args.out, writer="simulate fit", force=args.force, resume=args.resume)
    from simulate.fiber import tablecache

    walk_parts_before = tablecache.stored("structwalk")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", api.FitWarning)   # said below, as the verdict and the warnings
            outcome = job.run(progress=progress(args))
    except KeyboardInterrupt:
        if getattr(job, "phase", "") == "writing":
            print(f"simulate fit: interrupted while writing the outputs, which are unchanged in {args.out}; "
                  f"{_fit_interrupted(args, walk_parts_before)}", file=sys.stderr)
        else:
            print(f"simulate fit: interrupted; {_fit_interrupted(args, walk_parts_before)}", file=sys.stderr)
        return 130
    except OSError as exc:
        raise UsageError(write_failed(args.out, exc) + " (the fit state is kept: --resume)") from None
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
