"""A lab session on the mock goniophotometer, compared with a simulation of the same fabric.

The embedded mock holds red cotton (an analytic stand-in with the fabric's published colour) and is
measured through the real driver over Modbus TCP and a serial pseudo-terminal; the summation model
simulates red cotton at the same plan; the comparison normalises the simulation at the normal
direction and judges curve error and colour.

    python examples/mock_vs_simulation.py OUT_DIR [--target-rel-err 0.03]

Writes OUT_DIR/measured (the acquisition) and OUT_DIR/simulated, prints the verdict, and exits 0
when the simulation matches within the default thresholds, 1 otherwise.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import fabric_optics as fo


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--target-rel-err", type=float, default=0.03)
    ap.add_argument("--plan", default="red-cotton", help="acquisition plan (preset or TOML path)")
    args = ap.parse_args(argv)

    measured = fo.measure_on_mock(args.out / "measured", sample="red-cotton", plan=args.plan)
    print(f"measured {len(measured)} values of {measured.name}")

    simulated = fo.simulate("red-cotton", plan=args.plan, method="summation", target_rel_err=args.target_rel_err,
                            seed=1)
    fo.write_dataset(simulated, args.out / "simulated")

    verdict = fo.check(fo.compare(measured, simulated))
    print(verdict.summary())
    return 0 if verdict.passed else 1


if __name__ == "__main__":
    raise SystemExit(main())
