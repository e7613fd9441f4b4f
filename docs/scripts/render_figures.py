"""Render the measured figures of the documentation from the JSON their runs wrote.

Every benchmark or validation figure the README and the manual show lives in ONE JSON file, written by
the command that measured it and wrapped with that command and the machine it ran on. This script
renders each into the Markdown between the markers

    <!-- BEGIN FIGURE: NAME -->
    <!-- END FIGURE: NAME -->

of README.md and docs/**/*.md; prose points to those tables and never copies their numbers.

    python docs/scripts/render_figures.py                 # fill every marked block
    python docs/scripts/render_figures.py --check         # exit 1 naming the stale files, write nothing
    python docs/scripts/render_figures.py --record NAME FILE.json --command "simulate bench --quick --out D"
        # wrap a run's JSON as docs/data/NAME.json with its command and this machine

``tests/docs/test_figures.py`` fails when a committed block differs from a fresh rendering.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import statistics
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from simulate.provenance import machine

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "docs" / "data"
REGENERATE = "python docs/scripts/render_figures.py"
_BLOCK = re.compile(r"(<!-- BEGIN FIGURE: ([\w-]+) -->\n)(.*?)(<!-- END FIGURE: \2 -->)", re.S)


def load(name: str, path: Path | None = None) -> dict[str, Any]:
    """The JSON of figure ``name``, from ``docs/data/NAME.json`` or ``path``.

    Parameters
    ----------
    name : str
        The figure's data name.
    path : pathlib.Path, optional
        Another file to read instead.

    Returns
    -------
    dict
        The parsed JSON (a record: ``name``, ``command``, ``machine``, ``data``).

    Raises
    ------
    SystemExit
        The file is missing or not JSON; the message names it and how to produce it.
    """
    path = path or DATA / f"{name}.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise SystemExit(f"render_figures: {path.relative_to(ROOT)}: {exc}; produce it with the command its "
                         f"figure names, then `{REGENERATE} --record ...`") from None


def _machine_text(m: dict[str, Any]) -> str:
    """A record's machine on one line: CPU, logical CPUs, system (the parts it has)."""
    parts = [str(m.get("cpu") or ""), f"{m['cpus']} logical CPUs" if m.get("cpus") else "",
             str(m.get("system") or "")]
    return ", ".join(p for p in parts if p)


def _source(record: dict[str, Any], extra: str = "") -> str:
    """The line under a figure: the command that produced it, the machine (``extra`` after it), the data file."""
    return (f"*Produced by `{record['command']}` on {_machine_text(record['machine'])}"
            f"{extra}. Data: `docs/data/{record['name']}.json`.*")


def _table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table of ``header`` and ``rows``."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def fig_slab_kernel() -> str:
    """The Monte Carlo kernel on the van de Hulst slab (``simulate bench``).

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/bench-quick.json``).
    """
    rec = load("bench-quick")
    d = rec["data"]
    one, two = d["throughput"]["one_thread"], d["throughput"]["all_threads"]
    case = d["throughput"]["case"]
    run = one["runs"][0]
    rows = [
        ["photons per second, 1 thread (median)", f"{one['median_photons_per_s'] / 1e6:.2f} M"],
        [f"photons per second, {two['threads']} threads (median)", f"{two['median_photons_per_s'] / 1e6:.2f} M"],
        ["events per photon", f"{one['median_events_per_photon']:.3f}"],
        ["nanoseconds per event, 1 thread", f"{one['median_ns_per_event']:.1f}"],
        ["time against photons, log-log slope", f"{d['time_vs_photons']['loglog_slope']:.3f}"],
        ["peak resident memory", f"{d['peak_rss_mb']:.0f} MB"],
        ["Rd, Tt of one run", f"{run['Rd']:.5f} ± {run['u_Rd']:.5f}, {run['Tt']:.5f} ± {run['u_Tt']:.5f}"],
        ["reference Rd, Tt (van de Hulst)", f"{case['reference_Rd']}, {case['reference_Tt']}"],
    ]
    note = (f" ({one['photons_per_run']:,} photons per run, {one['repeats']} repeats;"
            " the machine was shared with other work, so speeds are a lower bound)")
    return _table(["figure", "value"], rows) + "\n\n" + _source(rec, note)


def fig_driver() -> str:
    """The driver's own overhead against the fast mock (``gonio bench-driver``).

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/driver.json``).
    """
    rec = load("driver")
    d = rec["data"]
    rows = [
        [f"a whole acquisition of the `{d['plan']}` plan ({d['points']} geometries, {d['rows']} values) "
         "against the fast mock", f"{d['median_wall_s']:.1f} s"],
        ["driver time per geometry (outside the exchanges and waits)", f"{d['median_driver_ms_per_point']:.1f} ms"],
        ["driver time per (geometry, wavelength) value", f"{d['median_driver_ms_per_row']:.2f} ms"],
        ["replay of the recorded transcript, no device, per value", f"{d['replay_ms_per_row']:.2f} ms"],
    ]
    return _table(["figure", "value"], rows) + "\n\n" + _source(rec)


def _method_errors(file: str, reference: str) -> tuple[str, dict[str, Any], list[dict[str, Any]]]:
    """The summary table of a method-errors file under simulate/configs, its provenance and rows."""
    path = ROOT / "simulate" / "configs" / file
    d = load(file.removesuffix(".json"), path)
    prov = d["provenance"]
    geos = d["geometries"]
    rows = []
    for method in ("summation", "classic"):
        values = sorted(100 * g[method] for g in geos)
        worst = max(geos, key=lambda g: g[method])
        rows.append([method, f"{statistics.median(values):.1f} %", f"{values[int(0.9 * (len(values) - 1))]:.1f} %",
                     f"{values[-1]:.1f} %",
                     f"θi {worst['theta_i']:g}°, θo {worst['theta_o']:g}°, Δφ {worst['rel_phi_o']:g}°"])
    mc = sorted(100 * g["mc_rel_se"] for g in geos)
    rows.append([f"{reference} (its own standard error)", f"{statistics.median(mc):.2f} %", "", f"{mc[-1]:.2f} %",
                 ""])
    return _table(["model", "median", "90th percentile", "largest", "where largest"], rows), prov, geos


def _method_errors_caption(prov: dict[str, Any], geos: list, file: str, command: str) -> str:
    """The caption under a method-errors table: the error's definition, the plan, the config, the command, the file."""
    return (f"*RMS over wavelengths of (model − Monte Carlo) relative to the Monte Carlo's spectral "
            f"peak, at the {len(geos)} geometries of the `{prov['plan']}` plan for the `{prov['config']}` config. "
            f"Produced by `{command}` on a {prov.get('machine', {}).get('cpus')}-CPU machine. Data: "
            f"`simulate/configs/{file}` (also what `simulate fabric --method auto` reads for this structure).*")


def fig_method_errors() -> str:
    """Where the cheaper models depart from the woven Monte Carlo (red cotton).

    Returns
    -------
    str
        The block's Markdown: the table(s) and the caption naming the plan, the config, the command and
        ``simulate/configs/method-errors.json``.
    """
    text, prov, geos = _method_errors("method-errors.json", "woven Monte Carlo")
    command = prov["command"].split(" (")[0] + " --target 0.01 --threads 2"
    return text + "\n\n" + _method_errors_caption(prov, geos, "method-errors.json", command)


#: the felt's regions (in-plane geometries): name -> test on (theta_i, theta_o, rel_phi_o)
FELT_REGIONS: dict[str, Callable[[float, float, float], bool]] = {
    "forward, grazing (mirror side, θo ≥ 60°, θi ≥ 30°)": lambda ti, to, az: az == 180.0 and to >= 60 and ti >= 30,
    "opposition (source side, within 10° of the source)": lambda ti, to, az: ti > 0 and az == 0.0
    and abs(to - ti) <= 10,
    "elsewhere": lambda ti, to, az: True,
}


def fig_method_errors_felt() -> str:
    """Where the cheaper models depart from the felt Monte Carlo (green felt), overall and by region.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the caption naming the plan, the config, the command and
        ``simulate/configs/method-errors-felt.json``.
    """
    file = "method-errors-felt.json"
    text, prov, geos = _method_errors(file, "felt Monte Carlo")
    rows, seen = [], set()
    for name, inside in FELT_REGIONS.items():
        sel = [g for i, g in enumerate(geos) if i not in seen and inside(g["theta_i"], g["theta_o"], g["rel_phi_o"])]
        seen |= {i for i, g in enumerate(geos) if g in sel}
        rows.append([name, str(len(sel))] + [f"{100 * statistics.median(g[m] for g in sel):.1f} % / "
                                             f"{100 * max(g[m] for g in sel):.1f} %" for m in ("summation", "classic")])
    regions = _table(["region", "geometries", "summation: median / largest", "classic: median / largest"], rows)
    command = prov["command"].split(" (")[0]
    return (text + "\n\n" + regions + "\n\n" + _method_errors_caption(prov, geos, file, command)[:-1]
            + f" The felt Monte Carlo reached {100 * prov['mc_rel_err']:.1f} % (its target "
            f"{100 * prov['target_rel_err']:g} %).*")


def fig_demo_cost() -> str:
    """Wall time and peak memory of ``make demo`` from a fresh clone.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/demo.json``).
    """
    rec = load("demo")
    d = rec["data"]
    minutes, seconds = divmod(round(d["wall_seconds"]), 60)
    rows = [["wall time", f"{minutes} min {seconds:02d} s"],
            ["peak memory (largest process)", f"{d['peak_rss_mb'] / 1024:.1f} GB"]]
    if d.get("cpu_seconds"):
        rows.append(["CPU time (user + system)", f"{d['cpu_seconds']:.0f} s"])
    cpu = d.get("cpu_steps", {})
    for step, secs in d.get("steps", {}).items():
        rows.append([f"wall time of `{step}`", f"{secs:.0f} s" + (f" ({cpu[step]:.0f} CPU s)" if step in cpu else "")])
    again = d.get("second_run")
    if again:
        minutes, seconds = divmod(round(again["wall_seconds"]), 60)
        rows.append(["wall time of a second `make demo` in the same clone", f"{minutes} min {seconds:02d} s"
                     f" ({again['cpu_seconds']:.0f} CPU s, {again['peak_rss_mb'] / 1024:.1f} GB)"])
        for step, secs in again.get("steps", {}).items():
            if step not in ("make venv", "the environment (the project alone)"):
                rows.append([f"second run: `{step}`", f"{secs:.0f} s"])
    note = f" ({d['conditions']}" + (f"; the second run: {again['conditions']}" if again and again.get("conditions")
                                       else "") + ")" if d.get("conditions") else ""
    return _table(["figure", "value"], rows) + "\n\n" + _source(rec, note)


def _pair(values: list, u: list | None = None, digits: int = 3) -> str:
    """550 and 650 nm of a [450, 550, 650] list, with their standard errors when given."""
    if u is None:
        return f"{values[1]:.{digits}f} / {values[2]:.{digits}f}"
    return f"{values[1]:.{digits}f} ± {u[1]:.{digits}f} / {values[2]:.{digits}f} ± {u[2]:.{digits}f}"


def fig_felt_opposition() -> str:
    """The felt Monte Carlo's opposition ratio with one parameter of ``green-felt-mc`` changed at a time.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-opposition.json``).
    """
    rec = load("felt-opposition")
    d = dict(rec["data"])
    d["variants"] = [v for v in d["variants"] if v.get("pooled")]     # a scan under way lists variants not yet traced
    incid = [f"{t:g}" for t in d["settings"]["incidences_deg"]]
    f = d["file"]["incidences"]
    header = ["variant"] + [f"θi {t}°, {o}" for t in incid for o in ("single scattering", "all orders")]
    rows = [["the RGL file"] + [c for t in incid for c in ("", _pair(f[t]["ratio"]))]]
    for v in d["variants"]:
        o = v["pooled"]
        rows.append([v["label"]] + [_pair(o[k][t]["ratio"], o[k][t]["u_ratio"]) for t in incid for k in ("single", "all")])
    ratios = _table(header, rows)
    t0, t1 = incid
    preset = next((v for v in d["variants"] if v["name"] == "preset"), None)
    ref = preset["pooled"]["all"][t1]["normal_view"] if preset else None

    def level_colour(nv: list) -> list[str]:
        """A normal view's level over the preset's (at 550 nm) and its colour (450 and 650 over 550 nm)."""
        level = f"{nv[1] / ref[1]:.2f}" if ref else ""
        return [level, f"{nv[0] / nv[1]:.2f} / {nv[2] / nv[1]:.2f}"]

    header2 = ["variant", "felt: volume fraction, thickness", f"multiply scattered share of the rings, θi {t0}°",
               f"ratio's standard error from the seeds' scatter, θi {t0}°, all orders",
               f"β towards the normal at θi {t1}°, 550 nm, over the preset's", "its colour: β450 / β550, β650 / β550",
               "seeds, CPU seconds (all its traces)"]
    rows2 = [["the RGL file", "", "", "", *level_colour(f[t1]["normal_view"]), ""]]
    for v in d["variants"]:
        s, a = v["pooled"]["single"][t0], v["pooled"]["all"][t0]
        share = [1.0 - (s["ring_6"][k] + s["ring_30"][k]) / (a["ring_6"][k] + a["ring_30"][k]) for k in range(3)]
        felts = [r["felt"] for r in v["runs"]]
        spread = a["u_ratio_seeds"]
        rows2.append([v["label"], f"{statistics.mean(x for f_ in felts for x in f_['volume_fraction']):.3f}, "
                      f"{statistics.mean(x for f_ in felts for x in f_['thickness_um']) / 1000:.2f} mm",
                      _pair(share, digits=2), _pair(spread) if spread[1] is not None else "",
                      *level_colour(v["pooled"]["all"][t1]["normal_view"]),
                      f"{len(v['runs'])}, {v['cpu_seconds']:.0f}"])
    others = _table(header2, rows2)
    st = d["settings"]
    note = (f" (each variant traced at {st['seeds']} seeds, each with its own felts, table and rays, at target "
            f"{100 * st['target_rel_err']:g} %, {st['ring_points']} directions on each "
            "ring; the seeds' rings pooled; 550 / 650 nm; ± one standard error, each ring point's error taken as "
            "independent"
            + ("" if d.get("complete") else "; the scan is incomplete: variants missing") + ")")
    split = _felt_split_table(d, incid)
    if split:
        note += (". Third table: the variants traced with `--split`; each part's share of the light on the ring 30° "
                 "from retro and its own ratio (the all-orders ratio is the shares' weighted sum of the parts' ratios); "
                 "the multiply scattered part is all orders less the two single-scattering parts")
    return ratios + "\n\n" + others + ("\n\n" + split if split else "") + "\n\n" + _source(rec, note)


def _felt_split_table(d: dict[str, Any], incid: list[str]) -> str:
    """The opposition ratio taken apart: the first fiber's surface reflection, the light through it, the rest."""
    rows = []
    for v in d["variants"]:
        o = v["pooled"]
        if "surface" not in o or "volume" not in o:
            continue
        for t in incid:
            a, s_, b = o["all"][t], o["surface"][t], o["volume"][t]
            m6 = [a["ring_6"][k] - s_["ring_6"][k] - b["ring_6"][k] for k in range(3)]
            m30 = [a["ring_30"][k] - s_["ring_30"][k] - b["ring_30"][k] for k in range(3)]
            um6 = [math.sqrt(a["u_ring_6"][k] ** 2 + s_["u_ring_6"][k] ** 2 + b["u_ring_6"][k] ** 2) for k in range(3)]
            um30 = [math.sqrt(a["u_ring_30"][k] ** 2 + s_["u_ring_30"][k] ** 2 + b["u_ring_30"][k] ** 2)
                    for k in range(3)]
            cells = []
            for r6, r30, u6, u30 in ((s_["ring_6"], s_["ring_30"], s_["u_ring_6"], s_["u_ring_30"]),
                                     (b["ring_6"], b["ring_30"], b["u_ring_6"], b["u_ring_30"]), (m6, m30, um6, um30)):
                ratio = [r6[k] / r30[k] for k in range(3)]
                u = [ratio[k] * math.hypot(u6[k] / r6[k], u30[k] / r30[k]) for k in range(3)]
                share = [r30[k] / a["ring_30"][k] for k in range(3)]
                cells += [_pair(share, digits=2), _pair(ratio, u)]
            excess = a["ratio"][2] - a["ratio"][1]
            cells.append(f"{_pair(a['ratio'], a['u_ratio'])}; {excess:+.3f} ± {math.hypot(a['u_ratio'][1], a['u_ratio'][2]):.3f}")
            rows.append([v["label"], f"{t}°", *cells])
    if not rows:
        return ""
    header = ["variant", "θi", "surface reflection at the first fiber: share", "its ratio",
              "through the first fiber, out of it: share", "its ratio", "multiply scattered: share", "its ratio",
              "all orders: ratio; 650 nm less 550 nm"]
    return _table(header, rows)


def fig_felt_opposition_lambertian() -> str:
    """The preset's felts with opaque Lambertian fibers: the opposition ratio against the albedo, read at the file's levels.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-opposition.json``).
    """
    rec = load("felt-opposition")
    d = rec["data"]
    lamb = d.get("lambertian") or {}
    if not lamb.get("pooled"):
        return "(not traced: `python docs/scripts/felt_opposition_scan.py --resume --lambertian`)\n\n" + _source(rec)
    incid = [f"{t:g}" for t in d["settings"]["incidences_deg"]]
    p, share, f = lamb["pooled"], lamb["multiple_share"], d["file"]["incidences"]
    header = ["albedo"] + [f"θi {t}°: {c}" for t in incid for c in (
        "single scattering ratio", "all orders ratio", "multiply scattered share, ring 6° / 30°", "β towards the normal")]
    rows = []
    for k, a in enumerate(lamb["albedos"]):
        row = [f"{a:g}"]
        for t in incid:
            s_, al = p["single"][t], p["all"][t]
            row += [f"{s_['ratio'][k]:.3f} ± {s_['u_ratio'][k]:.3f}", f"{al['ratio'][k]:.3f} ± {al['u_ratio'][k]:.3f}",
                    f"{share[t]['ring_6'][k]:.2f} / {share[t]['ring_30'][k]:.2f}", f"{al['normal_view'][k]:.3f}"]
        rows.append(row)
    rows.append(["the RGL file, 550 / 650 nm"] + [c for t in incid for c in (
        "", _pair(f[t]["ratio"]), "", _pair(f[t]["normal_view"]))])
    curve = _table(header, rows)
    names = {"normal_view": "β towards the normal", "ring_6": "β on the ring 6°", "ring_30": "β on the ring 30°"}
    header2 = ["matched to the file's", "θi", "albedo at 550 / 650 nm", "felt's ratio at 550 / 650 nm",
               "its 650 nm less 550 nm", "the file's ratio", "the file's 650 nm less 550 nm"]
    rows2 = []
    for m, by in lamb["readoff"].items():
        for t in incid:
            r = by[t]
            at = r["at"]
            cells = ["outside the traced albedos"] * 3
            if r["excess"] is not None:
                cells = [f"{at[0]['albedo']:.3f} ± {at[0]['u_albedo']:.4f} / {at[1]['albedo']:.3f} ± {at[1]['u_albedo']:.4f}",
                         f"{at[0]['ratio']:.3f} ± {at[0]['u_ratio']:.3f} / {at[1]['ratio']:.3f} ± {at[1]['u_ratio']:.3f}",
                         f"{r['excess']:+.3f} ± {r['u_excess']:.3f}"]
            rows2.append([names[m], f"{t}°", *cells, _pair(f[t]["ratio"]), f"{r['file_excess']:+.3f}"])
    readoff = _table(header2, rows2)
    header3 = ["albedo at 550 nm"] + [f"θi {t}°: {c}" for t in incid for c in (
        "albedo at 650 nm", "650 nm less 550 nm", "β towards the normal at 550 nm over the file's")]
    rows3 = []
    for k, a in enumerate(lamb["albedos"]):
        row = [f"{a:g}"]
        for t in incid:
            fam = lamb["readoff"]["normal_view"][t]["family"][k]
            if fam["albedo_second"] is None:
                row += ["below the traced albedos", "", ""]
            else:
                row += [f"{fam['albedo_second']:.3f}", f"{fam['excess']:+.3f}",
                        f"{fam['level_first'] / f[t]['normal_view'][1]:.2f}"]
        rows3.append(row)
    family = _table(header3, rows3)
    st = d["settings"]
    ratio = {t: lamb["readoff"]["normal_view"][t]["file_level_ratio"] for t in incid}
    note = (f" (the preset's felts at the scan's {len(lamb['runs'])} seeds, every albedo on the same paths, target "
            f"{100 * st['target_rel_err']:g} %; {lamb.get('cpu_seconds', 0):.0f} CPU seconds; ± one standard error. "
            "Second table: the all-orders curves read, linearly between the traced albedos, at the file's 550 and 650 nm "
            "levels. Third table: the albedo pairs whose β towards the normal keeps the file's 650 / 550 nm ratio ("
            + ", ".join(f"{ratio[t]:.3f} at {t}°" for t in incid) + ") whatever the level)")
    return curve + "\n\n" + readoff + "\n\n" + family + "\n\n" + _source(rec, note)


def fig_felt_demo_plan() -> str:
    """Variants of ``green-felt-mc`` traced at the demo's plan against ``gonio truth`` of the felt's file.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-demo-plan.json``).
    """
    rec = load("felt-demo-plan")
    d = rec["data"]
    incid = list(d["runs"][0]["nrmse_by_incidence"])
    header = [f"run ({100 * d['target_rel_err']:g} % target)", f"NRMSE overall ({' / '.join(incid)} deg)", "dh / ds", "k_Y",
              "CPU (user + system), peak RSS"]
    rows = [[r["label"], f"{r['nrmse']:.3f} (" + " / ".join(f"{r['nrmse_by_incidence'][t]:.3f}" for t in incid) + ")",
             f"{r['dh']:.3f} / {r['ds']:.3f}", f"{r['k_Y']:.2f}", f"{r['cpu_seconds']:.0f} s, {r['peak_rss_gb']:.2f} GB"]
            for r in d["runs"]]
    note = (f" (the file: `{d['file']}`; each run: `simulate fabric CONFIG --method mc --plan {d['plan']} "
            f"--target-rel-err {d['target_rel_err']:g} --threads 2 --out DIR/RUN`)")
    return _table(header, rows) + "\n\n" + _source(rec, note)


def _residual_label(run: str) -> str:
    """A run's name as the tables show it."""
    return f"`{run.rstrip('/').rsplit('/', 1)[-1]}`"


def _residual_runs(rec: dict[str, Any]) -> str:
    """Per run: NRMSE overall and per incidence, the forward region's share and the forward rise."""
    d = rec["data"]
    runs = d["runs"]
    first = next(iter(runs.values()))
    incid = list(first["by_incidence"])
    rise = list(first["forward_rise"])
    has_rings = any(r["by_region"][k].get("n") for r in runs.values() for k in ("ring-6", "ring-30"))
    has_grazing = any(r["by_region"]["grazing"].get("n") for r in runs.values())
    plane = ("back", "near", "forward") + (("grazing",) if has_grazing else ())
    parts = plane + (("rings",) if has_rings else ())
    header = ["run", f"NRMSE ({' / '.join(incid)} deg)", f"share of the squared error: {' / '.join(parts)}",
              f"forward rise β(70)/β(30) at {' / '.join(rise)} deg", "dh / ds / k_Y"]
    file_rise = " / ".join(f"{first['forward_rise'][t]['measured']:.2f}" for t in rise)
    rows = [["the file", "-", "-", file_rise, "-"]]
    for run, r in runs.items():
        reg = r["by_region"]
        ring = sum(reg[k].get("share", 0.0) for k in ("ring-6", "ring-30"))
        shares = " / ".join(f"{100 * reg[k].get('share', 0.0):.0f} %" for k in plane)
        shares += f" / {100 * ring:.0f} %" if has_rings else ""
        c = r["colour"]
        rows.append([_residual_label(run),
                     f"{r['nrmse']:.3f} (" + " / ".join(f"{r['by_incidence'][t]['nrmse_own']:.3f}" for t in incid) + ")",
                     shares,
                     " / ".join(f"{r['forward_rise'][t]['simulated']:.2f}" for t in rise),
                     f"{c['dh']:+.3f} / {c['ds']:+.3f} / {c['k_Y']:.2f}"])
    return _table(header, rows)


def _residual_split(r: dict[str, Any]) -> str:
    """One run's squared error by incidence and region: share, the NRMSE without it, the bias."""
    incid = list(r["by_incidence"])
    regions = [k for k in ("back", "near", "forward", "grazing", "ring-6", "ring-30")
               if r["by_region"][k].get("n")]
    header = ["theta_i", *[f"{k}: share, NRMSE without, bias" for k in regions], "all regions: share"]
    rows = []
    for t in incid:
        cells = []
        for k in regions:
            v = r["by_incidence_region"].get(f"{t}|{k}", {"n": 0})
            cells.append("-" if not v.get("n") else
                         f"{100 * v['share']:.1f} %, {v['nrmse_without']:.3f}, {v['bias_rel']:+.3f}")
        rows.append([t, *cells, f"{100 * r['by_incidence'][t]['share']:.1f} %"])
    rows.append(["all", *[f"{100 * r['by_region'][k]['share']:.1f} %, {r['by_region'][k]['nrmse_without']:.3f}, "
                          f"{r['by_region'][k]['bias_rel']:+.3f}" for k in regions], "100 %"])
    return _table(header, rows)


def _residual_profile(runs: dict[str, Any]) -> str:
    """The model over the file in plane (band sums), mean and range over the runs, per incidence and ``s``."""
    profs = [r["profile"] for r in runs.values()]
    incid = list(profs[0])
    angles = sorted({float(a) for p in profs for t in incid for a in p[t]})
    keys = [f"{a:g}" for a in angles]
    rows = []
    for t in incid:
        cells = []
        for a in keys:
            vals = [p[t][a] for p in profs if a in p.get(t, {})]
            cells.append(f"{statistics.fmean(vals):.2f}" if vals else "-")
        rows.append([t, *cells])
    return _table(["theta_i \\ s", *keys], rows)


def fig_felt_residual() -> str:
    """``green-felt-mc`` against the felt's file at the demo's plan: per seed and target, and the split of one run.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual.json``).
    """
    rec = load("felt-residual")
    first_run, first = next(iter(rec["data"]["runs"].items()))
    note = (f" (`FILE`: `gonio truth fixtures/real/acrylic_felt_green_rgb.bsdf --plan green-felt`; the runs "
            "`simulate fabric green-felt-mc --method mc --plan green-felt --target-rel-err T --seed S --threads 1`). "
            f"Second table: {_residual_label(first_run)} split by incidence and region (share of the squared error, "
            "the NRMSE if those points matched exactly, the mean residual over the file's mean β). Third table: the "
            "model over the file in plane, each summed over the wavelengths, mean of the runs (s < 0: the source's "
            "side; the mirror direction is s = theta_i)")
    return (_residual_runs(rec) + "\n\n" + _residual_split(first) + "\n\n" + _residual_profile(rec["data"]["runs"])
            + "\n\n" + _source(rec, note))


def fig_felt_residual_measured() -> str:
    """The same split at the file's measured incidences up to 59.52 deg, with the retro rings.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-measured.json``).
    """
    rec = load("felt-residual-measured")
    d = rec["data"]
    run, r = next(iter(d["runs"].items()))
    plane = r["by_plane"]
    text = (f"{_residual_label(run)}: NRMSE {r['nrmse']:.3f} over {r['n']} points; in plane {100 * plane['in plane']['share']:.0f} % of the "
            f"squared error ({plane['in plane']['n']} points), out of plane {100 * plane['out of plane']['share']:.0f} % "
            f"({plane['out of plane']['n']} points, NRMSE without them {plane['out of plane']['nrmse_without']:.3f}).")
    note = (f" (`FILE`: `gonio truth fixtures/real/acrylic_felt_green_rgb.bsdf --plan measured`, cut at "
            f"{d['max_incidence']:g} deg; the runs `simulate fabric green-felt-mc --method mc --plan measured59.toml "
            "--target-rel-err T --seed S --threads 1`). Second table: the first run split by incidence and region")
    return _residual_runs(rec) + "\n\n" + _residual_split(r) + "\n\n" + text + "\n\n" + _source(rec, note)


def fig_felt_residual_noise() -> str:
    """Seed-to-seed noise of ``green-felt-mc`` in NRMSE units.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-noise.json``).
    """
    rec = load("felt-residual-noise")
    rows = [[_residual_label(p["a"]) + " / " + _residual_label(p["b"]), f"{p['nrmse_seeds']:.3f}",
             f"{p['nrmse_noise_a']:.3f} / {p['nrmse_noise_b']:.3f}"] for p in rec["data"]["pairs"]]
    return _table(["seeds", "noise of one run (from the pair)", "the runs' own u_sim, as if independent"], rows) + \
        "\n\n" + _source(rec)


def fig_felt_realisations() -> str:
    """Seeds of ``green-felt-mc`` per felt realisation count (``felt_residual.py realisations``).

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-realisations.json``).
    """
    rec = load("felt-realisations")
    rows = []
    for g in rec["data"]["groups"]:
        runs = g["runs"]
        rows.append([f"`{g['group']}`", str(g["realisations"]), f"{100 * g['target_rel_err']:g} %",
                     " / ".join(f"{r['nrmse']:.3f}" for r in runs),
                     f"{g['nrmse_std']:.4f} ({g['nrmse_range']:.3f})", f"{g['noise_one_run']:.3f} ({g['pairs']})",
                     f"{g['z_rms']:.2f} ({100 * g['z_above_2']:.1f} %)", f"{100 * g['rel_err_mean']:.2f} %",
                     f"{g['rays_mean'] / 1e3:.0f} k",
                     f"{g['cpu_s_mean']:.1f} s" if g.get("cpu_s_mean") is not None else "-",
                     f"{g['peak_rss_mb_mean'] / 1024:.2f} GB" if g.get("peak_rss_mb_mean") is not None else "-"])
    header = ["runs", "realisations", "target", "NRMSE per seed", "NRMSE std (range)", "noise of one run (pairs)",
              "z RMS (beyond 2)", "reported error", "rays", "CPU", "peak RSS"]
    return _table(header, rows) + "\n\n" + _source(rec)


def fig_felt_residual_sensitivity() -> str:
    """One-at-a-time variants of ``green-felt-mc`` at 5 %, seed 0.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-sensitivity.json``).
    """
    rec = load("felt-residual-sensitivity")
    note = (" (each run `simulate fabric CONFIG --method mc --plan green-felt --target-rel-err 0.05 --threads 1`, "
            "CONFIG from `python docs/scripts/felt_residual.py variants --out DIR`)")
    return _residual_runs(rec) + "\n\n" + _source(rec, note)


def _third_cells(runs: list[dict[str, Any]], group: str) -> tuple[str, str]:
    """Mean over ``runs`` of a wavelength third's part of ``NRMSE^2`` (its forward side's in brackets).

    With the model's forward rise at 30 / 45 deg there.
    """
    part = statistics.fmean(r["by_band_group"][group]["contribution"] for r in runs)
    fwd = statistics.fmean(r["by_band_group_region"][f"{group}|forward"]["contribution"] for r in runs)
    rise = " / ".join(f"{statistics.fmean(r['forward_rise_by_band_group'][group][t]['simulated'] for r in runs):.2f}"
                      for t in ("30", "45"))
    return f"{part:.4f} ({fwd:.4f})", rise


def _residual_thirds(green: dict[str, Any], permuted: dict[str, Any]) -> str:
    """Per wavelength third: the green preset against the green file and the permuted refit against the permuted file.

    The green preset's runs at 3 % and the permuted refit's runs (all but the one at the preset's dye):
    each third's part of ``NRMSE^2`` (the forward side's) and the forward rise, file and model.
    """
    g_runs = [r for k, r in green["runs"].items() if _residual_label(k).startswith("`preset-t3-")]
    p_runs = [r for k, r in permuted["runs"].items() if "preset-dye" not in k]
    header = ["wavelengths", "green: file's rise at 30 / 45 deg", "green preset: NRMSE² part (forward), its rise",
              "permuted: file's rise at 30 / 45 deg", "permuted refit: NRMSE² part (forward), its rise",
              "permuted less green: NRMSE² part (forward)"]
    rows = []
    for group in g_runs[0]["by_band_group"]:
        cells = []
        for runs in (g_runs, p_runs):
            file_rise = " / ".join(f"{runs[0]['forward_rise_by_band_group'][group][t]['measured']:.2f}" for t in ("30", "45"))
            part, rise = _third_cells(runs, group)
            cells += [file_rise, f"{part}, {rise}"]
        diff = (statistics.fmean(r["by_band_group"][group]["contribution"] for r in p_runs)
                - statistics.fmean(r["by_band_group"][group]["contribution"] for r in g_runs))
        diff_f = (statistics.fmean(r["by_band_group_region"][f"{group}|forward"]["contribution"] for r in p_runs)
                  - statistics.fmean(r["by_band_group_region"][f"{group}|forward"]["contribution"] for r in g_runs))
        rows.append([group, *cells, f"{diff:+.4f} ({diff_f:+.4f})"])
    total = [statistics.fmean(r["nrmse"] ** 2 for r in runs) for runs in (g_runs, p_runs)]
    rows.append(["all", "-", f"{total[0]:.4f} (NRMSE {math.sqrt(total[0]):.3f})", "-",
                 f"{total[1]:.4f} (NRMSE {math.sqrt(total[1]):.3f})", f"{total[1] - total[0]:+.4f}"])
    return _table(header, rows)


def fig_felt_residual_permuted() -> str:
    """The green felt's file with its channels permuted, refitted in the dye only, against the permuted file.

    By wavelength third, beside the green preset against the green file.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-permuted.json``, ``docs/data/felt-residual.json``).
    """
    rec = load("felt-residual-permuted")
    green = load("felt-residual")
    note = (" (`FILE`: `gonio truth felt_gbr.bsdf --plan green-felt`, felt_gbr.bsdf the green felt's file with new "
            "R, G, B = old G, B, R; DATA `gonio demo --sample felt_gbr.bsdf --plan green-felt`; `FIT` `simulate fit "
            "green-felt-mc DATA --method mc --free dye --max-runs 3 --target-rel-err 0.03 --out FIT`: "
            "`permuted-preset-dye` its first run (`FIT/initial`, the preset's dye, seed 0), `permuted-dye-s0` its result "
            "(`FIT/fitted`), `permuted-dye-sS` `simulate fabric FIT/fitted.toml --method mc --plan green-felt "
            "--target-rel-err 0.03 --seed S --threads 1`). "
            "Second table: per wavelength third, the mean of the green preset's three seeds at 3 % "
            "(`docs/data/felt-residual.json`) against the green file and of the refitted dye's runs above against the "
            "permuted file: the third's part of NRMSE² "
            "(its forward side's in brackets; the parts add up to NRMSE²) and the forward rise β(70)/β(30) at 30 / 45 deg")
    return (_residual_runs(rec) + "\n\n" + _residual_thirds(green["data"], rec["data"]) + "\n\n"
            + _source(rec, note))


def fig_felt_residual_combined() -> str:
    """The combined structure variant with its dye refitted, against the green file.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-combined.json``).
    """
    rec = load("felt-residual-combined")
    note = (" (`FILE`: `gonio truth fixtures/real/acrylic_felt_green_rgb.bsdf --plan green-felt`; the runs: "
            "`preset-t3-sS` as in the first figure; DATA `gonio demo --sample fixtures/real/acrylic_felt_green_rgb.bsdf "
            "--plan green-felt`; `FIT` `simulate fit combined.toml DATA --method mc --free dye --max-runs 3 "
            "--target-rel-err 0.03 --out FIT`, combined.toml from `felt_residual.py combine`: `combined-t3-s0` its first "
            "run (`FIT/initial`, the preset's dye, seed 0), `combined-dye-s0` its result (`FIT/fitted`), "
            "`combined-dye-sS` `simulate fabric FIT/fitted.toml --method mc --plan green-felt --target-rel-err 0.03 "
            "--seed S --threads 1`)")
    return _residual_runs(rec) + "\n\n" + _source(rec, note)


def _config_label(config: str) -> str:
    """A config as the tables name it: its file's stem (``DIR/fuzz-0.1-300.toml`` -> ``fuzz-0.1-300``)."""
    return f"`{config.rstrip('/').rsplit('/', 1)[-1].removesuffix('.toml')}`"


def fig_felt_top(merge: int = 2) -> str:
    """The felt's volume fraction against the depth below its top, the preset's felt and its loose tops.

    From ``felt_residual.py top``; ``merge`` of the run's layers are averaged into one column.

    Parameters
    ----------
    merge : int
        Layers per column.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-top.json``).
    """
    rec = load("felt-top")
    d = rec["data"]
    step = d["bin_um"] * merge
    profiles = {name: [statistics.fmean(p[k:k + merge]) for k in range(0, len(p), merge)]
                for name, p in d["profiles"].items()}
    columns = max(len(p) for p in profiles.values())
    header = ["felt", *[f"{k * step:g}-{(k + 1) * step:g}" for k in range(columns)]]
    rows = [[_config_label(name), *["0" if v == 0 else f"{v:.3f}" for v in p]] for name, p in profiles.items()]
    note = (f" (depth below the felt's top in µm; the felts of streams 0 .. {d['seeds'] - 1} pooled, "
            f"{merge} layers of {d['bin_um']:g} µm averaged in each column)")
    return _table(header, rows) + "\n\n" + _source(rec, note)


def fig_felt_residual_fuzz() -> str:
    """The loose-top variants of ``green-felt-mc`` against the felt's file.

    The split of section 8, the NRMSE with each band's least-squares factor and the mean residual per region.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-fuzz.json``).
    """
    rec = load("felt-residual-fuzz")
    plane = ("back", "near", "forward")
    rows = [[_residual_label(run), f"{r['nrmse_best_scale']:.3f}",
             " / ".join(f"{r['by_region'][k]['bias_rel']:+.3f}" for k in plane)] for run, r in rec["data"]["runs"].items()]
    bias = _table(["run", "NRMSE, each band's least-squares factor",
                   f"mean residual over the file's mean β: {' / '.join(plane)}"], rows)
    note = (" (`DIR/file`: `gonio truth fixtures/real/acrylic_felt_green_rgb.bsdf --plan green-felt --out DIR/file`; "
            "each run `simulate fabric CONFIG --method mc --plan green-felt --target-rel-err 0.05 --seed S --threads 1 "
            "--out DIR/RUN`. Second table: `nrmse_best_scale` and `by_region` of the same runs)")
    return _residual_runs(rec) + "\n\n" + bias + "\n\n" + _source(rec, note)


def fig_felt_lambert() -> str:
    """The in-plane forward rise of the felts with opaque Lambertian fibres (``felt_residual.py lambert``).

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-lambert.json``).
    """
    rec = load("felt-lambert")
    d = rec["data"]
    albedos = d["albedos"]
    first = next(iter(d["rise"].values()))
    incid = [k.split(" ", 1)[1] for k in first if k.startswith("single ")]
    header = ["felt", f"single scattering at {' / '.join(incid)} deg",
              *[f"all orders, albedo {a:g}" for a in albedos]]
    rows = []
    for name, rise in d["rise"].items():
        cells = [" / ".join(f"{rise[f'single {t}']['ratio'][0]:.3f}" for t in incid)]
        cells += [" / ".join(f"{rise[f'all {t}']['ratio'][k]:.3f}" for t in incid) for k in range(len(albedos))]
        rows.append([_config_label(name), *cells])
    se = [e for rise in d["rise"].values() for v in rise.values() for e in v["se"]]
    note = (f" (β(70)/β(30) in plane on the mirror's side, felt of stream 0, each the mean of 8 turns of the "
            f"incidence about the normal; standard error {min(se):.3f}-{max(se):.3f})")
    return _table(header, rows) + "\n\n" + _source(rec, note)


def fig_fiber_phase() -> str:
    """The fibre's own phase at the felt's normal incidence (``felt_residual.py phase``).

    ``p(110)/p(150)`` of the preset fibre and its variants, the curve, and the felt traced in single scattering
    against what the phase predicts (``felt-lambert``'s single scattering of the opaque Lambertian felt sets
    the felt's own factor).

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/fiber-phase.json``, ``docs/data/felt-lambert.json``).
    """
    rec = load("fiber-phase")
    d = rec["data"]
    lam = d["lambert"]
    configs = d["configs"]
    first = next(iter(configs.values()))
    bands = [b for b in first["bands"] if b != "all"]
    views = first["views_deg"]
    photons, tables = first["photons_per_row"], first["tables"]
    header = ["fibre", f"p(110)/p(150): {' / '.join(bands)}", "all bands", f"volume albedo: {' / '.join(bands)}",
              "surface albedo", "share into the source's half"]
    rows = [["opaque Lambertian", f"{lam['ratio']:.3f}", f"{lam['ratio']:.3f}", "-", "-",
             f"{lam['upper_share']:.2f}" if "upper_share" in lam else "-"]]
    for name, r in configs.items():
        b = r["bands"]
        rows.append([_config_label(name), " / ".join(f"{b[k]['ratio']:.3f}" for k in bands),
                     f"{b['all']['ratio']:.3f} ± {b['all']['se']:.3f}",
                     " / ".join(f"{b[k]['volume_albedo']:.3f}" for k in bands), f"{r['surface_albedo']:.3f}",
                     f"{b['all']['upper_share']:.2f}"])
    variants = _table(header, rows)
    shown = [k for k, v in enumerate(views) if v >= 0]
    head = ["fibre", *[f"{views[k]:g} ({180 - views[k]:g})" for k in shown]]

    def normalised(curve: list[float]) -> list[str]:
        at0 = curve[views.index(0.0)]
        return [f"{curve[k] / at0:.3f}" for k in shown]

    crows = [["opaque Lambertian", *normalised(lam["curve"])]]
    name0 = next(iter(configs))
    crows += [[f"{_config_label(name0)} {b}", *normalised(first["bands"][b]["curve"])] for b in (*bands, "all")]
    crows += [[f"{_config_label(name0)} {b}, volume share",
               *[f"{first['bands'][b]['volume_share'][k]:.2f}" for k in shown]] for b in ("all",)]
    curve = _table(head, crows)
    out = [variants, curve]
    if d.get("felt"):
        lam_felt = load("felt-lambert")["data"]["rise"]["green-felt-mc"]["single 0"]
        own = lam_felt["ratio"][0] / lam["ratio"]
        fhead = ["config", "band", "p(110)/p(150)", f"× {d['factor_isotropic']:.2f} (isotropic extinction)",
                 f"× {d['factor_plane']:.2f} (fibres in the plane)", f"× {own:.2f} (the Lambertian felt's)",
                 "felt, single scattering", "felt, all orders"]
        frows = []
        for name, felt in d["felt"].items():
            for b in (*bands, "all"):
                p = configs[name]["bands"][b]["ratio"]
                frows.append([_config_label(name), b, f"{p:.3f}", f"{p * d['factor_isotropic']:.3f}",
                              f"{p * d['factor_plane']:.3f}", f"{p * own:.3f}",
                              f"{felt['single']['bands'][b]['ratio']:.3f} ± {felt['single']['bands'][b]['se']:.3f}",
                              f"{felt['all']['bands'][b]['ratio']:.3f} ± {felt['all']['bands'][b]['se']:.3f}"])
        out.append(_table(fhead, frows))
    if d.get("oblique"):
        ob = d["oblique"]
        inc = next(iter(ob.values()))["incidences_deg"]
        ohead = ["fibre", f"S(70)/S(30) on the mirror's side at {' / '.join(f'{t:g}' for t in inc)} deg"]
        orows = [["opaque Lambertian", " / ".join(f"{r:.3f}" for r in next(iter(ob.values()))["lambert"])]]
        orows += [[_config_label(name), " / ".join(f"{r:.3f} ± {e:.3f}" for r, e in zip(
            o["bands"]["all"]["ratio"], o["bands"]["all"]["se"], strict=True))] for name, o in ob.items()]
        out.append(_table(ohead, orows))
    note = (f" (normal incidence on the felt, the fibre's axis in the felt's plane at {first['azimuths']} azimuths; "
            f"{tables} independent exit tables of {photons} photons per row, ± their standard error; second table: "
            f"S over S at the normal against the view angle, the scattering angle in brackets; third table: "
            f"β(70)/β(30) of the felt at normal incidence, both sides' mean"
            + ("; last table: the fibre at oblique beams, the source on the felt's -x side, all bands" if d.get("oblique")
               else "") + ")")
    return "\n\n".join(out) + "\n\n" + _source(rec, note)

def _residual_bias(rec: dict[str, Any]) -> str:
    """Per run: the NRMSE with each band's least-squares factor and the mean residual per in-plane region."""
    plane = ("back", "near", "forward")
    rows = [[_residual_label(run), f"{r['nrmse_best_scale']:.3f}",
             " / ".join(f"{r['by_region'][k]['bias_rel']:+.3f}" for k in plane)] for run, r in rec["data"]["runs"].items()]
    return _table(["run", "NRMSE, each band's least-squares factor",
                   f"mean residual over the file's mean β: {' / '.join(plane)}"], rows)


def fig_felt_residual_phase() -> str:
    """The fibre variants whose phase reaches the file's demand, traced in the felt and split as in section 8.

    The variants are those of ``fiber-phase``; with each band's least-squares NRMSE and the mean residual per region.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-phase.json``).
    """
    rec = load("felt-residual-phase")
    bias = _residual_bias(rec)
    note = (" (`DIR/file`: `gonio truth fixtures/real/acrylic_felt_green_rgb.bsdf --plan green-felt --out DIR/file`; "
            "each run `simulate fabric CONFIG --method mc --plan green-felt --target-rel-err 0.05 --seed 0 --threads 1 "
            "--out DIR/RUN`, CONFIG the preset or its variant of `felt_residual.py phase --variants`, the dye the "
            "preset's unless named)")
    return _residual_runs(rec) + "\n\n" + bias + "\n\n" + _source(rec, note)

#: The felt's forward rise over its fibre's S(70)/S(30) (``fiber-phase``, ``felt-residual-phase``): at the normal
#: 1.54 (the preset fibre in single scattering) to 1.75 (the fibres whose lobe the boundary smears), at the oblique
#: beams 1.75; the file's rise over it is the fibre's S(70)/S(30) the file asks (``fiber-phase-twofield``)
TWOFIELD_FACTORS_NORMAL = (1.54, 1.75)
TWOFIELD_FACTOR = 1.75


def twofield_asked(file_rise: dict[str, float]) -> dict[str, tuple[float, float]]:
    """The fibre's ``S(70)/S(30)`` the file's forward rise asks per incidence: ``(low, high)``.

    A range at the normal (the file's rise over :data:`TWOFIELD_FACTORS_NORMAL`), one value at the
    oblique beams (over :data:`TWOFIELD_FACTOR`).

    Parameters
    ----------
    file_rise : dict of str to float
        The file's forward rise by incidence (``"0"``, ``"27.76"``, ...).

    Returns
    -------
    dict of str to tuple of (float, float)
        The asked range by incidence (low equal to high at the oblique beams).
    """
    out = {}
    for t, rise in file_rise.items():
        if float(t) == 0.0:
            out[t] = (rise / max(TWOFIELD_FACTORS_NORMAL), rise / min(TWOFIELD_FACTORS_NORMAL))
        else:
            out[t] = (rise / TWOFIELD_FACTOR, rise / TWOFIELD_FACTOR)
    return out


def twofield_distance(ratios: list[float], asked: list[tuple[float, float]]) -> float:
    """``sum ln(S / asked)^2`` over the incidences, ``asked`` the nearest end of its range (0 inside it).

    Parameters
    ----------
    ratios : list of float
        The fibre's ``S(70)/S(30)`` per incidence.
    asked : list of tuple of (float, float)
        The asked range per incidence, in the same order (:func:`twofield_asked`).

    Returns
    -------
    float
        The distance (0 when every ratio lies in its range).
    """
    total = 0.0
    for r, (lo, hi) in zip(ratios, asked, strict=True):
        total += math.log(r / lo) ** 2 if r < lo else math.log(r / hi) ** 2 if r > hi else 0.0
    return total


def fig_fiber_phase_twofield() -> str:
    """The fibre's ``S(70)/S(30)`` at the normal and the oblique beams over a grid of two fields.

    The fields are the boundary's slope about the axis and the reflection's slope; against what the file's
    rise asks (:func:`twofield_asked`), with the volume albedo at 510-580 nm and the distance
    :func:`twofield_distance`, its rank.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/fiber-phase-twofield.json``, ``docs/data/felt-residual.json``).
    """
    rec = load("fiber-phase-twofield")
    d = rec["data"]
    file_rise = {t: v["measured"] for t, v in next(iter(load("felt-residual")["data"]["runs"].values()))[
        "forward_rise"].items()}
    ob = d["oblique"]
    incid = ["0", *[f"{t:g}" for t in next(iter(ob.values()))["incidences_deg"]]]
    asked_of = twofield_asked(file_rise)
    asked = [asked_of[t] for t in incid]
    rows, dist = [], {}
    for name, r in d["configs"].items():
        ratios = [r["bands"]["all"]["ratio"], *ob[name]["bands"]["all"]["ratio"]]
        ses = [r["bands"]["all"]["se"], *ob[name]["bands"]["all"]["se"]]
        dist[name] = twofield_distance(ratios, asked)
        rows.append([name, " / ".join(f"{x:.3f} ± {e:.3f}" for x, e in zip(ratios, ses, strict=True)),
                     f"{r['bands']['510-580 nm']['volume_albedo']:.3f}", f"{dist[name]:.3f}"])
    rank = {name: k + 1 for k, name in enumerate(sorted(dist, key=dist.get))}
    body = [[_config_label(row[0]), *row[1:], str(rank[row[0]])] for row in rows]
    head = [["the file asks", " / ".join(f"{lo:.2f}-{hi:.2f}" if hi > lo else f"{lo:.2f}" for lo, hi in asked),
             "-", "-", "-"]]
    photons = next(iter(d["configs"].values()))["photons_per_row"]
    tables = next(iter(d["configs"].values()))["tables"]
    table = _table(["fibre (slope about the axis, reflection's slope)",
                    f"S(70)/S(30) at {' / '.join(incid)} deg", "volume albedo 510-580 nm",
                    "sum of ln(S / asked)^2", "rank"], head + body)
    note = (f" (the preset with `[surface] transmission_rms_slope_around` and `rms_slope` set, the slope along the "
            f"axis the preset's 0.1; {tables} independent exit tables of {photons} photons per row, ± their standard "
            f"error; all bands; at 0 deg both sides' mean, at the oblique beams the mirror's side; the file asks its "
            f"forward rise (`docs/data/felt-residual.json`) over the felt's factor, "
            f"{min(TWOFIELD_FACTORS_NORMAL):g}-{max(TWOFIELD_FACTORS_NORMAL):g} at the normal, {TWOFIELD_FACTOR:g} at "
            f"the oblique beams; the distance takes at the normal the nearest end of the range)")
    return table + "\n\n" + _source(rec, note)


def fig_felt_residual_twofield() -> str:
    """The Monte Carlo fit of the dye and both slopes from the closest point of ``fiber-phase-twofield``.

    Its config traced at two seeds beside the preset's, split as in section 8.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/felt-residual-twofield.json``).
    """
    rec = load("felt-residual-twofield")
    note = (" (`DIR/file`: `gonio truth fixtures/real/acrylic_felt_green_rgb.bsdf --plan green-felt --out DIR/file`; "
            "DATA `gonio demo --sample fixtures/real/acrylic_felt_green_rgb.bsdf --plan green-felt`; each run "
            "`simulate fabric CONFIG --method mc --plan green-felt --target-rel-err 0.05 --seed S --threads 1 "
            "--out DIR/RUN`, `preset-sS` the preset, `fit-*-sS` the fit's `fitted.toml` of `simulate fit START DATA "
            "--method mc --free dye,rms_slope,surface.transmission_rms_slope_around --max-runs 6 --target-rel-err 0.05 "
            "--seed 0 --threads 1`, START the grid's point it names; `fit10-*` the same fit continued to `--max-runs 10` "
            "with `--resume`)")
    return _residual_runs(rec) + "\n\n" + _residual_bias(rec) + "\n\n" + _source(rec, note)


def fig_speed_accuracy() -> str:
    """The Monte Carlo's achieved error against its marginal cost (``simulate bench --study speed-accuracy``).

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/speed-accuracy.json``).
    """
    rec = load("speed-accuracy")
    d = rec["data"]
    rows = []
    for name, f in d["fabrics"].items():
        for r in f["runs"]:
            rows.append([name, f"{r['target']:g}", f"{r['achieved_error']:.2%} ± {r['achieved_error_se']:.2%}",
                         f"{r['table_seconds']:.1f} s + {r['trace_seconds']:.1f} s",
                         f"{r['startup_seconds']:.1f} s + {r['setup_seconds']:.1f} s"])
        floors = ", ".join(f"{k} {v:.1%}" for k, v in f["model_floors"].items())
        rows.append([name, "floors", floors, "", ""])
    note = (f" (achieved error ± its sampling spread; {d['threads']} thread, each target run twice with seeds {d['seeds'][0]} and {d['seeds'][1]}, tables"
            f" floored at {d['table_floor']} photons per row)")
    return _table(["fabric", "target", "achieved error", "marginal: tables + rays", "fixed: start-up + set-up"],
                  rows) + "\n\n" + _source(rec, note)


def fig_fibre_section_screen() -> str:
    """The flattened section's forward rise against the round section's, in two dimensions.

    Returns
    -------
    str
        The block's Markdown: the table(s) and the line naming the command, the machine and the data
        (``docs/data/fibre-section-screen.json``).
    """
    rec = load("fibre-section-screen")
    d = rec["data"]
    incid = sorted({r["theta_i_deg"] for r in d["rows"]})
    rows = []
    for band in d["fibre"]["bands_nm"]:
        for orient in ("flat", "random"):
            for aspect in sorted({r["aspect"] for r in d["rows"]}):
                sel = sorted((r for r in d["rows"] if r["band_nm"] == band and r["orientation"] == orient
                              and r["aspect"] == aspect), key=lambda r: r["theta_i_deg"])
                cells = [f"{r['rise']:.2f} ± {r['rise_se']:.2f}"
                         + ("" if aspect == 1.0 else f" ({r['change']:+.0%})") for r in sel]
                raised = "" if aspect == 1.0 else str(sum(r["change"] > 2 * r["change_se"] for r in sel))
                rows.append([f"{band:.0f}", orient, f"{aspect:g}", *cells, raised])
    head = ["band (nm)", "orientation", "aspect", *[f"S(70)/S(30) at {t:.2f} deg" for t in incid],
            "raised (of 4)"]
    note = (f" ({d['rays']} rays per section and incidence, seed {d['seed']}; ± the spread over ten batches of the"
            " rays; in brackets the change from the round section; raised: changes above twice their standard"
            " error)")
    return _table(head, rows) + "\n\n" + _source(rec, note)


FIGURES: dict[str, Callable[[], str]] = {
    "fibre-section-screen": fig_fibre_section_screen,
    "speed-accuracy": fig_speed_accuracy,
    "felt-residual": fig_felt_residual,
    "felt-residual-measured": fig_felt_residual_measured,
    "felt-residual-noise": fig_felt_residual_noise,
    "felt-realisations": fig_felt_realisations,
    "felt-residual-sensitivity": fig_felt_residual_sensitivity,
    "felt-residual-permuted": fig_felt_residual_permuted,
    "felt-residual-combined": fig_felt_residual_combined,
    "felt-top": fig_felt_top,
    "felt-residual-fuzz": fig_felt_residual_fuzz,
    "felt-lambert": fig_felt_lambert,
    "fiber-phase": fig_fiber_phase,
    "felt-residual-phase": fig_felt_residual_phase,
    "fiber-phase-twofield": fig_fiber_phase_twofield,
    "felt-residual-twofield": fig_felt_residual_twofield,
    "felt-opposition": fig_felt_opposition,
    "felt-opposition-lambertian": fig_felt_opposition_lambertian,
    "felt-demo-plan": fig_felt_demo_plan,
    "slab-kernel": fig_slab_kernel,
    "driver": fig_driver,
    "method-errors": fig_method_errors,
    "method-errors-felt": fig_method_errors_felt,
    "demo-cost": fig_demo_cost,
}


def render(text: str) -> str:
    """``text`` with every marked block filled from its JSON.

    Parameters
    ----------
    text : str
        A Markdown page.

    Returns
    -------
    str
        The page with each ``BEGIN FIGURE`` / ``END FIGURE`` block's body replaced by its figure.

    Raises
    ------
    SystemExit
        A block names a figure that :data:`FIGURES` does not hold.
    """
    def fill(m: re.Match) -> str:
        """The block of the match ``m`` with its figure."""
        name = m.group(2)
        if name not in FIGURES:
            raise SystemExit(f"render_figures: unknown figure {name!r}; known: {', '.join(FIGURES)}")
        return f"{m.group(1)}{FIGURES[name]().rstrip()}\n{m.group(4)}"
    return _BLOCK.sub(fill, text)


def pages() -> list[Path]:
    """The pages that may hold figure blocks.

    Returns
    -------
    list of pathlib.Path
        README.md, then every Markdown file under docs/, sorted.
    """
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def record(name: str, source: Path, command: str) -> Path:
    """Wrap ``source`` (a run's JSON) as ``docs/data/NAME.json`` with its command and this machine.

    Parameters
    ----------
    name : str
        The figure's data name.
    source : pathlib.Path
        The run's JSON.
    command : str
        The command that wrote it.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    data = json.loads(source.read_text(encoding="utf-8"))
    out = DATA / f"{name}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"name": name, "command": command, "machine": machine(), "data": data},
                              indent=1) + "\n", encoding="utf-8")
    return out


def main(argv: list[str] | None = None) -> int:
    """Fill every figure block of the pages, check them (``--check``) or wrap a run's JSON (``--record``).

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--check``, ``--record NAME FILE.json --command CMD``);
        ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0, or 1 under ``--check`` when a page's blocks are stale (one line names the pages and the
        command that regenerates them).
    """
    ap = argparse.ArgumentParser(description="Render the documentation's measured figures from docs/data/*.json.")
    ap.add_argument("--check", action="store_true", help="exit 1 if a committed block is stale; write nothing")
    ap.add_argument("--record", nargs=2, metavar=("NAME", "FILE.json"), help="wrap a run's JSON as docs/data/NAME.json")
    ap.add_argument("--command", help="with --record: the command that wrote FILE.json")
    args = ap.parse_args(argv)
    if args.record:
        if not args.command:
            ap.error("--record needs --command (the command that produced the JSON)")
        print(record(args.record[0], Path(args.record[1]), args.command))
        return 0
    stale = []
    for path in pages():
        text = path.read_text(encoding="utf-8")
        new = render(text)
        if new != text:
            if args.check:
                stale.append(str(path.relative_to(ROOT)))
            else:
                path.write_text(new, encoding="utf-8")
    if stale:
        print(f"render_figures: stale figures in {', '.join(stale)}; regenerate with `{REGENERATE}`", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
