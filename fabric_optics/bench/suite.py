"""``simulate bench``: throughput and cost growth of the Monte Carlo kernel (docs/quality.md C).

Measured on the van de Hulst slab case (n = 1, mu_a = 10/cm, mu_s = 90/cm, g = 0.75,
d = 0.02 cm; MCML manual Table 6.1):

* one thread and all threads, run alternately (side by side, the machine being noisy), after
  a warm-up call that compiles or loads the kernel; medians of 7 repeats (quick: 5) of photons/s,
  events per photon and ns per event; the speed-up is the median of the paired ratios;
* the cold compile time (first call in a fresh interpreter with an empty numba cache);
* (not with ``--quick``) whole ``simulate slab`` processes: start-up with a cold and a warm numba
  cache, and the MCML-style case (van de Hulst slab, 3e7 photons, one thread) to set beside
  ``time mcml`` of the user's own MCML build;
* time vs photons (expected linear: fitted log-log slope ~1);
* time vs optical thickness ``mu_t d`` at the same albedo and g;
* the peak resident set size of the process;
* (not with ``--quick``) the fiber BRDF routes, :mod:`fabric_optics.bench.fiber`, the woven-fabric
  Monte Carlo, :mod:`fabric_optics.bench.woven`, and ``simulate fabric red-cotton`` at 1 % by
  summation and Monte Carlo (cold and warm table cache), whole processes and in process,
  :mod:`fabric_optics.bench.fabric`; the Monte Carlo's achieved error against its marginal cost,
  :mod:`fabric_optics.bench.speed_accuracy` (``speed-accuracy.png``).

Writes ``DIR/bench.json`` and ``DIR/bench.png`` (matplotlib, Agg); :func:`markdown_table`
formats the headline figures.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numba
import numpy as np

from simulate.montecarlo import run_slab

__all__ = ["VAN_DE_HULST", "run_bench", "markdown_table"]

log = logging.getLogger(__name__)

VAN_DE_HULST: dict[str, Any] = {"mu_a": 10.0, "mu_s": 90.0, "g": 0.75, "n": 1.0, "thickness": 0.02}

_COLD_SNIPPET = (
    "import time; t = time.perf_counter()\n"
    "from simulate.montecarlo import run_slab\n"
    "t1 = time.perf_counter()\n"
    "run_slab(10.0, 90.0, g=0.75, n=1.0, thickness=0.02, photons=1000, seed=0)\n"
    "t2 = time.perf_counter()\n"
    "print(t1 - t, t2 - t1)\n"
)


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def _cold_compile_seconds() -> dict[str, float] | None:
    """Import and first-call times in a fresh interpreter with an empty numba cache."""
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        try:
            proc = subprocess.run(
                [sys.executable, "-c", _COLD_SNIPPET], env=env, capture_output=True, text=True,
                timeout=600, check=True,
            )
        except (subprocess.SubprocessError, OSError) as exc:
            log.warning("cold compile measurement failed: %s", exc)
            return None
    import_s, first_call_s = (float(v) for v in proc.stdout.split())
    return {"import_seconds": import_s, "first_call_seconds": first_call_s}


#: the MCML-style whole-process case: ``simulate slab`` as a user runs it, one thread, van de Hulst slab
MCML_CASE_PHOTONS = 30_000_000


def _slab_command(photons: int, threads: int | None = None) -> list[str]:
    case = VAN_DE_HULST
    cmd = [sys.executable, "-m", "fabric_optics.cli.simulate", "slab", "--mua", str(case["mu_a"]), "--mus", str(case["mu_s"]),
           "--g", str(case["g"]), "--n", str(case["n"]), "--thickness", str(case["thickness"]),
           "--photons", str(photons), "--json"]
    return cmd + (["--threads", str(threads)] if threads else [])


def _timed_process(cmd: list[str], env: dict[str, str]) -> dict[str, Any]:
    """Wall and CPU seconds of one whole process (its JSON output kept)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return {"wall_seconds": wall, "cpu_seconds": cpu, "result": json.loads(proc.stdout)}


def _whole_process(repeats: int = 5) -> dict[str, Any] | None:
    """Whole ``simulate slab`` processes (in-process timings miss start-up and recompiles).

    Start-up: a tiny run (10^3 photons) with an empty numba cache (cold: compiles) and then
    ``repeats`` times on that cache (warm: loads; median). The MCML-style case: the van de Hulst
    slab, :data:`MCML_CASE_PHOTONS` photons, one thread, warm cache (median of 3) -- compare with
    ``time mcml`` on the same slab (MCML 1.2.2 is not part of this project).
    """
    with tempfile.TemporaryDirectory(prefix="numba-whole-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        try:
            cold = _timed_process(_slab_command(1000), env)
            warm = [_timed_process(_slab_command(1000), env) for _ in range(repeats)]
            mcml = [_timed_process(_slab_command(MCML_CASE_PHOTONS, threads=1), env) for _ in range(3)]
        except (subprocess.SubprocessError, OSError, ValueError) as exc:
            log.warning("whole-process measurement failed: %s", exc)
            return None
    last = mcml[-1]["result"]
    return {
        "startup_cold_seconds": cold["wall_seconds"],
        "startup_warm_median_seconds": float(statistics.median(r["wall_seconds"] for r in warm)),
        "startup_warm_median_cpu_seconds": float(statistics.median(r["cpu_seconds"] for r in warm)),
        "startup_warm_runs": [r["wall_seconds"] for r in warm],
        "mcml_case": {"photons": MCML_CASE_PHOTONS, "threads": 1,
                      "median_wall_seconds": float(statistics.median(r["wall_seconds"] for r in mcml)),
                      "median_cpu_seconds": float(statistics.median(r["cpu_seconds"] for r in mcml)),
                      "Rd": last["Rd"], "u_Rd": last["u_Rd"], "Tt": last["Tt"], "u_Tt": last["u_Tt"]},
    }


def _run(threads: int, photons: int, seed: int, **case: Any) -> dict[str, float]:
    r = run_slab(photons=photons, seed=seed, threads=threads, **case)
    events = r.events_per_photon * r.photons
    return {
        "photons": r.photons,
        "seconds": r.seconds,
        "photons_per_s": r.photons / r.seconds,
        "events_per_photon": r.events_per_photon,
        "ns_per_event": r.seconds / events * 1e9,
        "Rd": r.Rd,
        "Tt": r.Tt,
        "u_Rd": r.u_Rd,
        "u_Tt": r.u_Tt,
    }


def _median(rows: list[dict[str, float]], key: str) -> float:
    return float(statistics.median(row[key] for row in rows))


def run_bench(out: Path, quick: bool = False) -> dict[str, Any]:
    """Run the kernel benchmark and write ``out/bench.json`` and ``out/bench.png``.

    Parameters
    ----------
    out : pathlib.Path
        Existing output directory.
    quick : bool
        Small runs (a smoke test of a few seconds); the cold compile is then skipped.

    Returns
    -------
    dict
        The report written to ``bench.json``.
    """
    max_threads = numba.config.NUMBA_NUM_THREADS
    repeats = 5 if quick else 7
    photons = 200_000 if quick else 4_000_000  # one-thread runs long against the timer (docs/reference/figures.md)
    t0 = time.perf_counter()
    run_slab(photons=1000, seed=0, threads=1, **VAN_DE_HULST)
    warmup = time.perf_counter() - t0

    one: list[dict[str, float]] = []
    many: list[dict[str, float]] = []
    for rep in range(repeats):
        one.append(_run(1, photons, rep, **VAN_DE_HULST))
        many.append(_run(max_threads, photons, rep, **VAN_DE_HULST))
    ratios = [m["photons_per_s"] / o["photons_per_s"] for o, m in zip(one, many, strict=True)]

    def summary(rows: list[dict[str, float]], threads: int) -> dict[str, Any]:
        return {
            "threads": threads,
            "photons_per_run": photons,
            "repeats": len(rows),
            "median_photons_per_s": _median(rows, "photons_per_s"),
            "median_photons_per_s_per_thread": _median(rows, "photons_per_s") / threads,
            "median_seconds": _median(rows, "seconds"),
            "median_events_per_photon": _median(rows, "events_per_photon"),
            "median_ns_per_event": _median(rows, "ns_per_event"),
            "runs": rows,
        }

    throughput = {
        "case": dict(VAN_DE_HULST, reference_Rd=0.09739, reference_Tt=0.66096),
        "one_thread": summary(one, 1),
        "all_threads": summary(many, max_threads),
        "speedup_median_of_paired_ratios": float(statistics.median(ratios)),
        "speedup_paired_ratios": ratios,
    }

    # time vs photons (linear growth expected)
    counts = [50_000, 100_000, 200_000, 400_000] if quick else [100_000, 300_000, 1_000_000, 3_000_000]
    scaling = [_run(max_threads, c, 0, **VAN_DE_HULST) for c in counts]
    slope = float(np.polyfit(np.log(counts), np.log([s["seconds"] for s in scaling]), 1)[0])

    # time vs optical thickness at albedo 0.9, g = 0.75
    taus = [0.1, 1.0, 10.0, 100.0]
    tau_photons = 20_000 if quick else 200_000
    thickness_rows = []
    for tau in taus:
        row = _run(max_threads, tau_photons, 0, mu_a=0.1 * tau, mu_s=0.9 * tau, g=0.75, n=1.0, thickness=1.0)
        row["optical_thickness"] = tau
        row["seconds_per_photon"] = row["seconds"] / row["photons"]
        thickness_rows.append(row)

    cold = None if quick else _cold_compile_seconds()
    whole = None if quick else _whole_process()

    report: dict[str, Any] = {
        "schema": "simulate-bench/1",
        "quick": quick,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": {
            "cpus": os.cpu_count(),
            "numba_threads": max_threads,
            "threading_layer": numba.threading_layer(),
            "python": platform.python_version(),
            "numba": numba.__version__,
            "platform": platform.platform(),
        },
        "warmup_seconds": warmup,
        "cold_compile": cold,
        "whole_process": whole,
        "throughput": throughput,
        "time_vs_photons": {"runs": scaling, "loglog_slope": slope, "threads": max_threads},
        "time_vs_optical_thickness": {"runs": thickness_rows, "albedo": 0.9, "g": 0.75, "threads": max_threads},
        "peak_rss_mb": _peak_rss_mb(),
    }
    if not quick:
        # the fiber routes (fabric_optics.bench.fiber): the next-event + white headline and the three
        # routes side by side; skipped by --quick (it takes minutes)
        from fabric_optics.bench.fiber import chart, run_fiber_bench

        report["fiber"] = run_fiber_bench()
        chart(report["fiber"], out / "fiber.png")
        # the woven-fabric Monte Carlo (fabric_optics.bench.woven): ray engine, red-cotton headline,
        # where summation and classic depart from it
        from fabric_optics.bench import woven as bench_woven

        report["woven"] = bench_woven.run_woven_bench()
        bench_woven.chart(report["woven"], out / "woven.png")
        bench_woven.chart_cost_growth(report["woven"], out / "cost-growth.png")
        # the Monte Carlo's achieved error against its marginal cost, red cotton and the felt
        from fabric_optics.bench import speed_accuracy

        report["speed_accuracy"] = speed_accuracy.run_speed_accuracy()
        speed_accuracy.chart(report["speed_accuracy"], out / "speed-accuracy.png")
        # simulate fabric red-cotton at 1 % against its time targets: summation, mc cold / warm table cache
        from fabric_optics.bench.fabric import run_fabric_bench

        report["fabric"] = run_fabric_bench()
    (out / "bench.json").write_text(json.dumps(report, indent=2))
    _chart(report, out / "bench.png")
    return report


def _chart(report: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    tp = report["throughput"]
    labels = ["1 thread", f"{tp['all_threads']['threads']} threads"]
    for i, key in enumerate(("one_thread", "all_threads")):
        values = [r["photons_per_s"] / 1e6 for r in tp[key]["runs"]]
        axes[0].scatter([i] * len(values), values, color="0.5", s=12, zorder=3)
        axes[0].bar(i, tp[key]["median_photons_per_s"] / 1e6, color=("C0", "C1")[i], alpha=0.7)
    axes[0].axhline(5.0, color="k", ls="--", lw=1, label="target 5 M/s per core")
    axes[0].set_xticks([0, 1], labels)
    axes[0].set_ylabel("M photons / s (median, dots: runs)")
    axes[0].set_title(f"van de Hulst slab; speed-up {tp['speedup_median_of_paired_ratios']:.2f}x")
    axes[0].legend(loc="lower right", fontsize=8)

    runs = report["time_vs_photons"]["runs"]
    axes[1].loglog([r["photons"] for r in runs], [r["seconds"] for r in runs], "o-")
    axes[1].set_xlabel("photons")
    axes[1].set_ylabel("kernel time / s")
    axes[1].set_title(f"time vs photons (log-log slope {report['time_vs_photons']['loglog_slope']:.2f})")

    rows = report["time_vs_optical_thickness"]["runs"]
    taus = [r["optical_thickness"] for r in rows]
    axes[2].loglog(taus, [r["seconds_per_photon"] * 1e9 for r in rows], "o-", label="ns / photon")
    axes[2].loglog(taus, [r["events_per_photon"] for r in rows], "s--", label="events / photon")
    axes[2].set_xlabel("optical thickness mu_t d (albedo 0.9, g 0.75)")
    axes[2].set_title("cost vs optical thickness")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown_table(report: dict[str, Any]) -> str:
    """Headline figures of a :func:`run_bench` report as a markdown table."""
    tp = report["throughput"]
    o, m = tp["one_thread"], tp["all_threads"]
    cold = report.get("cold_compile")
    lines = [
        "| figure | value |",
        "|---|---|",
        f"| 1 thread, median M photons/s | {o['median_photons_per_s'] / 1e6:.2f} |",
        f"| {m['threads']} threads, median M photons/s | {m['median_photons_per_s'] / 1e6:.2f} |",
        f"| speed-up {m['threads']} / 1 thread (median of paired runs) | {tp['speedup_median_of_paired_ratios']:.2f}x |",
        f"| events / photon | {o['median_events_per_photon']:.3f} |",
        f"| ns / event (1 thread) | {o['median_ns_per_event']:.1f} |",
        f"| time vs photons, log-log slope | {report['time_vs_photons']['loglog_slope']:.3f} |",
        f"| warm-up (first call, cache as found) | {report['warmup_seconds']:.2f} s |",
        "| cold compile (empty cache, first call) | "
        + (f"{cold['first_call_seconds']:.2f} s (+ import {cold['import_seconds']:.2f} s) |" if cold else "not measured |"),
        f"| peak RSS | {report['peak_rss_mb']:.0f} MB |",
    ]
    whole = report.get("whole_process")
    if whole:
        mc = whole["mcml_case"]
        lines += [
            f"| whole process `simulate slab`, 10^3 photons: cold / warm cache (median) | "
            f"{whole['startup_cold_seconds']:.2f} s / {whole['startup_warm_median_seconds']:.2f} s |",
            f"| whole process, {mc['photons']:.0e} photons, 1 thread (MCML-style case; median wall, CPU) | "
            f"{mc['median_wall_seconds']:.2f} s, {mc['median_cpu_seconds']:.2f} s CPU; Rd {mc['Rd']:.5f} +- "
            f"{mc['u_Rd']:.5f}, Tt {mc['Tt']:.5f} +- {mc['u_Tt']:.5f} |",
        ]
    first = o["runs"][0]
    lines.append(
        f"| Rd, Tt (1 thread, run 1; reference 0.09739, 0.66096) | {first['Rd']:.5f} +- {first['u_Rd']:.5f}, "
        f"{first['Tt']:.5f} +- {first['u_Tt']:.5f} |"
    )
    if "woven" in report:
        from fabric_optics.bench.woven import markdown as woven_markdown

        lines += ["", "woven-fabric Monte Carlo:", "", woven_markdown(report["woven"])]
    if "fabric" in report:
        from fabric_optics.bench.fabric import markdown as fabric_markdown

        lines += ["", "simulate fabric (whole processes and in process):", "", fabric_markdown(report["fabric"])]
    return "\n".join(lines)
