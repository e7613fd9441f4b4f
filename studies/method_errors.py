"""Where the cheaper fabric models depart from the woven Monte Carlo: the data behind ``--method auto``.

Per geometry of the red-cotton plan, the departure of a model from the Monte Carlo reference is
:func:`simulate.montecarlo.accuracy.relative_error` of ``model - MC`` on that geometry's
spectrum: the RMS over wavelengths of ``(model - MC) / max_lambda(MC)``, the same definition as
``--target-rel-err``. ``simulate bench`` runs it (:mod:`studies.bench_woven`) and
:func:`errors_from_report` turns its report into the table that
:func:`simulate.fabric.auto.choose` reads (``simulate/configs/method-errors.json``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from simulate.montecarlo.accuracy import relative_error

__all__ = ["model_datasets", "frame", "departure", "errors_from_report", "auto_counts", "main"]


def model_datasets() -> dict:
    """Summation and classic on the red-cotton plan at 1 %: seconds and their tables."""
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config
    from simulate.virtual import fabric_dataset

    cfg = load_config("red-cotton")
    plan = load_plan("red-cotton")
    out = {}
    for method in ("summation", "classic"):
        t = time.perf_counter()
        ds = fabric_dataset(cfg, plan, method, target_rel_err=0.01)
        out[method] = {"seconds": time.perf_counter() - t, "table": ds.table.to_dict(orient="list")}
    return out


def frame(table: dict):
    """A report's table (dict of columns) as a DataFrame."""
    import pandas as pd

    return pd.DataFrame(table)


def departure(report: dict) -> dict:
    """Per geometry, the RMS over wavelengths of ``(model - MC) / max_lambda(MC)`` (the accuracy
    target's spectral-peak convention) and the MC's own relative error there; median and max."""
    mc = frame(report["red_cotton"]["table"])
    key = ["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm"]
    out: dict[str, Any] = {}
    for name, m in report["models"].items():
        j = mc.merge(frame(m["table"]), on=key, suffixes=("_mc", "_m"))
        rows = []
        for (ti, pi, to, po), g in j.groupby(["theta_i", "phi_i", "theta_o", "phi_o"]):
            peak = float(g["beta_mc"].max())
            # relative_error of the model's error on this geometry's one spectrum: the one definition
            dep = relative_error(g["beta_mc"].to_numpy(float), (g["beta_m"] - g["beta_mc"]).to_numpy(float))
            se = float(np.sqrt(np.mean((g["u_beta_mc"] / peak) ** 2)))
            rows.append({"theta_i": float(ti), "theta_o": float(to), "rel_phi_o": float((po - pi) % 360.0),
                         "departure": dep, "mc_rel_se": se})
        deps = np.array([r["departure"] for r in rows])
        out[name] = {"max_rms_departure": float(deps.max()), "median_rms_departure": float(np.median(deps)),
                     "geometries": rows}
    return out


def errors_from_report(report: dict) -> dict:
    """The ``--method auto`` data file (``simulate/configs/method-errors.json``) from a report with a ``departure``."""
    rows: dict[tuple, dict] = {}
    for name, d in report["departure"].items():
        for r in d["geometries"]:
            key = (r["theta_i"], r["theta_o"], r["rel_phi_o"])
            rows.setdefault(key, {"theta_i": r["theta_i"], "theta_o": r["theta_o"], "rel_phi_o": r["rel_phi_o"],
                                  "mc_rel_se": r["mc_rel_se"]})[name] = r["departure"]
    return {"provenance": {"command": "simulate bench", "config": "red-cotton", "plan": "red-cotton",
                           "reference": "woven Monte Carlo", "target_rel_err": report.get("target", 0.01),
                           "machine": report.get("machine", {})},
            "geometries": sorted(rows.values(), key=lambda r: (r["theta_i"], r["rel_phi_o"], r["theta_o"]))}


def auto_counts(errors: dict, targets: tuple[float, ...] = (0.01, 0.02, 0.05, 0.1, 0.15)) -> dict:
    """How many of the study's geometries ``--method auto`` gives to each method, per target."""
    from simulate.fabric.auto import choose

    g = errors["geometries"]
    ti = [r["theta_i"] for r in g]
    to = [r["theta_o"] for r in g]
    po = [r["rel_phi_o"] for r in g]
    out = {}
    for t in targets:
        names, _ = choose(ti, [0.0] * len(g), to, po, t, errors=errors)
        out[str(t)] = {m: int((names == m).sum()) for m in ("classic", "summation", "mc")}
    return out


def main(argv: list[str] | None = None) -> None:
    """``python -m studies.method_errors [--target 0.01] [--threads N] [--out JSON] [--chart PNG]``: the
    where-methods-fail part of ``simulate bench`` alone (the red-cotton MC in a child process, the
    summation and classic at 1 %), the ``--method auto`` data file and the chart."""
    import argparse
    import datetime
    import json
    import os
    from pathlib import Path

    from studies.bench_woven import in_child, chart

    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--target", type=float, default=0.01)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", default=None, help="write the --method auto data file here")
    ap.add_argument("--chart", default=None, help="write the model/MC chart here (PNG)")
    a = ap.parse_args(argv)
    load = os.getloadavg()
    report: dict[str, Any] = {"machine": {"cpus": os.cpu_count(), "load_at_start": [round(x, 2) for x in load]},
                              "target": a.target}
    report["red_cotton"] = in_child(a.target, threads=a.threads)
    report["models"] = model_datasets()
    report["departure"] = departure(report)
    errors = errors_from_report(report)
    errors["provenance"]["date"] = datetime.date.today().isoformat()
    errors["provenance"]["command"] = "python -m studies.method_errors (the where-methods-fail part of simulate bench)"
    info = report["red_cotton"]["info"]
    errors["provenance"]["mc_model"] = {k: info.get(k) for k in ("yarn_surface", "yarn_volume", "twist_deg",
                                                                  "pile_packing_fraction")}
    rc = report["red_cotton"]
    print(f"MC: {rc['wall_seconds']:.0f} s wall, rel_err {rc['rel_err']:.2%}; models: "
          + ", ".join(f"{k} {v['seconds']:.0f} s" for k, v in report["models"].items()))
    for name, d in report["departure"].items():
        print(f"{name}: departure median {d['median_rms_departure']:.1%}, max {d['max_rms_departure']:.1%}")
        for r in sorted(d["geometries"], key=lambda r: (r["theta_i"], r["rel_phi_o"], r["theta_o"])):
            print(f"  inc {r['theta_i']:4.0f} obs {r['theta_o']:4.0f} az {r['rel_phi_o']:5.0f}: "
                  f"{r['departure']:6.1%} (MC se {r['mc_rel_se']:.1%})")
    print("auto, geometries per method:", json.dumps(auto_counts(errors)))
    if a.out:
        Path(a.out).write_text(json.dumps(errors, indent=1) + "\n")
    if a.chart:
        chart(report, Path(a.chart))


if __name__ == "__main__":
    main()
