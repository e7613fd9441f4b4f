"""A felt's dye refitted: the structure fitted once, the colour of another felt fitted alone.

The real green felt of the RGL database (``fixtures/real/acrylic_felt_green_rgb.bsdf``) is measured
on the mock goniophotometer; the ``green-felt`` preset holds the felt's structure. Only its dye is
freed (as knots started from the measured colour) and fitted by the summation model; the script
prints the fitted colour's hue and saturation differences and the curve error before and after.

    python examples/refit_felt_dye.py OUT_DIR [--max-evaluations 60] [--wavelengths 450,550,650] [--force]

``--wavelengths``: the model's wavelengths in the fit (the felt is measured in RGB; by default the
config's). A second run into OUT_DIR needs ``--force`` (it replaces the measurement and the fit).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import fabric_optics as fo
from fabric_optics.cli.common import wavelengths_arg

FELT = Path(__file__).resolve().parents[1] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"


def main(argv: list[str] | None = None) -> int:
    """Measure the felt on the mock, fit only its dye by the summation model, and print the colour and curve errors.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``OUT_DIR``, ``--sample``, ``--max-evaluations``, ``--target-rel-err``,
        ``--wavelengths``, ``--force``); ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0 after the fit, 2 when OUT_DIR holds an earlier run and ``--force`` is not given (nothing is
        measured then).
    """
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--sample", default=str(FELT), help="RGL .bsdf file or dataset to measure on the mock")
    ap.add_argument("--max-evaluations", type=int, default=None)
    ap.add_argument("--target-rel-err", type=float, default=0.03)
    ap.add_argument("--wavelengths", type=wavelengths_arg, default=None, metavar="NM,NM,...|START:STOP:STEP",
                    help="model wavelengths of the fit in nm (default: the config's)")
    ap.add_argument("--force", action="store_true", help="replace OUT_DIR's measurement and fit of an earlier run")
    args = ap.parse_args(argv)

    for sub in ("measured", "fit"):             # refused before anything is measured
        folder = args.out / sub
        if not args.force and folder.is_dir() and any(folder.iterdir()):
            print(f"refit_felt_dye: {folder} holds an earlier run; pass --force to replace it, or choose "
                  "another OUT_DIR", file=sys.stderr)
            return 2
    measured = fo.measure_on_mock(args.out / "measured", sample=args.sample, plan="green-felt", force=args.force)
    outcome = fo.fit("green-felt", measured, "dye", args.out / "fit", method="summation", dye="knots",
                     max_evaluations=args.max_evaluations, target_rel_err=args.target_rel_err,
                     wavelengths_nm=args.wavelengths, force=args.force)
    for key in ("start", "fitted"):
        c = outcome.summary[key]
        colour = f", dh {c['dh']:+.4f} turn, ds {c['ds']:+.4f}" if "dh" in c else ""
        print(f"{key:>7}: NRMSE {c['nrmse']:.4f}{colour}")
    print(f"fitted config: {outcome.out / 'fitted.toml'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
