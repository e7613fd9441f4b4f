"""A felt's dye refitted: the structure fitted once, the colour of another felt fitted alone.

The real green felt of the RGL database (``fixtures/real/acrylic_felt_green_rgb.bsdf``) is measured
on the mock goniophotometer; the ``green-felt`` preset holds the felt's structure. Only its dye is
freed (as knots started from the measured colour) and fitted by the summation model; the script
prints the fitted colour's hue and saturation differences and the curve error before and after.

    python examples/refit_felt_dye.py OUT_DIR [--max-evaluations 60] [--wavelengths 450,550,650]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import fabric_optics as fo

FELT = Path(__file__).resolve().parents[1] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--sample", default=str(FELT), help="RGL .bsdf file or dataset to measure on the mock")
    ap.add_argument("--max-evaluations", type=int, default=None)
    ap.add_argument("--target-rel-err", type=float, default=0.03)
    args = ap.parse_args(argv)

    measured = fo.measure_on_mock(args.out / "measured", sample=args.sample, plan="green-felt")
    outcome = fo.fit("green-felt", measured, "dye", args.out / "fit", method="summation", dye="knots",
                     max_evaluations=args.max_evaluations, target_rel_err=args.target_rel_err)
    for key in ("start", "fitted"):
        c = outcome.summary[key]
        colour = f", dh {c['dh']:+.4f} turn, ds {c['ds']:+.4f}" if "dh" in c else ""
        print(f"{key:>7}: NRMSE {c['nrmse']:.4f}{colour}")
    print(f"fitted config: {outcome.out / 'fitted.toml'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
