"""``compare`` command line: ``compare report`` and ``compare check`` (docs/architecture.md).

::

    compare report MEASURED [SIMULATED ...] --out REPORT_DIR [--force] [--fit FIT_DIR ...]
                   [--seed-sample DATASET_DIR] [--renders RENDER_DIR]
    compare check  MEASURED SIMULATED [--max-nrmse X] [--max-hue-diff X] [--max-sat-diff X]
                   [--max-level-ratio X]
    compare render FILE.bsdf [FILE.bsdf ...] --out DIR [--force]

Exit status: 0 success (``check``: every figure within its threshold), 1 a failed check (the
failing figures are printed), 2 a usage or input error (one line on stderr, no traceback).

``check`` refuses (exit 1) a dataset whose meta says the run is incomplete (``"complete": false``,
as ``gonio acquire`` writes for a stopped run), printing how many of the planned points are
missing, unless ``--allow-incomplete``; ``report`` shows such data with a banner. Comparing a
dataset with itself (same directory or same ``radiance.csv`` content) is warned about on stderr.

``check`` thresholds (defaults chosen from the reference results of docs/physics.md section 8: the
published model hues lie within 0.01 of the measured one, saturations within 0.01):

- ``--max-nrmse`` 0.10: overall NRMSE of the normalised curves (RMSE / mean measured beta);
- ``--max-hue-diff`` 0.02: ``|dh|`` on the hue circle (hue in [0, 1));
- ``--max-sat-diff`` 0.05: ``|ds|``;
- ``--max-level-ratio`` 1.5: the absolute level, ``max(k_Y, 1/k_Y)`` with ``k_Y`` the luminance-weighted
  normalisation factor at the colour geometry (:class:`compare.comparison.Level`): a model scaled by 2 fails.
  Not judged for a relative measurement. The verdict says in words when a model matches in shape but not in
  level.

An RGB measurement is compared per channel, a spectral simulation converted to its colour space
first (:mod:`compare.bands`); the conversion is printed as a note. A photometric (Y-only)
measurement has no colour: only the NRMSE is checked (noted). A relative measurement
(``"relative": true``) is normalised like any other; the hue and saturation thresholds still
apply (they do not depend on the scale), and no V is stated (noted). No threshold uses V.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from compare.comparison import incomplete_datasets
from compare.errors import CompareError
from compare.metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_LEVEL_RATIO, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF
from compare.normalise import DEFAULT_WINDOW_DEG
from fabric_optics import api
from fabric_optics.cli import registry
from fabric_optics.cli.common import add_force, refuse_existing
from gonio.data import DatasetError
from gonio.data.printable import printable

__all__ = ["DEFAULT_MAX_HUE_DIFF", "DEFAULT_MAX_NRMSE", "DEFAULT_MAX_SAT_DIFF", "PROGRAM", "main", "build_parser"]

log = logging.getLogger("compare")


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a number >= 0")
    return value


def _positive(text: str) -> float:
    value = _non_negative(text)
    if value == 0:
        raise argparse.ArgumentTypeError("must be > 0")
    return value


def _common_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--normal-window", type=_positive, default=DEFAULT_WINDOW_DEG,
                   metavar="DEG", help="largest |s| of the normal-incidence points used to "
                   f"estimate beta(0,0) (default {DEFAULT_WINDOW_DEG:g})")
    p.add_argument("--illuminant", default="D65",
                   help="illuminant of the colour match (default D65)")


def _report_arguments(rep: argparse.ArgumentParser) -> None:
    rep.add_argument("measured", metavar="MEASURED", help="measured dataset directory")
    rep.add_argument("simulated", metavar="SIMULATED", nargs="*",
                     help="simulated dataset(s) or a `simulate sweep` folder; none: look at MEASURED alone "
                          "(curves, colour strips, colour table)")
    rep.add_argument("--out", required=True, metavar="REPORT_DIR",
                     help="output directory: new or empty (an existing report only with --force)")
    add_force(rep, "an existing report in --out (report.html, metrics.json and figures/ files of those names; "
                   "other files are kept)")
    rep.add_argument("--renders", metavar="RENDER_DIR", default=None,
                     help="embed the renders of a `compare render` folder (measured and simulated side by side; "
                          "needs a SIMULATED dataset)")
    rep.add_argument("--svg", action="store_true",
                     help="also write every figure as figures/*.svg (vector)")
    rep.add_argument("--fit", action="append", default=[], metavar="FIT_DIR",
                     help="add a table of the parameters a `simulate fit` found (its --out folder: "
                          "fit.json), with their uncertainties; repeatable")
    rep.add_argument("--seed-sample", default=None, metavar="DATASET_DIR",
                     help="judge a simulated red-cotton dataset against the published colour of red "
                          "cotton at incidence 0 / observation 10 deg (printed and reported)")
    _common_arguments(rep)


def _check_arguments(chk: argparse.ArgumentParser) -> None:
    chk.add_argument("measured", metavar="MEASURED", help="measured dataset directory")
    chk.add_argument("simulated", metavar="SIMULATED", help="simulated dataset directory")
    chk.add_argument("--max-nrmse", type=_non_negative, default=DEFAULT_MAX_NRMSE, metavar="X",
                     help=f"largest overall NRMSE (default {DEFAULT_MAX_NRMSE:g})")
    chk.add_argument("--max-hue-diff", type=_non_negative, default=DEFAULT_MAX_HUE_DIFF,
                     metavar="X", help="largest |hue difference| on the circle, hue in [0, 1) "
                                       f"(default {DEFAULT_MAX_HUE_DIFF:g})")
    chk.add_argument("--allow-incomplete", action="store_true",
                     help="compare even when a dataset's meta says the run is incomplete "
                          "(\"complete\": false; by default that fails the check)")
    chk.add_argument("--max-sat-diff", type=_non_negative, default=DEFAULT_MAX_SAT_DIFF,
                     metavar="X", help=f"largest |saturation difference| "
                                       f"(default {DEFAULT_MAX_SAT_DIFF:g})")
    chk.add_argument("--max-level-ratio", type=_non_negative, default=DEFAULT_MAX_LEVEL_RATIO, metavar="X",
                     help="largest ratio between the model's absolute level and the measured one, max(k_Y, 1/k_Y) "
                          f"at the colour geometry (default {DEFAULT_MAX_LEVEL_RATIO:g}: a model scaled by 2 fails; "
                          "not judged for a relative measurement)")
    _common_arguments(chk)


# ---- compare render: one self-contained block ------------------------------------------------------
_RENDER_DESCRIPTION = ("Render each FILE.bsdf (e.g. `gonio export` of a measurement, "
                       "`simulate export` of a model) on a cushion and on a flat swatch "
                       "lit from four sides, side by side: DIR/render_sheet.png, one PNG "
                       "per image, DIR/render.json (settings, seconds). Needs the render "
                       "extra (mitsuba).")


def _render_arguments(ren: argparse.ArgumentParser) -> None:
    ren.add_argument("files", metavar="FILE.bsdf", nargs="+", help="RGL .bsdf files")
    ren.add_argument("--out", required=True, metavar="DIR", help="output folder (new, or a previous render)")
    ren.add_argument("--label", action="append", default=None, metavar="NAME",
                     help="a label per file, in order (default: the file's description)")
    ren.add_argument("--spp", type=int, default=32, help="samples per pixel (32)")
    ren.add_argument("--size", default="240x180", metavar="WxH", help="cushion image size (240x180)")
    ren.add_argument("--swatch-size", type=int, default=112, metavar="PX", help="swatch image size (112)")
    add_force(ren, "an existing render in --out (or write into a folder that holds anything)")


def _render_cmd(args) -> int:
    from compare.render import MitsubaMissing, RenderSettings, render_materials, require_mitsuba, write_render_set
    from gonio.data.formats.rgl_bsdf import read_rgl_bsdf

    out = Path(args.out)
    refuse_existing(out, args.force)
    if args.label and len(args.label) != len(args.files):
        raise CompareError(f"--label given {len(args.label)} times for {len(args.files)} files")
    try:
        w, h = (int(x) for x in args.size.lower().split("x"))
    except ValueError:
        raise CompareError(f"--size {args.size}: expected WxH, e.g. 240x180") from None
    if not (8 <= w <= 4096 and 8 <= h <= 4096 and 8 <= args.swatch_size <= 4096 and 1 <= args.spp <= 65536):
        raise CompareError("--size/--swatch-size must be 8..4096 px and --spp 1..65536")
    files = [read_rgl_bsdf(f) for f in args.files]      # a malformed file: one line naming it
    labels = args.label or [f.description[:40] or Path(f.path).stem for f in files]
    settings = RenderSettings(spp=args.spp, size=(w, h), swatch_size=args.swatch_size)
    try:
        require_mitsuba()
        images = render_materials(list(zip(labels, args.files, strict=True)), settings)
    except MitsubaMissing as exc:
        raise CompareError(str(exc)) from None
    info = write_render_set(images, out, settings)
    print(f"compare render: {len(images)} images in {info['seconds_total']:.1f} s; {out / info['sheet']}")
    return 0
# ---- end compare render -------------------------------------------------------------------------


def _report(args) -> int:
    """`compare report`.

    The arguments checked (messages naming the flags), then the same code as Python's
    :func:`fabric_optics.write_report`; prints the seed sample's check and each model's curve error.
    """
    import json

    from compare.report.samples import published_colour_check
    from compare.sweep import is_sweep_dir

    if args.renders is not None and not Path(args.renders).is_dir():
        raise CompareError(f"--renders {args.renders}: not a folder (make one with `compare render FILE.bsdf "
                           "... --out DIR`)")
    if args.renders is not None and not args.simulated:
        raise CompareError("--renders: the renders are set beside a simulation; give a SIMULATED dataset too "
                           "(compare report MEASURED SIMULATED --renders DIR)")
    refuse_existing(args.out, args.force)
    measured = api.read_dataset(args.measured)
    sweep = any(is_sweep_dir(p) for p in args.simulated)   # a `simulate sweep` directory: compare.sweep
    if sweep and len(args.simulated) > 1:
        raise CompareError("a sweep directory must be the only SIMULATED (compare report MEASURED SWEEP_DIR)")
    models = list(args.simulated) if sweep else [api.read_dataset(p) for p in args.simulated]
    if not sweep:
        for line in incomplete_datasets(measured, models):
            log.warning("%s; the report says so in a banner", printable(line))
    seed = None
    if args.seed_sample is not None and models and not sweep:
        seed = api.read_dataset(args.seed_sample)
        _, checks = published_colour_check(seed)
        print(f"seed sample '{printable(seed.name)}' against the published colour of red cotton "
              "(incidence 0, observation 10 deg):")
        for c in checks:
            print(printable(f"  {c.line()}"))
    try:
        report = api.write_report(measured, *models, out=args.out, force=args.force, fits=args.fit,
                                  seed_sample=seed, renders=args.renders, svg=args.svg,
                                  window_deg=args.normal_window, illuminant=args.illuminant)
    except OSError as exc:
        raise CompareError(f"cannot write the report into --out {args.out}: "
                           f"{exc.strerror or exc} ({exc.filename}); choose a writable "
                           "directory") from None
    if models and not sweep:
        overall = json.loads((Path(report).parent / "metrics.json").read_text(encoding="utf-8"))["overall"]
        for name, o in overall.items():
            print(printable(f"{name}: overall RMSE {o['rmse']:.4g}, NRMSE {o['nrmse']:.4g}"))
    print(f"report: {report}")
    return 0


def _check(args) -> int:
    measured = api.read_dataset(args.measured)
    simulated = api.read_dataset(args.simulated)
    incomplete = incomplete_datasets(measured, [simulated])
    if incomplete and not args.allow_incomplete:
        for line in incomplete:
            print(f"compare check: FAIL {printable(line)}; finish the run (gonio acquire --resume) or pass "
                  "--allow-incomplete")
        return 1
    for line in incomplete:
        print(f"compare check: note: {printable(line)} (compared anyway: --allow-incomplete)")
    comparison = api.compare(measured, simulated, window_deg=args.normal_window, illuminant=args.illuminant)
    verdict = api.check(comparison, max_nrmse=args.max_nrmse, max_hue_diff=args.max_hue_diff,
                        max_sat_diff=args.max_sat_diff, max_level_ratio=args.max_level_ratio)
    print(printable(f"compare check: {verdict.summary()}", newlines=True))
    name = verdict.name
    words = comparison.level(name).words(name, comparison.overall[name].nrmse, args.max_level_ratio, args.max_nrmse)
    print(printable(f"  level: {words}", newlines=True))
    return 0 if verdict.passed else 1


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="compare: %(levelname)s: %(message)s", stream=sys.stderr)


#: The ``compare`` program: its commands (:mod:`fabric_optics.cli.registry`).
PROGRAM = registry.Program(
    prog="compare",
    description="Compare simulated radiance-coefficient datasets with a measured one: "
                "normalise at the normal direction, curve errors, HSV colour match.",
    commands=(
        registry.Command("report", "write report.html, metrics.json and figures/*.png", _report_arguments, _report,
                         description="Compare one or more simulations with a measurement and "
                                     "write REPORT_DIR/report.html (self-contained), "
                                     "REPORT_DIR/metrics.json and REPORT_DIR/figures/*.png.",
                         out="folder"),
        registry.Command("check", "exit 0 when a simulation matches within thresholds, 1 otherwise",
                         _check_arguments, _check,
                         description="CI verdict: compare SIMULATED with MEASURED; exit 0 "
                                     "when within all thresholds, 1 (printing the failing "
                                     "figures) otherwise, 2 on bad input."),
        registry.Command("render", "render RGL .bsdf files with Mitsuba 3 (cushion + lit swatch)", _render_arguments,
                         _render_cmd, description=_RENDER_DESCRIPTION, out="folder"),
    ),
    user_errors=(DatasetError, CompareError),
    setup_logging=_setup_logging,
)


def build_parser() -> argparse.ArgumentParser:
    """The ``compare`` parser, every subcommand included."""
    return registry.build_parser(PROGRAM)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``compare`` command line; return the exit status."""
    return registry.main(PROGRAM, argv)


if __name__ == "__main__":
    raise SystemExit(main())
