"""What the summation fit's surface parameter costs: per evaluation and per fit, against a dye-only fit.

    gonio demo --sample fixtures/real/acrylic_felt_green_rgb.bsdf --plan measured --out DIR/measured --no-progress
    python docs/scripts/summation_fit_cost.py DIR/measured --json DIR/summation-fit-cost.json [--before TREE]

The demo's summation fit (green-felt, ``--dye knots``, 800 evaluations at most, 3 % target) with ``--free
dye,rms_slope`` (the demo's), ``--free rms_slope`` and ``--free dye``. Per evaluation: the CPU seconds of the fit
problem's residuals (:meth:`fabric_optics.fitting.problem.FitProblem.residuals`) over a sequence of points that
change the dye only, and over one that moves the RMS slope by 2.5 % in ``log`` at every point (a new point of the
surface lattice each time, :data:`fabric_optics.fitting.problem.SURFACE_LATTICE_STEP`), after a first evaluation
that reads the walk. Per fit: ``simulate fit`` under ``/usr/bin/time`` (CPU seconds, wall, peak memory).

``--before TREE`` (and ``--after TREE``, default this one): the same measurements of another source tree (a checkout of an earlier commit, run with
``PYTHONPATH=TREE`` in this environment), alternating with this tree's, run for run; the figures are the minimum of
``--repeats`` runs (the machine may be shared). Every run reads the same walk from one table cache
(``FABRIC_OPTICS_CACHE_DIR``: ``DIR/cost-cache``, filled by a first fit before any run is timed): warm caches.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: the fits timed: label, ``--free``
FITS = (("dye_rms_slope", "dye,rms_slope"), ("rms_slope", "rms_slope"), ("dye", "dye"))
FIT_ARGS = ("--method", "summation", "--dye", "knots", "--max-evaluations", "800", "--target-rel-err", "0.03",
            "--no-progress", "--force")
#: evaluations per sequence of the per-evaluation figures
EVALUATIONS = 60


def _problem(measured: str, free: str) -> object:
    """The demo summation fit's problem for the measurement ``measured`` with ``--free free``."""
    from fabric_optics import api

    with tempfile.TemporaryDirectory() as tmp:
        job = api.prepare_fit("green-felt", measured, free, Path(tmp) / "fit", method="summation", dye="knots",
                              target_rel_err=0.03, force=True)
    return job.problem


def evaluations(measured: str, n: int) -> dict:
    """CPU seconds per evaluation of the demo fit's problem, and per evaluation of each fit's search.

    Dye-only steps, and RMS-slope steps (each a new point of the surface lattice), after one evaluation
    that reads the walk; then each fit's search (:func:`fabric_optics.fitting.search.search_fit`, the
    walk read before it) over its evaluations.

    Parameters
    ----------
    measured : str
        The demo's acquisition folder.
    n : int
        Evaluations per sequence (dye steps, RMS-slope steps).

    Returns
    -------
    dict
        ``first_s`` (the evaluation that reads the walk), per sequence the mean, median and total CPU
        seconds, and per fit of :data:`FITS` its search's CPU seconds, evaluations and their quotient.
    """
    import numpy as np

    from fabric_optics.fitting.search import search_fit

    problem = _problem(measured, "dye,rms_slope")
    free = list(problem.free)
    x0 = np.array([p.start for p in free])
    dye = [i for i, p in enumerate(free) if p.kind == "dye"]
    slope = [i for i, p in enumerate(free) if p.kind == "surface"][0]
    c = time.process_time()
    problem.residuals(x0)
    first = time.process_time() - c
    rng = np.random.default_rng(0)
    out: dict = {"first_s": first}
    for label in ("dye", "rms_slope"):
        times = []
        for k in range(1, n + 1):
            x = x0.copy()
            if label == "dye":
                x[dye] -= rng.uniform(0.0, 0.1, len(dye))   # below the start: within the table's absorption
            else:
                x[slope] = x0[slope] * np.exp(-0.025 * k)
            c = time.process_time()
            problem.residuals(x)
            times.append(time.process_time() - c)
        out[label] = {"evaluations": n, "mean_s": float(np.mean(times)), "median_s": float(np.median(times)),
                      "total_s": float(np.sum(times))}
    out["search"] = {}
    for label, free_names in FITS:
        problem = _problem(measured, free_names)
        problem.table(problem.config_at(np.array([p.start for p in problem.free])))   # the walk, read
        c = time.process_time()
        search_fit(problem, max_evaluations=800)
        cpu = time.process_time() - c
        evals = problem.counters.evaluations
        out["search"][label] = {"cpu_s": cpu, "evaluations": evals, "per_evaluation_s": cpu / evals}
    return out


def _env(tree: str | None, cache: Path) -> dict:
    """The environment of a run of ``tree`` (this one when None) with the shared table cache ``cache``."""
    env = dict(os.environ, FABRIC_OPTICS_CACHE_DIR=str(cache))
    if tree is not None:
        env["PYTHONPATH"] = tree
    else:
        env.pop("PYTHONPATH", None)
    return env


def _per_evaluation(tree: str | None, measured: str, cache: Path) -> dict:
    """:func:`evaluations` of the source tree ``tree``, run in a process of its own."""
    got = subprocess.run([sys.executable, __file__, measured, "--evaluations-only"], env=_env(tree, cache),
                         check=True, capture_output=True, text=True, cwd=tree or ROOT)
    return json.loads(got.stdout.strip().splitlines()[-1])


def _fit(tree: str | None, measured: str, cache: Path, free: str, out: Path) -> dict:
    """One ``simulate fit`` of ``tree`` under ``/usr/bin/time``: its CPU, wall, peak memory, evaluations, NRMSE and values."""
    simulate = Path(sys.executable).parent / "simulate"
    cmd = ["/usr/bin/time", "-f", "%U %S %e %M", str(simulate), "fit", "green-felt", measured, "--free", free,
           "--out", str(out), *FIT_ARGS]
    got = subprocess.run(cmd, env=_env(tree, cache), capture_output=True, text=True, cwd=tree or ROOT)
    if got.returncode not in (0, 3):
        raise RuntimeError(f"{' '.join(cmd)}: exit {got.returncode}\n{got.stderr[-2000:]}")
    user, system, wall, rss = got.stderr.strip().splitlines()[-1].split()
    summary = json.loads((out / "fit.json").read_text())
    info = summary.get("info", {})
    return {"cpu_s": round(float(user) + float(system), 2), "wall_s": float(wall), "max_rss_mb": int(rss) // 1024,
            "evaluations": info.get("evaluations"), "nrmse": summary.get("fitted", {}).get("nrmse"),
            "x": [p["value"] for p in summary.get("parameters", [])]}


def main(argv: list[str] | None = None) -> int:
    """Measure the per-evaluation and per-fit costs of this tree (and of ``--before``), and write them as JSON.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (the measurement, ``--json``, ``--before``, ``--after``, ``--repeats``);
        ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0; argparse exits 2 without ``--json``, and a fit that fails raises RuntimeError with its
        command and the end of its error output.
    """
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("measured", help="the demo's acquisition (gonio demo --plan measured)")
    ap.add_argument("--json", help="output file")
    ap.add_argument("--before", help="another source tree, measured alternately with this one")
    ap.add_argument("--after", help="the source tree measured as 'after' (default: this one)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--evaluations-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    measured = str(Path(args.measured).resolve())
    if args.evaluations_only:
        print(json.dumps(evaluations(measured, EVALUATIONS)), flush=True)
        return 0
    if not args.json:
        ap.error("--json is required")
    from simulate.provenance import machine

    work = Path(args.json).resolve().parent
    cache = work / "cost-cache"
    after = None if args.after is None else str(Path(args.after).resolve())
    trees = {"after": after} if args.before is None else {"before": str(Path(args.before).resolve()), "after": after}
    _fit(after, measured, cache, "dye", work / "cost-fit-warm")      # fills the table cache: the walk
    runs: dict = {name: {"per_evaluation": [], "fits": {label: [] for label, _ in FITS}} for name in trees}
    for r in range(args.repeats):
        for name, tree in trees.items():
            runs[name]["per_evaluation"].append(_per_evaluation(tree, measured, cache))
            for label, free in FITS:
                runs[name]["fits"][label].append(_fit(tree, measured, cache, free, work / f"cost-fit-{label}"))
            print(name, r, json.dumps(runs[name]["per_evaluation"][-1]), flush=True)
    figures: dict = {}
    for name, got in runs.items():
        per = got["per_evaluation"]
        figures[name] = {
            "per_evaluation_cpu_s": {label: min(p[label]["mean_s"] for p in per) for label in ("dye", "rms_slope")},
            "search_per_evaluation_cpu_s": {label: min(p["search"][label]["per_evaluation_s"] for p in per)
                                            for label, _ in FITS},
            "search_cpu_s": {label: min(p["search"][label]["cpu_s"] for p in per) for label, _ in FITS},
            "search_evaluations": {label: per[0]["search"][label]["evaluations"] for label, _ in FITS},
            "fits": {label: {key: min(f[key] for f in fits)
                             if key in ("cpu_s", "wall_s", "max_rss_mb") else fits[0][key]
                             for key in fits[0]} for label, fits in got["fits"].items()}}
    out = {"name": "summation-fit-cost",
           "command": "python docs/scripts/summation_fit_cost.py DIR/measured --json DIR/summation-fit-cost.json"
                      + ("" if args.before is None else " --before TREE") + ("" if args.after is None else " --after TREE"),
           "fit_command": "simulate fit green-felt DIR/measured --free FREE " + " ".join(FIT_ARGS[:-2]) + " --out DIR",
           "note": (f"minimum of {args.repeats} runs{' alternating with the other tree' if args.before else ''}; "
                    "per evaluation: CPU seconds (time.process_time) of FitProblem.residuals, mean over "
                    f"{EVALUATIONS} points per sequence (dye: the knots moved; rms_slope: the slope moved 2.5 % in "
                    "log per point, a new lattice point each); search: CPU seconds of each fit's search_fit (the "
                    "walk read before) over its evaluations; per fit: /usr/bin/time user + system CPU seconds, "
                    "wall, peak RSS; one warm table cache for every run"),
           "machine": machine(), "figures": figures, "runs": runs}
    Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
