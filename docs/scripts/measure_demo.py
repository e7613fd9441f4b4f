"""Measure ``make demo`` (wall time, CPU time, peak memory) and record it as docs/data/demo.json.

    python docs/scripts/measure_demo.py [--conditions "fresh clone, idle machine"]
    python docs/scripts/render_figures.py        # then put the figures into README.md and the manual

Peak memory is the largest resident set of any one process of the run (``getrusage`` of the waited-for
children, as ``/usr/bin/time -v`` reports it). Run it from a fresh clone on an otherwise idle machine:
that is what the README's cost figure promises a new user.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_figures import ROOT, record  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conditions", default="", help="how the run was made, e.g. 'fresh clone, idle machine'")
    args = ap.parse_args(argv)
    start = time.monotonic()
    code = subprocess.call(["make", "demo"], cwd=ROOT)
    wall = time.monotonic() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    if code != 0:
        print(f"measure_demo: make demo exited {code}; nothing recorded", file=sys.stderr)
        return code
    data = {"wall_seconds": round(wall, 1), "cpu_seconds": round(usage.ru_utime + usage.ru_stime, 1),
            "peak_rss_mb": round(usage.ru_maxrss / 1024, 1), "conditions": args.conditions}
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
        json.dump(data, f)
    print(record("demo", Path(f.name), "make demo"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
