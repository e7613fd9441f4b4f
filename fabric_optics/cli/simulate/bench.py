"""``simulate bench``: the kernel benchmark (bench.json, bench.png, a markdown table) or one study.

The work is :func:`fabric_optics.bench.suite.run_bench` and :mod:`fabric_optics.bench.studies`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fabric_optics.cli.common import (
    add_force,
)
from gonio.data.outputs import prepare_folder

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate bench``."""
    p.add_argument("--out", type=Path, required=True, help="output directory (bench.json, bench.png)")
    add_force(p)
    p.add_argument("--quick", action="store_true", help="smoke test: small runs, a few seconds")
    from fabric_optics.bench.studies import STUDIES

    p.add_argument("--study", choices=sorted(STUDIES), help="run this documented study instead of the benchmark: "
                   + "; ".join(f"{k}: {v[0]}" for k, v in sorted(STUDIES.items())) + " (OUT/NAME.json)")


def run(args: argparse.Namespace) -> int:
    """Run ``simulate bench``; return the exit status."""
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
