"""Where the cheaper fabric models depart from the woven Monte Carlo: the data behind ``--method auto``.

Per geometry of a study's plan (red cotton on its plan; the green felt on the felt's plan), the departure of a model from the Monte Carlo reference is
:func:`simulate.montecarlo.accuracy.relative_error` of ``model - MC`` on that geometry's
spectrum: the RMS over wavelengths of ``(model - MC) / max_lambda(MC)``, the same definition as
``--target-rel-err``. ``simulate bench`` runs it (:mod:`fabric_optics.bench.woven`) and
:func:`errors_from_report` turns its report into the table that
:func:`simulate.fabric.auto.choose` reads: one table per structure kind, ``simulate/configs/method-errors.json``
(woven, red cotton) and ``simulate/configs/method-errors-felt.json`` (nonwoven, green felt), each made by
``python -m fabric_optics.bench.method_errors --study NAME --out FILE`` (:data:`STUDIES`). A blend study
(``populations``) traces its config with the study's ``[[populations]]`` appended (the green felt as two
populations of different dyes): ``simulate/configs/method-errors-felt-blend.json``, which ``--method auto``
reads for a felt blend within its :func:`simulate.fabric.auto.dye_spread` (recorded in the table); red cotton as
two populations of its dye at two strengths: ``simulate/configs/method-errors-woven-blend.json``, whose summation
departs as the one-population table's, so ``--method auto`` reads that table for a woven blend within the
study's dye spread (:data:`simulate.fabric.auto.BLEND_DEPARTURES`).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from simulate.montecarlo.accuracy import relative_error

__all__ = ["STUDIES", "run", "model_datasets", "frame", "departure", "errors_from_report", "auto_counts", "against",
           "main"]


#: the blend of the green felt whose body keeps the preset's colour: half with the dye's knots above 600 nm as
#: clear as its green (a yellow-green fiber), half with those knots' absorption doubled (a blue-green fiber)
_RED_CLEAR = """[[populations]]
name = "red-clear"
share = 0.5
[populations.fiber.dye]
curve = "knots"
wavelength_nm = [390.0, 435.714, 481.429, 527.143, 572.857, 618.571, 664.286, 710.0]
log10_per_um = [-0.7429, -0.06555, -1.6602, -2.02274, -1.98626, -2.0, -2.0, -2.0]
"""
BLEND_RED_X2 = _RED_CLEAR + """
[[populations]]
name = "red-x2"
share = 0.5
[populations.fiber.dye]
curve = "knots"
wavelength_nm = [390.0, 435.714, 481.429, 527.143, 572.857, 618.571, 664.286, 710.0]
log10_per_um = [-0.7429, -0.06555, -1.6602, -2.02274, -1.98626, -1.28411, -1.36778, -1.50128]
"""
#: the same with the second population's red absorption x10 of the preset's (a body darker in red)
BLEND_RED_X10 = _RED_CLEAR + """
[[populations]]
name = "red-x10"
share = 0.5
[populations.fiber.dye]
curve = "knots"
wavelength_nm = [390.0, 435.714, 481.429, 527.143, 572.857, 618.571, 664.286, 710.0]
log10_per_um = [-0.7429, -0.06555, -1.6602, -2.02274, -1.98626, -0.58514, -0.66881, -0.80231]
"""
#: the blend of red cotton whose populations differ in their dye's strength only: half with the preset's dye, half
#: with its two bands x3 (the same red passed above 620 nm, the orange edge and the violet darker)
BLEND_RED_COTTON_X3 = """[[populations]]
name = "red"
share = 0.5

[[populations]]
name = "red-x3"
share = 0.5
[populations.fiber.dye]
curve = "gaussian-bands"
baseline_per_um = 0.0001
bands = [
    { center_nm = 520, width_nm = 26.9, peak_per_um = 3.3 },
    { center_nm = 490, width_nm = 32, peak_per_um = 1.86 },
]
"""
#: the same with the second population's bands x10 (the orange edge darker still)
BLEND_RED_COTTON_X10 = BLEND_RED_COTTON_X3.replace('"red-x3"', '"red-x10"').replace("3.3 }", "11.0 }") \
    .replace("1.86 }", "6.2 }")

#: the studies: config and plan (presets; ``populations``: the ``[[populations]]`` appended to the config),
#: the Monte Carlo's target, the table file under simulate/configs and the structure kind ``--method auto``
#: reads it for (:func:`simulate.fabric.auto.table_for`; a blend's :data:`simulate.fabric.auto.BLEND_TABLES`)
STUDIES: dict[str, dict[str, Any]] = {
    "red-cotton": {"config": "red-cotton", "plan": "red-cotton", "target": 0.01, "kind": "woven",
                   "file": "method-errors.json", "reference": "woven Monte Carlo"},
    "red-cotton-blend": {"config": "red-cotton", "plan": "red-cotton", "target": 0.01, "kind": "woven",
                         "populations": BLEND_RED_COTTON_X3, "blend": "blend-red-x3",
                         "file": "method-errors-woven-blend.json", "reference": "woven Monte Carlo of the blend"},
    "red-cotton-blend-x10": {"config": "red-cotton", "plan": "red-cotton", "target": 0.01, "kind": "woven",
                             "populations": BLEND_RED_COTTON_X10, "blend": "blend-red-x10", "file": None,
                             "reference": "woven Monte Carlo of the blend"},
    "green-felt": {"config": "green-felt-mc", "plan": "green-felt", "target": 0.03, "kind": "nonwoven",
                   "file": "method-errors-felt.json", "reference": "felt Monte Carlo"},
    "green-felt-blend": {"config": "green-felt-mc", "plan": "green-felt", "target": 0.03, "kind": "nonwoven",
                         "populations": BLEND_RED_X2, "blend": "blend-red-x2",
                         "file": "method-errors-felt-blend.json", "reference": "felt Monte Carlo of the blend"},
    "green-felt-blend-x10": {"config": "green-felt-mc", "plan": "green-felt", "target": 0.03, "kind": "nonwoven",
                             "populations": BLEND_RED_X10, "blend": "blend-red-x10", "file": None,
                             "reference": "felt Monte Carlo of the blend"},
}


def blend_config(study: str, directory: str | Path) -> Path:
    """The config a blend study traces, written into ``directory`` (the runs load it by path).

    Its preset's text with the study's ``[[populations]]`` appended.
    """
    from importlib import resources

    st = STUDIES[study]
    text = resources.files("simulate.configs").joinpath(f"{st['config']}.toml").read_text()
    path = Path(directory) / f"{st['config']}-{st['blend']}.toml"
    path.write_text(text.rstrip("\n") + "\n\n" + st["populations"])
    return path


def model_datasets(config: str = "red-cotton", plan_name: str = "red-cotton") -> dict:
    """Summation and classic on the study's plan at 1 %: seconds and their tables."""
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config
    from simulate.virtual import fabric_dataset

    cfg = load_config(config)
    plan = load_plan(plan_name)
    out = {}
    for method in ("summation", "classic"):
        t = time.perf_counter()
        ds = fabric_dataset(cfg, plan, method, target_rel_err=0.01)
        out[method] = {"seconds": time.perf_counter() - t, "table": ds.table.to_dict(orient="list")}
    return out


def _mc_report(report: dict) -> dict:
    """The Monte Carlo reference of a report (``mc``; ``red_cotton`` in reports of the red-cotton study)."""
    mc = report.get("mc", report.get("red_cotton"))
    if not isinstance(mc, dict):
        raise ValueError("the report has no Monte Carlo reference ('mc')")
    return mc


def frame(table: dict):
    """A report's table (dict of columns) as a DataFrame."""
    import pandas as pd

    return pd.DataFrame(table)


def departure(report: dict) -> dict:
    """Per geometry, the RMS over wavelengths of ``(model - MC) / max_lambda(MC)``, with its median and max.

    The accuracy target's spectral-peak convention; the MC's own relative error there is given beside it.
    """
    mc = frame(_mc_report(report)["table"])
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


def errors_from_report(report: dict, study: str = "red-cotton") -> dict:
    """The ``--method auto`` data file of ``study`` (:data:`STUDIES`) from a report with a ``departure``."""
    rows: dict[tuple, dict] = {}
    for name, d in report["departure"].items():
        for r in d["geometries"]:
            key = (r["theta_i"], r["theta_o"], r["rel_phi_o"])
            rows.setdefault(key, {"theta_i": r["theta_i"], "theta_o": r["theta_o"], "rel_phi_o": r["rel_phi_o"],
                                  "mc_rel_se": r["mc_rel_se"]})[name] = r["departure"]
    st = STUDIES[study]
    prov = {"command": "simulate bench", "study": study, "kind": st["kind"],
            "config": report.get("config", st["config"]),
            "plan": st["plan"], "reference": st["reference"],
            "target_rel_err": report.get("target", st["target"]),
            "machine": report.get("machine", {})}
    if "populations" in report:       # a blend study: what was appended, and how differently it absorbs
        prov.update(blend=st.get("blend"), populations=report["populations"], dye_spread=report["dye_spread"])
    return {"provenance": prov,
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


def against(errors: dict, base: dict) -> dict:
    """How a study's departures differ from another table's (``base``) at the geometries they share, per model.

    The mean and median of ``departure - base departure``, the mean's standard error (from the two Monte Carlo
    references' errors at each geometry, ``mc_rel_se``, independent runs), the mean of the per-geometry
    differences in units of their own error (``z``; 0 for tables that differ by noise only) and how many
    geometries differ by more than 3 of those errors.
    """
    key = ("theta_i", "theta_o", "rel_phi_o")
    rows = {tuple(round(float(r[k]), 6) for k in key): r for r in base["geometries"]}
    pairs = [(r, rows[k]) for r in errors["geometries"] if (k := tuple(round(float(r[c]), 6) for c in key)) in rows]
    out: dict[str, Any] = {"geometries": len(pairs)}
    for m in ("summation", "classic"):
        d = np.array([a[m] - b[m] for a, b in pairs])
        se = np.array([float(np.hypot(a["mc_rel_se"], b["mc_rel_se"])) for a, b in pairs])
        z = d / se
        out[m] = {"mean_difference": float(d.mean()), "median_difference": float(np.median(d)),
                  "se_of_mean": float(np.sqrt(np.sum(se ** 2)) / d.size), "mean_z": float(z.mean()),
                  "beyond_3_se": int(np.sum(np.abs(z) > 3.0)),
                  "median": float(np.median([a[m] for a, _ in pairs])),
                  "base_median": float(np.median([b[m] for _, b in pairs]))}
    return out


def against_lines(comparison: dict, name: str, base: str) -> list[str]:
    """The lines :func:`against` prints."""
    lines = [f"{name} against {base} ({comparison['geometries']} geometries):"]
    for m in ("summation", "classic"):
        c = comparison[m]
        lines.append(f"  {m}: departure {c['mean_difference']:+.3f} on average (+- {c['se_of_mean']:.3f}), "
                     f"median {c['median_difference']:+.3f}; mean z {c['mean_z']:+.2f}, {c['beyond_3_se']} beyond 3 "
                     f"standard errors; median departure {c['median']:.3f} against {c['base_median']:.3f}")
    return lines


def _red_cotton_child(target: float, queue: Any, method: str = "mc", seed: int | None = None,
                      threads: int | None = None, config: str = "red-cotton", plan_name: str = "red-cotton") -> None:
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config
    from simulate.virtual import fabric_dataset

    cfg = load_config(config)
    plan = load_plan(plan_name)
    t = time.perf_counter()
    ds = fabric_dataset(cfg, plan, method, target_rel_err=target, seed=seed, threads=threads or os.cpu_count() or 1)
    wall = time.perf_counter() - t
    info = ds.meta["provenance"]["fiber_info"]
    queue.put({"wall_seconds": wall, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
               "rel_err": ds.meta["provenance"]["rel_err"], "info": info,
               "table": ds.table.to_dict(orient="list")})


def in_child(target: float, method: str = "mc", seed: int | None = None, threads: int | None = None,
             config: str = "red-cotton", plan_name: str = "red-cotton") -> dict:
    """One run (red cotton unless told) in a spawned child process.

    Its wall time (of the run only, not the process start) and its own peak memory.
    """
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    p = ctx.Process(target=_red_cotton_child, args=(target, queue, method, seed, threads, config, plan_name))
    p.start()
    result = queue.get()
    p.join()
    return result


def chart(report: dict, path: Path) -> None:
    """Four panels (incidence 0/30/45/60).

    Beta at 620 nm of MC (error bars), summation, classic; below them the ratio of each model to MC against the
    signed observation angle.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mc = frame(_mc_report(report)["table"])
    models = {k: frame(v["table"]) for k, v in report["models"].items()}
    wl = 620.0
    incid = sorted(mc["theta_i"].unique())
    fig, axes = plt.subplots(2, len(incid), figsize=(4 * len(incid), 6.5), sharex=True)

    def curve(df, ti):
        s = df[(df["theta_i"] == ti) & (df["wavelength_nm"] == wl)].copy()
        # gonio.data.geometry's signed angle: s >= 0 on the mirror side (phi_o = phi_i + 180)
        s["signed"] = np.where(np.isclose((s["phi_o"] - s["phi_i"]) % 360.0, 180.0), s["theta_o"], -s["theta_o"])
        return s.sort_values("signed")

    for c, ti in enumerate(incid):
        m = curve(mc, ti)
        ax = axes[0, c]
        ax.errorbar(m["signed"], m["beta"], yerr=m["u_beta"], fmt="o", ms=3, color="k", label="Monte Carlo")
        # strict=False: a colour per model from a fixed palette, which may hold more colours than there are models
        for (name, df), col in zip(models.items(), ("C0", "C1"), strict=False):
            s = curve(df, ti)
            ax.plot(s["signed"], s["beta"], "-", color=col, label=name)
            j = s.merge(m, on="signed", suffixes=("", "_mc"))
            axes[1, c].plot(j["signed"], j["beta"] / j["beta_mc"], "-o", ms=3, color=col, label=name)
        ax.set_title(f"incidence {ti:g} deg, {wl:g} nm")
        axes[1, c].axhline(1.0, color="k", lw=0.8)
        axes[1, c].set_xlabel("signed observation angle (deg, + mirror side)")
    axes[0, 0].set_ylabel("beta")
    axes[1, 0].set_ylabel("model / Monte Carlo")
    axes[0, 0].legend(fontsize=8)
    rc = _mc_report(report)
    fig.suptitle(f"{report.get('study', 'red-cotton')}: Monte Carlo to {rc['rel_err']:.2%} rms in "
                 f"{rc['wall_seconds']:.0f} s, {os.cpu_count()} cores")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(study: str = "red-cotton", target: float | None = None, threads: int | None = None,
        config: str | None = None) -> tuple[dict, dict, list[str]]:
    """The study ``study`` (:data:`STUDIES`; ``config`` in place of its own).

    Its report, its ``--method auto`` table and its lines of text.
    """
    import datetime
    import json

    st = STUDIES[study]
    target = st["target"] if target is None else target
    load = os.getloadavg()
    report: dict[str, Any] = {"machine": {"cpus": os.cpu_count(), "load_at_start": [round(x, 2) for x in load]},
                              "target": target, "study": study, "config": config or st["config"]}
    with tempfile.TemporaryDirectory(prefix="method-errors-") as tmp:
        traced = report["config"]
        if "populations" in st and config is None:
            from simulate.config import load_config
            from simulate.fabric.auto import dye_spread

            path = blend_config(study, tmp)
            traced = str(path)
            report["populations"] = st["populations"]
            report["dye_spread"] = dye_spread(load_config(path))
        report["mc"] = in_child(target, threads=threads, config=traced, plan_name=st["plan"])
        report["models"] = model_datasets(traced, st["plan"])
    report["departure"] = departure(report)
    errors = errors_from_report(report, study)
    errors["provenance"]["date"] = datetime.date.today().isoformat()
    flags = (f" --study {study}" if study != "red-cotton" else "") + (f" --config {config}" if config else "")
    errors["provenance"]["command"] = (f"python -m fabric_optics.bench.method_errors{flags} "
                                       "(the where-methods-fail part of simulate bench)")
    rc = report["mc"]
    # the Monte Carlo's own error (its rays and its tables' noise) and why it ended
    errors["provenance"]["mc_rel_err"] = rc["rel_err"]
    info = rc["info"]
    errors["provenance"]["mc_stop"] = info.get("stop")
    if st["kind"] == "woven":
        errors["provenance"]["mc_model"] = {k: info.get(k) for k in ("yarn_surface", "yarn_volume", "twist_deg",
                                                                      "pile_packing_fraction")}
    lines = [f"MC: {rc['wall_seconds']:.0f} s wall, rel_err {rc['rel_err']:.2%}; models: "
             + ", ".join(f"{k} {v['seconds']:.0f} s" for k, v in report["models"].items())]
    for name, d in report["departure"].items():
        lines.append(f"{name}: departure median {d['median_rms_departure']:.1%}, max {d['max_rms_departure']:.1%}")
        for r in sorted(d["geometries"], key=lambda r: (r["theta_i"], r["rel_phi_o"], r["theta_o"])):
            lines.append(f"  inc {r['theta_i']:4.0f} obs {r['theta_o']:4.0f} az {r['rel_phi_o']:5.0f}: "
                         f"{r['departure']:6.1%} (MC se {r['mc_rel_se']:.1%})")
    lines.append("auto, geometries per method: " + json.dumps(auto_counts(errors)))
    return report, errors, lines


def main(argv: list[str] | None = None) -> None:
    """The where-methods-fail part of ``simulate bench`` alone, its ``--method auto`` data file and chart.

    ``python -m fabric_optics.bench.method_errors [--study NAME] [--target T] [--threads N] [--out JSON]
    [--chart PNG] [--report JSON]``: the study's Monte Carlo in a child process, the summation and classic
    at 1 %. ``--compare TABLE BASE [--json OUT]``: how one table's departures differ from another's
    (:func:`against`), no study run.
    """
    import argparse
    import json

    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--study", default="red-cotton", choices=sorted(STUDIES),
                    help="the fabric: its config, plan and table file (default red-cotton)")
    ap.add_argument("--config", default=None, help="a config in place of the study's own (same plan)")
    ap.add_argument("--target", type=float, default=None, help="the Monte Carlo's target (default: the study's)")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", default=None, help="write the --method auto data file here")
    ap.add_argument("--chart", default=None, help="write the model/MC chart here (PNG)")
    ap.add_argument("--report", default=None, help="write the whole report here (JSON: the tables of every method)")
    ap.add_argument("--compare", nargs=2, metavar=("TABLE", "BASE"), default=None,
                    help="compare two --method auto tables' departures instead of running a study")
    ap.add_argument("--json", default=None, help="with --compare: write the comparison here")
    ap.add_argument("--force", action="store_true", help="overwrite an existing --out, --chart, --report or --json")
    a = ap.parse_args(argv)
    for opt, val in (("--out", a.out), ("--chart", a.chart), ("--report", a.report), ("--json", a.json)):
        if val and Path(val).exists() and not a.force:
            ap.error(f"{opt} {val}: exists; pass --force to overwrite it")
    if a.compare:
        tables = []
        for path in a.compare:
            try:
                tables.append(json.loads(Path(path).read_text()))
            except (OSError, ValueError) as exc:
                ap.error(f"--compare {path}: not a readable --method auto table ({exc})")
        comparison = against(tables[0], tables[1])
        print("\n".join(against_lines(comparison, a.compare[0], a.compare[1])))
        if a.json:
            names = {"table": a.compare[0], "base": a.compare[1]}
            Path(a.json).write_text(json.dumps({**names, **comparison}, indent=1) + "\n")
        return
    report, errors, lines = run(a.study, a.target, a.threads, a.config)
    print("\n".join(lines))
    if a.out:
        Path(a.out).write_text(json.dumps(errors, indent=1) + "\n")
    if a.chart:
        chart(report, Path(a.chart))
    if a.report:
        Path(a.report).write_text(json.dumps(report, default=str) + "\n")


if __name__ == "__main__":
    main()
