"""``simulate bench``: ``simulate fabric red-cotton`` at 1 % as a user runs it, against time targets.

Whole processes (start-up, imports, kernel loading and the table cache included; in-process
timings miss them), median of 3, wall and CPU seconds (the children's ``getrusage``), the
achieved ``rel_err`` each run printed (its ``meta.json``, the one definition of
:func:`simulate.montecarlo.accuracy.relative_error`) and the load average around each run
(the machine is shared; a figure without its load is not comparable):

* ``summation`` on an empty table cache per run (its exit tables are cached, keyed with the dye);
* ``mc`` with a cold table cache (an empty ``FABRIC_OPTICS_CACHE_DIR`` per run: the yarn
  tables are computed) and a warm one (the tables of the first cold run loaded);

run interleaved (summation, mc cold, mc warm, then again) so a change of load spreads over all
three. Then the same three once in this process (imports and kernels warm): the difference is
the start-up. Targets (2 cores): summation <= 15 s, Monte Carlo <= 10 s, table
cached <= 5 s. The user's own table cache is never used.
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["CONFIG", "TARGET", "TARGETS_SECONDS", "fabric_command", "run_fabric_bench", "markdown"]

CONFIG = "red-cotton"
TARGET = 0.01
#: the time targets (wall seconds on 2 cores); benchmarks, never asserted by tests
TARGETS_SECONDS = {"summation": 15.0, "mc_cold": 10.0, "mc_warm": 5.0}
_CACHE_ENV = "FABRIC_OPTICS_CACHE_DIR"


def fabric_command(method: str, out: Path, target: float = TARGET, config: str = CONFIG) -> list[str]:
    """The ``simulate fabric`` command line of the benchmark."""
    return [sys.executable, "-m", "fabric_optics.cli.simulate", "fabric", config, "--method", method, "--target-rel-err",
            str(target), "--no-progress", "--out", str(out)]


def _outcome(out: Path) -> dict[str, Any]:
    prov = json.loads((out / "meta.json").read_text())["provenance"]
    table = (prov.get("fiber_info") or {}).get("table") or {}
    return {"rel_err": prov.get("rel_err"), "table_cache": table.get("cache"), "photons": prov.get("photons")}


def _code_root() -> str:
    import simulate

    return str(Path(simulate.__file__).resolve().parents[1])


def _process(cmd: list[str], env: dict[str, str]) -> dict[str, Any]:
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800, check=True, cwd=_code_root())
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"wall_seconds": wall, "cpu_seconds": after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime,
            "load_before": load, "load_after": os.getloadavg()[0], **_outcome(Path(cmd[-1]))}


def _in_process(argv: list[str]) -> dict[str, Any]:
    """Run ``simulate fabric`` ``argv`` (as :func:`fabric_command` builds it) through the Python interface.

    In this process: the same function the command calls, then the same write.
    """
    from fabric_optics import api

    config, method, target, out = argv[1], argv[3], float(argv[5]), Path(argv[-1])
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    api.write_dataset(api.simulate(config, method=method, target_rel_err=target), out, force=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_SELF)
    return {"wall_seconds": wall, "cpu_seconds": after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime,
            "load_before": load, "load_after": os.getloadavg()[0], **_outcome(out)}


def _summary(runs: list[dict[str, Any]], target: float | None) -> dict[str, Any]:
    wall = float(statistics.median(r["wall_seconds"] for r in runs))
    return {"median_wall_seconds": wall, "median_cpu_seconds": float(statistics.median(r["cpu_seconds"] for r in runs)),
            "rel_err": [r["rel_err"] for r in runs], "target_seconds": target,
            "met": None if target is None else wall <= target, "runs": runs}


def run_fabric_bench(repeats: int = 3, target: float = TARGET, config: str = CONFIG,
                     in_process: bool = True) -> dict[str, Any]:
    """Whole-process (median of ``repeats``) and in-process timings of summation, mc cold and mc warm."""
    saved = os.environ.get(_CACHE_ENV)
    with tempfile.TemporaryDirectory(prefix="bench-fabric-") as tmp:
        root = Path(tmp)
        warm_cache = root / "cache-warm"
        base = dict(os.environ)
        base.pop("FABRIC_OPTICS_NO_CACHE", None)
        # the children run this process's code, wherever they start (``-m`` puts the cwd first)
        base["PYTHONPATH"] = os.pathsep.join(filter(None, [_code_root(), base.get("PYTHONPATH", "")]))
        rows: dict[str, list[dict[str, Any]]] = {"summation": [], "mc_cold": [], "mc_warm": []}
        for i in range(repeats):
            # the summation's exit tables are cached too (keyed with the dye): an empty cache per run, the
            # figure the target is about, and the caller's own cache is never touched
            rows["summation"].append(_process(fabric_command("summation", root / f"s{i}", target, config),
                                              {**base, _CACHE_ENV: str(root / f"cache-sum{i}")}))
            cold = root / ("cache-warm" if i == 0 else f"cache-cold{i}")  # the first cold run fills the warm cache
            rows["mc_cold"].append(_process(fabric_command("mc", root / f"c{i}", target, config),
                                            {**base, _CACHE_ENV: str(cold)}))
            rows["mc_warm"].append(_process(fabric_command("mc", root / f"w{i}", target, config),
                                            {**base, _CACHE_ENV: str(warm_cache)}))
        whole = {k: _summary(v, TARGETS_SECONDS[k]) for k, v in rows.items()}
        inproc: dict[str, Any] | None = None
        if in_process:
            try:
                os.environ.pop("FABRIC_OPTICS_NO_CACHE", None)
                os.environ[_CACHE_ENV] = str(root / "cache-inproc-sum")
                argv = fabric_command("summation", root / "is", target, config)[3:]
                inproc = {"summation": _in_process(argv)}
                os.environ[_CACHE_ENV] = str(root / "cache-inproc")
                inproc["mc_cold"] = _in_process(fabric_command("mc", root / "ic", target, config)[3:])
                inproc["mc_warm"] = _in_process(fabric_command("mc", root / "iw", target, config)[3:])
            finally:
                if saved is None:
                    os.environ.pop(_CACHE_ENV, None)
                else:
                    os.environ[_CACHE_ENV] = saved
    return {"config": config, "target_rel_err": target, "repeats": repeats, "cpus": os.cpu_count(),
            "whole_process": whole, "in_process": inproc}


def markdown(report: dict[str, Any]) -> str:
    """The fabric bench's rows for :func:`fabric_optics.bench.suite.markdown_table`."""
    lines = ["| `simulate fabric " + f"{report['config']} --target-rel-err {report['target_rel_err']}` | "
             "wall (median) | CPU | rel_err | load | target |", "|---|---|---|---|---|---|"]
    names = {"summation": "summation", "mc_cold": "mc, cold table cache", "mc_warm": "mc, warm table cache"}
    for key, label in names.items():
        w = report["whole_process"][key]
        loads = [r["load_before"] for r in w["runs"]]
        lines.append(f"| {label}, whole process (median of {len(w['runs'])}) | {w['median_wall_seconds']:.1f} s | "
                     f"{w['median_cpu_seconds']:.1f} s | {', '.join(f'{e:.2%}' for e in w['rel_err'])} | "
                     f"{min(loads):.1f}-{max(loads):.1f} | {w['target_seconds']:.0f} s |")
        ip = (report.get("in_process") or {}).get(key)
        if ip:
            lines.append(f"| {label}, in process | {ip['wall_seconds']:.1f} s | {ip['cpu_seconds']:.1f} s | "
                         f"{ip['rel_err']:.2%} | {ip['load_before']:.1f} | |")
    return "\n".join(lines)
