"""Measure ``make demo`` (wall time, CPU time, peak memory, each step's time) and record it as docs/data/demo.json.

    python docs/scripts/measure_demo.py [--conditions "fresh clone, idle machine"]
    python docs/scripts/measure_demo.py --again [--conditions "..."]   # then a second run in the same clone
    python docs/scripts/render_figures.py        # then put the figures into README.md and the manual

The run is ``make demo`` step by step: ``make venv`` (the virtual environment; nothing to do when it
exists), then each command of the demo's recipe as ``make -n demo`` prints it, run by ``sh -c`` in the
repository, in order, stopping at the first that fails. Each step's wall time and peak memory are
recorded, and its CPU time (``cpu_steps``: user + system of the line's processes); a line of steps side by
side (the recipe runs independent steps two at a time) is one step, named after both. Peak memory is the
largest resident set of any one process (``wait4``'s resource usage of the
step's shell, which covers its waited-for children, as ``/usr/bin/time -v`` reports it). Run it from a
fresh clone on an otherwise idle machine: that is what the README's cost figure promises a new user.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[2]))   # the checkout: render_figures reads the machine from it
from render_figures import ROOT, record  # noqa: E402

#: what ``make demo`` builds of the environment: the project without the test and docs extras (Makefile, BASE_STAMP)
DEMO_ENV = ".venv/.installed-base-stamp"
#: the name of that step in docs/data/demo.json
ENV_STEP = "the environment (the project alone)"


def recipe() -> list[str]:
    """The shell commands of ``make demo``, in order (``make -n``: printed, not run).

    Returns
    -------
    list of str
        The recipe's command lines, without blank lines and ``echo`` lines; the environment's build
        is left out (measured as its own step).
    """
    # -o: the environment counts as built (measure_demo builds it first, as its own step)
    done = subprocess.run(["make", "-s", "-n", "-o", DEMO_ENV, "demo"], cwd=ROOT,
                          capture_output=True, text=True, check=True)
    return [line for line in done.stdout.splitlines() if line.strip() and not line.lstrip().startswith("echo ")]


#: the recipe's mark of two steps side by side: ``A & beside=$!; B ...; wait $beside`` (A in the background)
BESIDE = " & beside=$!; "


def _program_names(command: str) -> list[str]:
    """The short names of the project commands in one shell command line, in order (:func:`step_name`)."""
    lex = shlex.shlex(command, posix=True, punctuation_chars=True)
    lex.whitespace_split = True
    names: list[str] = []
    words: list[str] = []
    for token in [*lex, ";"]:
        if token in ("&", "&&", ";", "||", "|", "(", ")"):
            if words and Path(words[0]).name in ("gonio", "simulate", "compare"):
                name = " ".join([Path(words[0]).name, *words[1:2]])
                if "--method" in words:
                    name += f" --method {words[words.index('--method') + 1]}"
                names.append(name)
            words = []
        else:
            words.append(token)
    return names


def step_name(command: str) -> str:
    """A short name of one demo command: its program, subcommand and method, e.g. ``simulate fit --method mc``.

    A line of steps side by side (:data:`BESIDE`) names the foreground's steps (``+``) and then the one
    beside them, e.g. ``gonio demo beside simulate fabric --method summation``.

    Parameters
    ----------
    command : str
        One command line of the recipe.

    Returns
    -------
    str
        The name the step is recorded under in docs/data/demo.json.
    """
    background, _, foreground = command.rpartition(BESIDE)
    name = " + ".join(_program_names(foreground))
    if background:
        name += " beside " + " + ".join(_program_names(background))
    return name


def timed(argv: list[str]) -> tuple[int, float, float, float]:
    """Run ``argv`` in the repository: exit code, wall seconds, CPU seconds, peak RSS in MB.

    Parameters
    ----------
    argv : list of str
        The program and its arguments.

    Returns
    -------
    tuple of (int, float, float, float)
        The exit code, the wall seconds, the CPU seconds (user and system of the process and its
        waited-for children) and the largest resident set of any one of them (MB).
    """
    start = time.monotonic()
    proc = subprocess.Popen(argv, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return (proc.returncode, time.monotonic() - start, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024)


def main(argv: list[str] | None = None) -> int:
    """Run ``make demo`` step by step, timing each, and record the figures (docs/data/demo.json).

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--conditions``, ``--again``); ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0 when every step ran and the figures are recorded; else the exit code of the step that failed
        (nothing is recorded then).
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--conditions", default="", help="how the run was made, e.g. 'fresh clone, idle machine'")
    ap.add_argument("--again", action="store_true",
                    help="measure a second run in the same clone (its caches warm, its outputs there) and add it to "
                         "docs/data/demo.json as second_run, keeping the first run's figures")
    args = ap.parse_args(argv)
    steps: dict[str, float] = {}
    cpu_steps: dict[str, float] = {}
    totals = [0.0, 0.0, 0.0]  # wall, CPU, peak RSS

    def step(label: str, cmd: list[str]) -> int:
        """Time one step and add it to the figures; its exit code (a failed step is not added)."""
        code, secs, cpus, rss = timed(cmd)
        if code != 0:
            print(f"measure_demo: `{label}` exited {code}; nothing recorded", file=sys.stderr)
            return code
        while label in steps:
            label += " (again)"
        steps[label] = round(secs, 1)
        cpu_steps[label] = round(cpus, 1)
        totals[:] = [totals[0] + secs, totals[1] + cpus, max(totals[2], rss)]
        return 0

    # the recipe is read once the environment exists (before, make -n would list its build)
    if code := step(ENV_STEP, ["make", "-s", DEMO_ENV]):
        return code
    for command in recipe():
        print(command, flush=True)
        if code := step(step_name(command), ["sh", "-c", command]):
            return code
    wall, cpu, peak = totals
    data = {"wall_seconds": round(wall, 1), "cpu_seconds": round(cpu, 1), "peak_rss_mb": round(peak, 1),
            "steps": steps, "cpu_steps": cpu_steps, "conditions": args.conditions}
    if args.again:
        path = ROOT / "docs" / "data" / "demo.json"
        rec = json.loads(path.read_text(encoding="utf-8"))
        rec["data"]["second_run"] = data
        path.write_text(json.dumps(rec, indent=1) + "\n", encoding="utf-8")
        print(path)
        return 0
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
        json.dump(data, f)
    print(record("demo", Path(f.name), "make demo"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
