"""``simulate bench --study speed-accuracy``: the Monte Carlo's achieved error against its marginal cost.

For red cotton (woven) and the green felt (``green-felt-mc``), on a small plan (the plan's first
incidence, every third in-plane observation, 3 wavelengths), the fabric Monte Carlo runs at each
target twice, with two seeds, each run a whole process of its own with an empty table cache (after
a first run, not kept, that loads the fabric's compiled kernels):

* achieved error: each run's actual error in the target's one definition
  (:func:`simulate.montecarlo.accuracy.relative_error`: RMS over directions and wavelengths of the
  error over each direction's spectral peak), estimated from the two independent runs as
  ``relative_error(mean, (beta_1 - beta_2) / sqrt 2)`` -- no reference run needed, and its sampling
  spread (``err / sqrt(2 n)``, ``n`` values) is reported;
* marginal cost: the seconds the target buys -- the yarn tables' build and the ray tracing; the
  fixed costs are reported apart: start-up (process, imports, kernels; measured from the launch to
  the run's start) and set-up (mesh, optics: the run's time minus tables and tracing);
* the cheaper models' floors: the RMS over the same geometries of the summation's and the classic
  model's departure from the Monte Carlo (the ``--method auto`` tables
  ``simulate/configs/method-errors.json`` and ``method-errors-felt.json``, same definition).

The tables' photons per row have a floor in ``simulate fabric`` (:data:`simulate.raytrace.estimate.PILE_TABLE`
4 000, the fiber's 10 000): below a target of about 1 % (red cotton) or 1.7 % (felt) every run
builds the same table and lands near 1 %, which hides the trade-off. The study lowers that floor
to ``table_floor`` (0: the target alone sets the photons), and records it.

Writes ``OUT/speed-accuracy.json`` and ``OUT/speed-accuracy.png``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from simulate.provenance import machine

__all__ = ["FABRICS", "TARGETS", "small_plan", "achieved_error", "model_floors", "run_speed_accuracy", "chart",
           "study_lines", "machine"]

#: fabric -> (config, plan, the --method auto table of its departures)
FABRICS: dict[str, tuple[str, str, str]] = {
    "red cotton": ("red-cotton", "red-cotton", "method-errors.json"),
    "green felt": ("green-felt-mc", "green-felt", "method-errors-felt.json"),
}
#: the targets per fabric (a decade of error is ~100x the photons)
TARGETS: dict[str, tuple[float, ...]] = {"red cotton": (0.2, 0.1, 0.05, 0.02, 0.01),
                                         "green felt": (0.5, 0.2, 0.1, 0.05, 0.02)}
SEEDS = (11, 12)
COMMAND = "simulate bench --study speed-accuracy --out DIR"


def small_plan(plan: Any, wavelengths: int = 3, step: int = 3) -> Any:
    """``plan`` cut down.

    Its first incidence, every ``step``-th in-plane observation, ``wavelengths`` wavelengths spread over its range,
    no out-of-plane directions.
    """
    wl = np.asarray(plan.wavelengths_nm, float)
    pick = np.unique(np.linspace(0, wl.size - 1, wavelengths).round().astype(int))
    return dataclasses.replace(plan, wavelengths_nm=wl[pick], incidence_deg=list(plan.incidence_deg[:1]),
                               in_plane_deg=list(plan.in_plane_deg[::step]), directions_deg=[], retro_ring_deg=[],
                               _points=None)


@contextlib.contextmanager
def _table_floor(floor: int | None) -> Iterator[None]:
    """The tables' photons per row floored at ``floor`` (None: as shipped) while inside; restored after."""
    import simulate.raytrace.estimate as E

    if floor is None:
        yield
        return
    shipped, pile = E.table_photons, dict(E.PILE_TABLE)

    def table_photons(target_rel_err: float, noise: float = E.TABLE_NOISE, share: float = E.TABLE_SHARE,
                      min_photons: int = int(floor)) -> int:
        return shipped(target_rel_err, noise, share, int(floor))

    E.PILE_TABLE["min_photons"] = int(floor)
    E.table_photons = table_photons  # type: ignore[assignment]
    try:
        yield
    finally:
        E.table_photons = shipped  # type: ignore[assignment]
        E.PILE_TABLE.clear()
        E.PILE_TABLE.update(pile)


def _child(spec: dict[str, Any]) -> dict[str, Any]:
    """One run (``spec``: config, plan, target, seed, threads, table_floor, wavelengths, step)."""
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config
    from simulate.virtual import fabric_dataset

    cfg = load_config(spec["config"])
    plan = small_plan(load_plan(spec["plan"]), spec["wavelengths"], spec["step"])
    started = time.time()
    t = time.perf_counter()
    with _table_floor(spec["table_floor"]):
        ds = fabric_dataset(cfg, plan, "mc", target_rel_err=spec["target"], seed=spec["seed"],
                            threads=spec["threads"])
    wall = time.perf_counter() - t
    prov = ds.meta["provenance"]
    info = prov["fiber_info"]
    return {"started": started, "run_seconds": wall, "table_seconds": float(info["table"]["seconds"]),
            "trace_seconds": float(sum(r["seconds"] for r in info["incidences"])),
            "table_photons_per_row": info["table"]["photons_per_row"], "rays": info["rays"],
            "rel_err": prov["rel_err"], "table": ds.table.to_dict(orient="list")}


def _run(spec: dict[str, Any], in_process: bool) -> dict[str, Any]:
    """One run, a whole process of its own (empty table cache) unless ``in_process``."""
    if in_process:
        launched = time.time()
        r = _child(spec)
    else:
        with tempfile.TemporaryDirectory(prefix="bench-sa-") as cache:
            env = dict(os.environ, FABRIC_OPTICS_CACHE_DIR=cache)
            env.pop("FABRIC_OPTICS_NO_CACHE", None)
            # the child runs this process's code, wherever it starts
            root = str(Path(__file__).resolve().parents[2])
            env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH", "")]))
            launched = time.time()
            proc = subprocess.run([sys.executable, "-m", "fabric_optics.bench.speed_accuracy", json.dumps(spec)],
                                  env=env, capture_output=True, text=True, timeout=1800, check=True)
            r = json.loads(proc.stdout.splitlines()[-1])
    r["startup_seconds"] = max(0.0, r.pop("started") - launched)
    r["setup_seconds"] = max(0.0, r["run_seconds"] - r["table_seconds"] - r["trace_seconds"])
    r["marginal_seconds"] = r["table_seconds"] + r["trace_seconds"]
    return r


def achieved_error(table_a: dict, table_b: dict) -> tuple[float, float]:
    """Each of two independent runs' actual error in the target's definition, and its sampling spread.

    ``relative_error(mean, (beta_a - beta_b) / sqrt 2)``: the difference of two independent runs has
    twice the variance of one, so its mean square over ``n`` values estimates one run's; the spread
    of that RMS is ``err / sqrt(2 n)``.
    """
    import pandas as pd

    from simulate.montecarlo.accuracy import relative_error

    key = ["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm"]
    j = pd.DataFrame(table_a).merge(pd.DataFrame(table_b), on=key, suffixes=("_a", "_b"))
    geo = j.groupby(key[:4], sort=True)
    mean = np.vstack([0.5 * (g["beta_a"] + g["beta_b"]).to_numpy(float) for _, g in geo])
    diff = np.vstack([(g["beta_a"] - g["beta_b"]).to_numpy(float) for _, g in geo]) / math.sqrt(2.0)
    err = relative_error(mean, diff)
    return err, err / math.sqrt(2.0 * diff.size)


def model_floors(table: dict, errors_file: str) -> dict[str, float]:
    """RMS over ``table``'s geometries of the summation's and classic's departure from the Monte Carlo.

    ``table`` is the shipped ``--method auto`` table ``errors_file``, with the same definition as the target.
    """
    import simulate

    rows = json.loads((Path(simulate.__file__).parent / "configs" / errors_file).read_text())["geometries"]
    ti, pi, to, po = (np.asarray(table[k], float) for k in ("theta_i", "phi_i", "theta_o", "phi_o"))
    geos = {(a, (d - b) % 360.0, c) for a, b, c, d in zip(ti, pi, to, po, strict=True)}
    out: dict[str, float] = {}
    for model in ("summation", "classic"):
        found = [r[model] for g in geos for r in rows
                 if np.allclose([r["theta_i"], r["rel_phi_o"], r["theta_o"]], [g[0], g[1], g[2]]) and model in r]
        out[model] = float(np.sqrt(np.mean(np.square(found)))) if found else float("nan")
    return out


def run_speed_accuracy(*, quick: bool = False, fabrics: dict[str, tuple[float, ...]] | None = None,
                       threads: int = 1, table_floor: int | None = 0, wavelengths: int = 3, step: int = 3,
                       in_process: bool = False) -> dict[str, Any]:
    """The study's figures (module docstring) as a JSON-ready dict. ``quick``: every other target."""
    fabrics = fabrics or {k: (v[::2] if quick else v) for k, v in TARGETS.items()}
    report: dict[str, Any] = {"study": "speed-accuracy", "command": COMMAND + (" --quick" if quick else ""),
                              "machine": machine(), "load_at_start": [round(x, 2) for x in os.getloadavg()],
                              "threads": threads, "table_floor": table_floor, "seeds": list(SEEDS),
                              "plan": {"incidences": 1, "in_plane_step": step, "wavelengths": wavelengths},
                              "fabrics": {}}
    for name, targets in fabrics.items():
        config, plan, errors_file = FABRICS[name]
        rows = []
        # a first run, not kept: the first process of a fabric loads (or compiles) its kernels
        _run({"config": config, "plan": plan, "target": float(max(targets)), "seed": SEEDS[0] + 100,
              "threads": threads, "table_floor": table_floor, "wavelengths": wavelengths, "step": step}, in_process)
        for target in targets:
            runs = [_run({"config": config, "plan": plan, "target": float(target), "seed": s, "threads": threads,
                          "table_floor": table_floor, "wavelengths": wavelengths, "step": step}, in_process)
                    for s in SEEDS]
            err, se = achieved_error(runs[0]["table"], runs[1]["table"])
            keep = ("startup_seconds", "setup_seconds", "table_seconds", "trace_seconds", "marginal_seconds")
            row = {"target": float(target), "achieved_error": err, "achieved_error_se": se,
                   "reported_rel_err": [r["rel_err"] for r in runs],
                   "table_photons_per_row": runs[0]["table_photons_per_row"], "rays": [r["rays"] for r in runs],
                   **{k: float(np.mean([r[k] for r in runs])) for k in keep}}
            rows.append(row)
        floors = model_floors(runs[0]["table"], errors_file)
        report["fabrics"][name] = {"config": config, "plan": plan, "runs": rows, "model_floors": floors,
                                   "model_floors_source": f"simulate/configs/{errors_file}"}
    return report


def study_lines(report: dict[str, Any]) -> list[str]:
    """The study as text: one line per fabric and target."""
    lines = []
    for name, f in report["fabrics"].items():
        floors = ", ".join(f"{k} {v:.1%}" for k, v in f["model_floors"].items())
        lines.append(f"{name} ({f['config']}): floors {floors}")
        for r in f["runs"]:
            lines.append(f"  target {r['target']:<5g} achieved {r['achieved_error']:.2%} +- {r['achieved_error_se']:.2%}"
                         f"  marginal {r['marginal_seconds']:.1f} s (tables {r['table_seconds']:.1f} s, rays "
                         f"{r['trace_seconds']:.1f} s)  fixed: start-up {r['startup_seconds']:.1f} s, set-up "
                         f"{r['setup_seconds']:.1f} s")
    return lines


def chart(report: dict[str, Any], path: Path) -> None:
    """Left: achieved error against marginal cost (log-log), the models' floors as lines.

    Right: each run's cost split into its fixed part (start-up, set-up) and its marginal part (tables, rays).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 5.8), gridspec_kw={"width_ratios": [1.15, 1]})
    labels: list[str] = []
    parts: dict[str, list[float]] = {k: [] for k in ("startup_seconds", "setup_seconds", "table_seconds", "trace_seconds")}
    # strict=False: a colour per fabric from a fixed palette, which may hold more colours than there are fabrics
    for (name, f), col in zip(report["fabrics"].items(), ("C3", "C2"), strict=False):
        r = f["runs"]
        x = [v["marginal_seconds"] for v in r]
        a.errorbar(x, [v["achieved_error"] for v in r], yerr=[2 * v["achieved_error_se"] for v in r], fmt="o-",
                   color=col, label=f"{name}: Monte Carlo")
        for v in r:
            a.annotate(f"{v['target']:g}", (v["marginal_seconds"], v["achieved_error"]), fontsize=7, xytext=(4, 3),
                       textcoords="offset points", color=col)
        for model, ls in (("summation", "--"), ("classic", ":")):
            level = f["model_floors"].get(model)
            if level is not None and math.isfinite(level):
                a.axhline(level, color=col, ls=ls, lw=1, label=f"{name}: {model}")
        for v in r:
            labels.append(f"{name.split()[-1]} {v['target']:g}")
            for k in parts:
                parts[k].append(v[k])
    a.set_xscale("log")
    a.set_yscale("log")
    a.set_xlabel("marginal cost: table build + ray tracing (s)")
    a.set_ylabel("achieved error (RMS of error / spectral peak)")
    a.set_title("achieved error against marginal cost (labels: target)")
    a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3)
    y = np.arange(len(labels))
    left = np.zeros(len(labels))
    names = {"startup_seconds": "start-up (fixed)", "setup_seconds": "set-up: mesh, optics (fixed)",
             "table_seconds": "table build", "trace_seconds": "ray tracing"}
    for (k, v), col in zip(parts.items(), ("0.75", "0.55", "C0", "C1"), strict=True):
        b.barh(y, v, left=left, color=col, label=names[k])
        left += np.asarray(v)
    b.set_yticks(y, labels, fontsize=7)
    b.invert_yaxis()
    b.set_xlabel("seconds per run (mean of the two seeds)")
    b.set_title("where each run's time goes")
    b.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    m = report["machine"]
    fig.suptitle(f"Produced by `{report['command']}` on {m['cpu']}, {m['cpus']} logical CPUs, "
                 f"{report['threads']} thread(s); small plan: 1 incidence, {report['plan']['wavelengths']} wavelengths",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":   # the study's child process: one run, its JSON on the last line of stdout
    print(json.dumps(_child(json.loads(sys.argv[1]))))
