"""The ``gonio`` console script.

Mock, acquire, replay, check-plan, demo, truth, import, bench-driver.

Exit status
-----------
``acquire``, ``demo``: 0 complete; 1 stopped safely by an instrument fault that retries did not
clear (measured points kept; continue with ``--resume``); 2 usage or input error (plan, URL,
journal of another plan, unreachable device, a run directory in use by another session, a
``--record`` file that exists or is one of the run directory's own, an ``--out`` that the
output rule refuses: :mod:`gonio.data.outputs`); 130 interrupted by SIGINT/SIGTERM (measured points kept, shutter closed, drives
stopped).
``replay``: 0 the transcript was reproduced and the recorded run was complete; 1 the driver's
requests differ from the transcript (the message names the request index and the difference),
the transcript fails its integrity check (an edited line, named), or the recorded run itself
stopped; 2 usage or input error.
``check-plan``: 0 every point is measurable (or only expected beam-block points, with
``skip_blocked = true``); 1 some points are out of the soft limits or unexpectedly in the
beam-block zone (all listed); 2 invalid plan.
``mock``: see ``gonio mock --help``.

Every command that writes follows :func:`gonio.data.outputs.check_output` and then
:func:`gonio.data.outputs.refuse_existing`: a run folder (holding a journal) is never replaced (only
``acquire --resume`` continues it); any other existing output, a previous output of the same
command included, only with ``--force``.

A user error prints one line on stderr (``gonio <command>: ...``), never a traceback.

This module only parses arguments and prints; the work is done by the library:
:func:`gonio.acquisition.session.run_session` and
:func:`~gonio.acquisition.session.replay_session`, :func:`gonio.demo.run_demo`,
:func:`gonio.bench.bench_driver`, :func:`gonio.mock.truth.truth_dataset`,
:func:`gonio.data.formats.import_files`, :meth:`gonio.acquisition.plan.Plan.check`.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import shlex
import sys
from pathlib import Path

from fabric_optics import api
from fabric_optics.cli import common, registry
from fabric_optics.cli.common import (
    Parser,
    UsageError,
    add_force,
    add_no_progress,
    add_plan,
    add_verbose,
    plan_of,
    refuse_existing,
)
from gonio.acquisition.calibration import CalibrationError
from gonio.acquisition.engine import EXIT_OK, AcquisitionError, RunResult
from gonio.acquisition.journal import JournalError, read_journal
from gonio.acquisition.plan import PlanError, preset_names
from gonio.acquisition.record import ReplayMismatch, TranscriptError, TranscriptIntegrityError, load_transcript
from gonio.acquisition.session import check_run_output, replay_session, run_session
from gonio.data import DatasetError
from gonio.data.outputs import WRITTEN_BY, check_output
from gonio.data.printable import printable
from gonio.instrument.motion import DEFAULT_WAIT_TIMEOUT_S
from gonio.instrument.probe import LinkSetupError, open_links

__all__ = ["PROGRAM", "main", "build_parser", "build_parsers"]

log = logging.getLogger("gonio")

_USER_ERRORS = (PlanError, CalibrationError, JournalError, AcquisitionError, TranscriptError,
                DatasetError, LinkSetupError)

_UsageError = UsageError


MAX_TIMEOUT_S = 3600.0
"""Largest ``--timeout`` accepted (an hour: longer is a typo, not a slow link)."""


_FORCE_HELP = ("an existing dataset folder, or write into a folder that holds anything; a run "
               "folder, one holding a journal, is never replaced")


def _timeout_seconds(text: str) -> float:
    """``--timeout``: a finite number of seconds in (0, MAX_TIMEOUT_S]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not math.isfinite(value) or not 0.0 < value <= MAX_TIMEOUT_S:
        raise argparse.ArgumentTypeError(f"must be a number of seconds above 0 and at most "
                                         f"{MAX_TIMEOUT_S:g}, got {text}")
    return value


def _setup_logging(verbose: bool) -> None:
    root = logging.getLogger()
    if not root.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("gonio: %(message)s"))
        root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    # pymodbus logs every missing answer at ERROR; the driver counts and reports them itself
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


def _resume_command(args) -> str:
    """The exact command that continues this acquisition."""
    argv = ["gonio", "acquire", "--plan", args.plan, "--modbus", args.modbus, "--serial", args.serial]
    if args.timeout != 1.0:
        argv += ["--timeout", f"{args.timeout:g}"]
    if getattr(args, "seed", None) is not None:
        argv += ["--seed", str(args.seed)]
    if getattr(args, "wait_timeout", None) is not None:
        argv += ["--wait-timeout", f"{args.wait_timeout:g}"]
    return shlex.join(argv + ["--out", str(args.out), "--resume"])


def _finish(result: RunResult, command: str, resume: str | None = None) -> int:
    retries = ", ".join(f"{k} {v}" for k, v in result.retries.items()) or "none"
    where = f"; dataset: {result.dataset_path}" if result.dataset_path else "; no dataset (nothing measured)"
    if result.status == "complete":
        print(f"gonio {command}: complete, {result.points_measured}/{result.points_total} points"
              f"{where} (retries: {retries})")
    else:
        what = "interrupted" if result.status == "interrupted" else result.message
        then = f"; continue with: {resume}" if resume else ""
        print(f"gonio {command}: {what}; {result.points_measured}/{result.points_total} points "
              f"kept{where}{then}", file=sys.stderr)
    return result.exit_code


def _cmd_acquire(args) -> int:
    plan = api.load_plan(plan_of(args))
    out = Path(args.out)
    check_run_output(out, writer="gonio acquire", force=args.force, resume=args.resume)
    if not args.resume:
        refuse_existing(out, args.force)
    live = _start_live_view(args, plan, out, "acquire")
    try:
        modbus, serial_link = open_links(args.modbus, args.serial, args.timeout)
        try:
            result = run_session(plan, modbus, serial_link, out, resume=args.resume,
                                 seed=args.seed, record=Path(args.record) if args.record else None,
                                 progress=False if args.no_progress else None, force=args.force,
                                 wait_timeout_s=args.wait_timeout, subscribers=_live_subscribers(live))
        except OSError as exc:      # a full disk, a run directory gone read-only, ...
            raise _UsageError(_write_failure(exc, out, args)) from None
    finally:
        _close_live_view(live)
    return _finish(result, "acquire", _resume_command(args))


def _start_live_view(args, plan, out: Path, command: str):
    """With ``--live`` (or ``--live-port``): the live view's server, its address printed once; else None."""
    if not args.live and args.live_port is None:
        return None
    from gonio.acquisition.live import LOOPBACK, LiveServer, LiveView

    port = args.live_port or 0
    view = LiveView(plan, out)
    try:
        server = LiveServer(view, port)
    except OSError as exc:
        raise _UsageError(f"--live-port {port}: cannot listen on {LOOPBACK}:{port} ({exc.strerror or exc}); "
                          "choose another port, or leave --live-port out for a free one") from None
    print(f"gonio {command}: live view at {server.url}", flush=True)
    return server


def _live_subscribers(live) -> list:
    return [] if live is None else [live.view]


def _close_live_view(live) -> None:
    """Let a page that is watching fetch the end, then stop serving (never raises)."""
    if live is not None:
        live.view.ended("the command ended before the acquisition did")
        live.close()


def _write_failure(exc: OSError, out: Path, args) -> str:
    """One line for a failed write during a session: which file, and that the points are kept."""
    target = exc.filename or out
    journal = out / "journal.jsonl"
    try:
        kept = len({tuple(r["geometry"]) for r in read_journal(journal).of_type("point")})
    except Exception:  # noqa: BLE001 - the journal may not exist; the message still helps
        kept = 0
    return (f"cannot write {target}: {exc.strerror or exc}; the {kept} points measured so far are "
            f"kept in {journal}: free some space, then continue with: {_resume_command(args)}")


def _cmd_replay(args) -> int:
    try:
        transcript = load_transcript(args.transcript)
    except TranscriptIntegrityError as exc:     # an edited transcript proves nothing: exit 1
        print(f"gonio replay: {exc}", file=sys.stderr)
        return 1
    plan = api.load_plan(plan_of(args))
    check_run_output(Path(args.out), writer="gonio replay", force=args.force)
    refuse_existing(args.out, args.force)
    try:
        result = replay_session(transcript, plan, Path(args.out), force=args.force)
    except ReplayMismatch as exc:
        print(f"gonio replay: {str(exc).removeprefix('replay: ')}", file=sys.stderr)
        return 1
    code = _finish(result, "replay")
    return EXIT_OK if code == EXIT_OK else 1


def _cmd_check_plan(args) -> int:
    plan = api.load_plan(plan_of(args))
    chk = plan.check()
    n_wl = len(plan.wavelengths_nm)
    print(f"plan {printable(plan.name)} ({printable(plan.path)}): {len(plan.points())} geometries x {n_wl} wavelengths")
    print(f"measurable: {len(chk.ordered)} geometries ({len(chk.ordered) * n_wl} measurements), "
          f"ordered by rotation, incidence, detector plane, serpentine over the detector angle")
    if chk.blocked:
        tag = "expected, skipped" if plan.skip_blocked else "REFUSED"
        print(f"beam-block zone ({tag}): {len(chk.blocked)} geometries never sent to the controller")
        for p in chk.blocked:
            print(f"  theta_i={p.theta_i:g} phi_i={p.phi_i:g} theta_o={p.theta_o:g} phi_o={p.phi_o:g}"
                  f"  (axes {', '.join(f'{a:g}' for a in p.axes_deg)})")
    if chk.out_of_limits:
        print(f"out of the soft limits (REFUSED): {len(chk.out_of_limits)} geometries")
        for p, why in chk.out_of_limits:
            print(f"  theta_i={p.theta_i:g} phi_i={p.phi_i:g} theta_o={p.theta_o:g} "
                  f"phi_o={p.phi_o:g}: {why}")
    est = chk.estimated_s
    print(f"estimated duration at real speed: {est / 60:.1f} min ({est:.0f} s)")
    if args.list:
        for k, p in enumerate(chk.ordered):
            print(f"  {k:4d}  axes {', '.join(f'{a:g}' for a in p.axes_deg)}")
    if chk.ok:
        print("ok")
        return EXIT_OK
    print("not ok: some points cannot be measured (listed above)")
    return 1


def _plan_for(plan: str, sample: str, what: str):
    """The plan named ``plan``.

    ``measured``: the plan of the sample file's own measured incidences
    (:func:`gonio.acquisition.plan.measured_plan`; the sample must be an RGL .bsdf file).
    """
    from gonio.acquisition.plan import MEASURED, measured_plan

    if plan != MEASURED:
        return api.load_plan(plan)
    if not (str(sample).endswith(".bsdf") and Path(sample).is_file()):
        raise _UsageError(f"--plan {MEASURED}: follows the measured incidences of an RGL .bsdf file, but {what} "
                          f"{sample!r} is not one; give a .bsdf file or a plan")
    return measured_plan(sample)


def _cmd_demo(args) -> int:
    from gonio.data.outputs import is_run_folder
    from gonio.demo import is_previous_demo, run_demo
    from gonio.mock.samples import SampleError

    out = Path(args.out)
    plan = _plan_for(args.plan or common.DEFAULT_PLAN, args.sample, "--sample")
    # another run's folder there: run_demo's own message (never replaced, --force included)
    if out.is_dir() and not (is_run_folder(out) and not is_previous_demo(out)):
        refuse_existing(out, args.force)
    live = _start_live_view(args, plan, out, "demo")
    try:
        result, elapsed_s = run_demo(out, plan, seed=args.seed, timeout_s=args.timeout,
                                     progress=False if args.no_progress else None,
                                     force=args.force, wait_timeout_s=args.wait_timeout,
                                     sample=args.sample,
                                     name_from_sample=args.plan is None and args.sample != "red-cotton",
                                     subscribers=_live_subscribers(live))
    except SampleError as exc:
        raise _UsageError(f"--sample: {exc}") from None
    finally:
        _close_live_view(live)
    code = _finish(result, "demo")
    if code == EXIT_OK:
        print(f"gonio demo: plan {printable(plan.name)} measured on the embedded mock holding {printable(args.sample)} "
              f"in {elapsed_s:.1f} s; dataset in {out}/ (radiance.csv, meta.json)")
    return code


def _cmd_truth(args) -> int:
    plan = _plan_for(plan_of(args), args.sample, "SAMPLE")
    check_output(args.out, "dataset", writer="gonio truth", force=args.force)
    refuse_existing(args.out, args.force)
    try:
        dataset = api.truth(args.sample, plan)
    except api.InputError as exc:       # the sample's own message, as the option names it
        raise _UsageError(str(exc.__cause__ or exc)) from None
    dataset.meta[WRITTEN_BY] = "gonio truth"
    out = api.write_dataset(dataset, args.out, force=args.force)
    print(f"gonio truth: {printable(dataset.name)}, {len(dataset)} values at the geometries of plan "
          f"{plan.name}; dataset in {out}/")
    return EXIT_OK


def _cmd_bench(args) -> int:
    from gonio.bench import bench_driver
    from gonio.data import atomic_write

    if args.out:
        check_output(args.out, "file", writer="gonio bench-driver", force=args.force)
        refuse_existing(args.out, args.force)
    report = {WRITTEN_BY: "gonio bench-driver", **bench_driver(api.load_plan(args.plan),
                                                               repeats=args.repeats)}
    if args.out:
        check_output(args.out, "file", writer="gonio bench-driver", force=args.force)
        atomic_write(args.out, (json.dumps(report, indent=2) + "\n").encode())
    print(json.dumps(report, indent=2))
    return EXIT_OK


def _links(sp: argparse.ArgumentParser) -> None:
    """The options of a command that talks to the instrument (``acquire``, ``demo``)."""
    sp.add_argument("--timeout", type=_timeout_seconds, default=1.0, metavar="S",
                    help="link timeout in seconds (default 1.0; a READ? also gets its "
                         "integration time; at most 3600)")
    sp.add_argument("--wait-timeout", type=_timeout_seconds, default=None, metavar="S",
                    help="longest wait for a move (unless the move itself needs longer at "
                         "its velocity) and for a controller answering busy, e.g. another "
                         "client driving the instrument (default "
                         f"{DEFAULT_WAIT_TIMEOUT_S:g} s; at most 3600); a takeover by a "
                         "client that claims the instrument stops the session within 1 s")
    add_no_progress(sp)
    sp.add_argument("--live", action="store_true",
                    help="serve a live view of the acquisition on a local web page (127.0.0.1 only, "
                         "read-only; its address, with a random token, is printed once): the curves "
                         "per incidence with error bars as the points arrive, the position in the "
                         "plan, the time left, retries and faults, then the finished dataset")
    sp.add_argument("--live-port", type=common.int_in(1, 65535), default=None, metavar="PORT",
                    help="the live view's port on 127.0.0.1 (implies --live; default: a free port)")


def _acquire_arguments(a: argparse.ArgumentParser) -> None:
    add_plan(a, required=True, what="to measure")
    a.add_argument("--modbus", required=True, metavar="URL", help="tcp://HOST:PORT or rtu://DEVICE")
    a.add_argument("--serial", required=True, metavar="URL", help="device path, pty or socket://HOST:PORT")
    a.add_argument("--out", required=True, metavar="RUN_DIR", help="run directory")
    a.add_argument("--resume", action="store_true", help="continue the run journaled in RUN_DIR")
    a.add_argument("--record", metavar="FILE.jsonl",
                   help="record every request/response to a new file (an existing file is refused)")
    a.add_argument("--seed", type=int, default=None, metavar="N",
                   help="the mock's seed, recorded in the meta (default: none)")
    add_force(a, _FORCE_HELP)
    _links(a)


def _replay_arguments(r: argparse.ArgumentParser) -> None:
    r.add_argument("transcript", metavar="TRANSCRIPT")
    add_plan(r, required=True, what="of the recorded run")
    r.add_argument("--out", required=True, metavar="RUN_DIR")
    add_force(r, _FORCE_HELP)


def _check_plan_arguments(c: argparse.ArgumentParser) -> None:
    add_plan(c, required=True, what="to check")
    c.add_argument("--list", action="store_true", help="list the points in motion order")


def _demo_arguments(d: argparse.ArgumentParser) -> None:
    d.add_argument("--out", default="demo-out/measured", metavar="DIR",
                   help="dataset folder (default demo-out/measured)")
    d.add_argument("--sample", default="red-cotton", metavar="NAME|FILE",
                   help="the mock's virtual sample, as for `gonio mock --sample`: lambert:RHO, "
                        "red-cotton (default, an analytic stand-in), a dataset directory, or an RGL "
                        ".bsdf file (a real material, e.g. fixtures/real/acrylic_felt_green_rgb.bsdf); "
                        "without --plan the dataset is named after it")
    d.add_argument("--plan", default=None, metavar="PLAN",
                   help="acquisition plan to measure: a preset name or a TOML file (default red-cotton; "
                        "green-felt: the same geometry, the felt named as its sample; measured: the --sample .bsdf "
                        "file's own measured incidences and retro-reflection ring)")
    d.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    add_force(d, _FORCE_HELP)
    _links(d)


def _truth_arguments(t: argparse.ArgumentParser) -> None:
    t.add_argument("sample", metavar="SAMPLE",
                   help="lambert:RHO, red-cotton, a dataset directory or an RGL .bsdf file")
    add_plan(t, required=True, what="whose geometries and wavelengths are evaluated")
    t.add_argument("--out", required=True, metavar="DIR", help="dataset folder")
    add_force(t, _FORCE_HELP)


def _import_arguments(im: argparse.ArgumentParser) -> None:
    im.add_argument("format", metavar="FORMAT", choices=["rgl-bsdf", "pgii", "merl"],
                    help="rgl-bsdf | pgii | merl")
    im.add_argument("files", metavar="FILE", nargs="+", help="file(s) to import")
    im.add_argument("--out", required=True, metavar="DIR", help="dataset folder")
    add_force(im, _FORCE_HELP)
    add_plan(im, default=None, what="whose geometries to evaluate (default: in-plane curves)")
    im.add_argument("--scale", type=float, metavar="FR_PER_UA",
                    help="pgii [uA] files: f_r per uA of detector current (absolute values); "
                         "without it raw currents make a relative dataset")
    im.add_argument("--white", metavar="FILE",
                    help="pgii [uA] files: a pgII [uA] file of a diffuse white standard measured with the "
                         "same detector (absolute values; see gonio.data.formats.pgii)")
    im.add_argument("--white-reflectance", type=float, default=0.99, metavar="RHO",
                    help="hemispherical reflectance of that standard (default 0.99)")
    im.add_argument("--keep-grazing", action="store_true",
                    help="keep incidences theta_i >= 89 deg (dropped by default: the RGL files' "
                         "89.99999 deg tables are extrapolations; see docs/dataset.md)")


def _cmd_import(args) -> int:
    from gonio.acquisition.plan import MEASURED
    from gonio.data.formats import import_notes

    if args.plan == MEASURED and not (args.files[0].endswith(".bsdf") and Path(args.files[0]).is_file()):
        raise _UsageError(f"--plan {MEASURED}: follows the measured incidences of an RGL .bsdf file, but FILE "
                          f"{args.files[0]!r} is not one; give a .bsdf file or a plan")
    if args.scale is not None and not (args.scale > 0 and args.scale < float("inf")):
        raise _UsageError(f"--scale {args.scale}: must be a positive number")
    if not (0.0 < args.white_reflectance <= 1.0):
        raise _UsageError(f"--white-reflectance {args.white_reflectance}: must be in (0, 1]")
    check_output(args.out, "dataset", writer="gonio import", force=args.force)
    refuse_existing(args.out, args.force)
    # the same code as Python's fabric_optics.import_measurement (it marks the folder as gonio import's)
    dataset = api.import_measurement(args.files, args.out, force=args.force, format=args.format, plan=args.plan,
                                     scale=args.scale, white=args.white, white_reflectance=args.white_reflectance,
                                     keep_grazing=args.keep_grazing)
    out = Path(args.out)
    bands = (f"channels {''.join(dataset.channels)} ({dataset.colour_space})" if dataset.is_rgb
             else f"{len(dataset.wavelengths_nm)} wavelengths")
    print(f"gonio import: {printable(dataset.name)}, {len(dataset.geometries())} geometries, {bands}"
          f"{', relative units' if dataset.relative else ''}; dataset in {out}/")
    for note in import_notes(dataset):
        print(f"gonio import: note: {printable(note)}")
    return EXIT_OK




# ---- gonio export: one self-contained block ---------------------------------------------------
_EXPORT_DESCRIPTION = (
    "Tabulate a radiance-coefficient dataset as an isotropic RGL .bsdf file (Dupuy & Jakob 2018), read by "
    "Mitsuba 3's and pbrt-v4's `measured` material and by `gonio import rgl-bsdf`. The in-plane curves are "
    "interpolated; the rule for directions the data do not cover (gonio.data.bsdf_dataset.dataset_brdf) is "
    "written into the file.")


def _export_arguments(ex: argparse.ArgumentParser) -> None:
    ex.add_argument("dataset", metavar="DATASET", help="dataset folder")
    ex.add_argument("--out", required=True, metavar="FILE.bsdf", help="file to write")
    add_force(ex, "FILE.bsdf if it exists")
    ex.add_argument("--resolution", type=common.int_in(4, 256), default=64,
                    help="values per axis of the warped grid, 4..256 (64)")
    ex.add_argument("--incidences", type=common.int_in(2, 64), default=16,
                    help="incidence nodes 0..90 deg besides the measured incidences, 2..64 (16)")


def _cmd_export(args) -> int:
    out = Path(args.out)
    refuse_existing(out, args.force)
    dataset = api.read_dataset(args.dataset)
    result = api.export_bsdf(dataset, out, resolution=args.resolution, incidences=args.incidences,
                             force=args.force, description=f"{dataset.name} (fabric-optics gonio export of a "
                                                           "measured dataset)",
                             provenance={"dataset": str(args.dataset)})
    rule = result.provenance["coverage"] if hasattr(result, "provenance") else result.coverage
    print(f"gonio export: {printable(dataset.name)} -> {out} ({result.evaluations} interpolated values; measured "
          f"incidences {rule['incidences_deg']} deg, observation {rule['observation_range_deg']} deg: "
          "values outside them are clamped/blended, see the file's provenance)")
    return EXIT_OK
# ---- end gonio export ---------------------------------------------------------------------------


def _bench_parser() -> argparse.ArgumentParser:
    b = Parser(prog="gonio bench-driver",
               description="Driver overhead benchmark: live "
                           "runs against the fast mock and replays of their "
                           "transcripts; prints JSON.")
    add_plan(b, what="measured by the benchmark")
    b.add_argument("--repeats", type=common.int_in(1, 1000), default=3, help="runs of each kind (default 3)")
    b.add_argument("--out", default=None, help="also write the JSON here (an existing file only with --force; "
                   "never a run folder's own file)")
    add_force(b, "an existing --out file")
    add_verbose(b, sub=False)
    return b


def _mock_main(argv: list[str]) -> int:
    from gonio.mock.cli import main as mock_main

    return mock_main(argv)


_ACQUIRE_EPILOG = ("Exit status: 0 complete; 1 stopped safely by an instrument fault "
                   "(measured points kept: continue with --resume); 2 usage or input "
                   "error; 130 interrupted (Ctrl-C, SIGTERM; points kept). --resume "
                   "reuses the journal's calibration when the plan and standard files "
                   "are unchanged, the instrument is the same and it is younger than "
                   "the plan's calibration_max_age_min; otherwise it is measured "
                   "again. --record writes a new transcript for this session.")


#: The ``gonio`` program: its commands (:mod:`fabric_optics.cli.registry`). ``acquire`` and ``replay``
#: lock their run folder for the session (gonio.acquisition.rundir) rather than claim their --out.
PROGRAM = registry.Program(
    prog="gonio",
    description="Goniophotometer driver, mock devices and acquisition.",
    epilog="Exit status: 0 success, 1 failed check / safe stop / replay mismatch, "
           "2 usage or input error, 130 interrupted. Plans: a TOML file or a preset name ("
           + ", ".join(preset_names()) + ").",
    metavar="COMMAND",
    required=False,
    error_word="",
    user_errors=_USER_ERRORS,
    setup_logging=_setup_logging,
    commands=(
        registry.Command("mock", "serve mock devices (see `gonio mock --help`)", delegate=_mock_main),
        registry.Command("acquire", "measure a plan", _acquire_arguments, _cmd_acquire,
                         description="Home, calibrate (dark + white standard), measure every point "
                                     "of --plan, journal each point, write the dataset in --out.",
                         epilog=_ACQUIRE_EPILOG),
        registry.Command("replay", "run the driver against a recorded transcript", _replay_arguments, _cmd_replay,
                         description="Run the driver with --plan against TRANSCRIPT (from "
                                     "`gonio acquire --record`), answering each request with the "
                                     "recorded response; writes the dataset in --out.",
                         epilog="Exit status: 0 reproduced (and the recorded run was complete); 1 "
                                "the driver sent a request that differs from the transcript (the "
                                "message names the request index and both requests), or the "
                                "recorded run itself stopped; 2 usage or input error."),
        registry.Command("check-plan", "validate a plan: limits, beam-block zone, duration", _check_plan_arguments,
                         _cmd_check_plan,
                         description="List the points the controller would refuse (soft limits, "
                                     "beam-block zone: never sent), the motion order and the "
                                     "estimated duration at real speed.",
                         epilog="Exit status: 0 every point measurable (beam-block points allowed "
                                "when the plan says skip_blocked = true); 1 some points refused "
                                "(listed); 2 invalid plan."),
        registry.Command("demo", "embedded mock (red cotton unless --sample) + a plan (red-cotton)", _demo_arguments,
                         _cmd_demo, out="folder",
                         description="Start the mock goniophotometer in this process (real protocol "
                                     "endpoints on loopback and a pseudo-terminal) holding --sample, "
                                     "and measure it with --plan into --out. The dataset's meta names "
                                     "the mock's sample (sample.mock_sample)."),
        registry.Command("truth", "write a mock sample's true beta at a plan's geometries", _truth_arguments,
                         _cmd_truth, out="folder",
                         description="Evaluate the mock's virtual sample (lambert:RHO, red-cotton, "
                                     "a dataset directory or an RGL .bsdf file) at the measurable geometries and the "
                                     "wavelengths of --plan and write it as a dataset (kind "
                                     "simulated, u_beta 0): the known answer an acquisition on the "
                                     "mock must recover."),
        registry.Command("import", "convert a file of another format into a dataset", _import_arguments,
                         _cmd_import, out="folder",
                         description="Read FILE (rgl-bsdf: an RGL .bsdf tensor file; pgii: one or "
                                     "more pgII text files, one incidence each; merl: a MERL "
                                     ".binary table) and write a radiance-coefficient dataset. "
                                     "Tabulated BRDFs (rgl-bsdf, merl) are evaluated at the "
                                     "geometries of --plan, by default at in-plane "
                                     "curves (the file's own incidence angles for rgl-bsdf)."),
        registry.Command("bench-driver", "driver overhead benchmark on the fast mock, with replays (JSON; see "
                                         "`gonio bench-driver --help`)",
                         run=_cmd_bench, parser=_bench_parser, out="file"),
        registry.Command("export", "write a dataset as an RGL .bsdf file (Mitsuba 3 / pbrt-v4)", _export_arguments,
                         _cmd_export, description=_EXPORT_DESCRIPTION, out="file"),
    ),
)


def build_parser() -> argparse.ArgumentParser:
    """The ``gonio`` parser, every subcommand included.

    ``mock`` and ``bench-driver`` parse their own arguments (:func:`build_parsers`).
    """
    return registry.build_parser(PROGRAM)


def build_parsers() -> dict[str, argparse.ArgumentParser]:
    """Every parser of ``gonio``.

    ``"gonio"`` (:func:`build_parser`, the subcommands included) and the two subcommands that parse their own
    arguments, ``"gonio mock"`` and ``"gonio bench-driver"``.
    """
    from gonio.mock.cli import build_parser as mock_parser

    return {"gonio": build_parser(), "gonio mock": mock_parser(), "gonio bench-driver": _bench_parser()}


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``gonio`` console script; returns the exit status."""
    return registry.main(PROGRAM, argv)


if __name__ == "__main__":
    sys.exit(main())
