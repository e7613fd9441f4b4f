"""``compare report MEASURED SWEEP_DIR --out R``: a parameter sweep charted against a measurement.

A sweep directory (written by ``simulate sweep``) is recognised by its ``sweep.json``; this
module reads only that file's ``parameters`` and ``points`` (``[{"index", "dir", "label",
"values": {name: value}}]``) and the points' datasets through :mod:`gonio.data` -- nothing of
``simulate`` is imported (the data flows one way).

The report is the usual comparison report (:func:`compare.report.write_report`) of the
measurement against the sweep's points (each named by its label, ``volume_fraction=0.05``), with
one section added at the top: "Parameter sweep", a table of every point's figures and the chart
``figures/sweep_metrics.png`` of the overall NRMSE, the hue difference ``dh`` (turns) and the
saturation difference ``ds`` against the swept parameter (the first parameter with more than one
value on the x axis, one line per combination of the others; a logarithmic axis when the values
span more than two decades). The figures are those of ``compare check``: each point is compared
with the measurement on its own (:func:`point_metrics`), so they equal ``simulate sweep
--measured``'s ``summary.csv``. ``sweep_metrics.csv`` in the report folder holds the same table.

Decisions:

- The usual per-dataset sections show at most :data:`MAX_CURVES` points (evenly spaced over the
  sweep, always including the first, the last and the one of lowest NRMSE): beyond that the
  in-plane panels are unreadable, and the chart already shows every point.
- The section is added through the report's public section API
  (:class:`compare.report.Section`, placed before the "Datasets" section, its figure written and
  listed with the report's own files): the report's layout stays :mod:`compare.report`'s
  business and a plain report is unchanged.
- Points not yet complete (an interrupted sweep) are listed as such and not charted; a sweep
  without any complete point is refused (:class:`~compare.errors.CompareError`, exit 2).
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gonio.data import Dataset, atomic_write, make_dataset, read_dataset

from .comparison import compare_datasets
from .errors import CompareError
from .normalise import DEFAULT_WINDOW_DEG

__all__ = ["MAX_CURVES", "SWEEP_NAME", "is_sweep_dir", "point_metrics", "read_sweep",
           "write_sweep_report"]

SWEEP_NAME = "sweep.json"
#: Most sweep points drawn in the usual per-dataset figures of a sweep report.
MAX_CURVES = 6
_FIGURE = "sweep_metrics.png"


def is_sweep_dir(path: str | Path) -> bool:
    """True when ``path`` is a directory holding a ``sweep.json`` (a ``simulate sweep`` output).

    Parameters
    ----------
    path : str or Path
        The path to look at.

    Returns
    -------
    bool
        Whether ``path/sweep.json`` is a file.
    """
    return (Path(path) / SWEEP_NAME).is_file()


def read_sweep(path: str | Path) -> dict:
    """The ``sweep.json`` of a sweep directory, checked for what the report reads.

    Parameters
    ----------
    path : path-like
        The sweep directory (``simulate sweep --out``).

    Returns
    -------
    dict
        The document, with ``parameters`` and ``points`` as the report reads them.

    Raises
    ------
    CompareError
        A missing or unreadable ``sweep.json``, or a point whose folder leads outside the sweep.
    """
    p = Path(path) / SWEEP_NAME
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise CompareError(f"{p}: not a readable sweep description ({exc})") from None
    ok = (isinstance(doc, dict) and isinstance(doc.get("parameters"), list) and doc["parameters"]
          and isinstance(doc.get("points"), list)
          and all(isinstance(q, dict) and {"dir", "label", "values"} <= set(q) for q in doc["points"]))
    if not ok:
        raise CompareError(f"{p}: not a sweep description (parameters and points expected)")
    for q in doc["points"]:     # a point's dir is points/<one name> inside the sweep (a crafted ../.. is refused)
        parts = q["dir"].split("/") if isinstance(q["dir"], str) else []
        inside = (len(parts) == 2 and parts[0] == "points" and parts[1] not in ("", ".", "..")
                  and (Path(path) / q["dir"]).resolve().is_relative_to((Path(path) / "points").resolve()))
        if not inside:
            raise CompareError(f"{p}: point dir {q['dir']!r} is not points/<name> inside the sweep directory")
    return doc


def point_metrics(measured: Dataset, simulated: Dataset, *, window_deg: float = DEFAULT_WINDOW_DEG,
                  illuminant: str = "D65") -> dict[str, float]:
    """``{"nrmse", "dh", "ds"}`` of one simulation against ``measured`` (as ``compare check``).

    ``dh`` and ``ds`` are NaN when the measurement has no colour (photometric).

    Parameters
    ----------
    measured, simulated : gonio.data.Dataset
        The measurement and one point's dataset.
    window_deg, illuminant :
        As :func:`compare.comparison.compare_datasets`.

    Returns
    -------
    dict of str -> float
        The point's NRMSE, hue and saturation differences.
    """
    c = compare_datasets(measured, [simulated], window_deg=window_deg, illuminant=illuminant)
    name = next(iter(c.simulated))
    out = {"nrmse": float(c.overall[name].nrmse), "dh": math.nan, "ds": math.nan}
    if c.colour is not None:
        sc = c.colour.simulated[name]
        out.update(dh=float(sc.dh), ds=float(sc.ds))
    return out


def _labelled(ds: Dataset, label: str) -> Dataset:
    meta = dict(ds.meta)
    meta["sample"] = {**(meta.get("sample") or {}), "name": label}
    out = make_dataset(ds.table, meta)
    out.path = ds.path
    return out


def _subset(table: pd.DataFrame) -> list[int]:
    """Row positions of the points drawn in the usual figures (module docstring)."""
    n = len(table)
    if n <= MAX_CURVES:
        return list(range(n))
    picks = {0, n - 1}
    if table["nrmse"].notna().any():
        picks.add(int(np.nanargmin(table["nrmse"].to_numpy(float))))
    for x in np.linspace(0, n - 1, MAX_CURVES):
        if len(picks) >= MAX_CURVES:
            break
        picks.add(int(round(x)))
    return sorted(picks)


def _chart(table: pd.DataFrame, names: list[str]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    varying = [n for n in names if table[n].nunique() > 1]
    x_name = varying[0] if varying else names[0]
    others = [n for n in names if n != x_name]
    metrics = [("nrmse", "overall NRMSE")]
    if table["dh"].notna().any():
        metrics += [("dh", "hue difference dh (turns)"), ("ds", "saturation difference ds")]
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.6 * len(metrics), 3.6), squeeze=False)
    groups = table.groupby(others, sort=True) if others else [((), table)]
    x_all = table[x_name].to_numpy(float)
    log_x = bool(np.all(x_all > 0) and x_all.max() / x_all.min() > 100.0)
    for ax, (col, label) in zip(axes.ravel(), metrics, strict=True):
        for key, rows in groups:
            rows = rows.sort_values(x_name)
            key = key if isinstance(key, tuple) else (key,)
            tag = ", ".join(f"{n}={v:g}" for n, v in zip(others, key, strict=True)) or None
            ax.plot(rows[x_name].to_numpy(float), rows[col].to_numpy(float), "o-", ms=4, label=tag)
        if col != "nrmse":
            ax.axhline(0.0, color="0.5", lw=0.8, ls=":")
        if log_x:
            ax.set_xscale("log")
        ax.set_xlabel(x_name.replace("$", r"\$"))
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if others:
        axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=150, metadata={"Software": None})
    plt.close(fig)
    return buffer.getvalue()


def _section(doc: dict, table: pd.DataFrame, names: list[str], png: bytes, shown: list[str]) -> str:
    e = html.escape

    def fmt(x: Any) -> str:
        if isinstance(x, (float, np.floating)):
            return f"{x:.4g}" if math.isfinite(x) else "-"
        return e(str(x))

    method = doc.get("method", "?")
    config = (doc.get("config") or {}).get("name", "?")
    parts = ["<h2>Parameter sweep</h2>",
             f"<p>{len(table)} points of the {e(str(method))} model of the config {e(str(config))}, "
             f"sweeping {e(', '.join(names))}; each point compared with the measurement on its own "
             "(the figures of <code>compare check</code>). The figures below the chart show "
             f"{e(', '.join(shown))}.</p>",
             "<table><tr>" + "".join(f"<th>{e(n)}</th>" for n in names)
             + "<th class='l'>status</th><th>NRMSE</th><th>dh (turns)</th><th>ds</th></tr>"]
    best = int(np.nanargmin(table["nrmse"].to_numpy(float))) if table["nrmse"].notna().any() else -1
    for i in range(len(table)):
        r = table.iloc[i]
        style = " style='font-weight:bold'" if i == best else ""
        parts.append(f"<tr{style}>" + "".join(f"<td>{fmt(v)}</td>" for v in table.loc[i, names])
                     + f"<td class='l'>{e(str(r['status']))}</td><td>{fmt(r['nrmse'])}</td>"
                     f"<td>{fmt(r['dh'])}</td><td>{fmt(r['ds'])}</td></tr>")
    parts.append("</table>")
    b64 = base64.b64encode(png).decode("ascii")
    parts.append(f"<figure><img alt='sweep metrics' src='data:image/png;base64,{b64}'>"
                 "<figcaption><b>Sweep.</b> Overall NRMSE of the normalised curves"
                 + (", hue difference dh (turns of the hue circle, simulated minus measured) and "
                    "saturation difference ds" if table["dh"].notna().any() else "")
                 + " of each complete point against the swept parameter (lowest NRMSE in bold in "
                 f"the table). <span style='color:#777'>(figures/{_FIGURE})</span></figcaption></figure>")
    return "\n".join(parts) + "\n"


def write_sweep_report(measured: Dataset, sweep_dir: str | Path, out_dir: str | Path, *, svg: bool = False,
                       force: bool = False, window_deg: float = DEFAULT_WINDOW_DEG,
                       illuminant: str = "D65") -> Path:
    """The comparison report of a sweep directory against ``measured`` (module docstring).

    Parameters
    ----------
    measured : gonio.data.Dataset
        The measurement.
    sweep_dir : path-like
        The sweep directory (:func:`read_sweep`).
    out_dir : path-like
        The report's folder (the output-folder policy of :func:`compare.report.write_report`).
    svg, force :
        As :func:`compare.report.write_report`.
    window_deg, illuminant :
        As :func:`compare.comparison.compare_datasets`.

    Returns
    -------
    pathlib.Path
        The path of ``report.html``.
    """
    from .report import Section, write_report

    sweep = Path(sweep_dir)
    doc = read_sweep(sweep)
    names = [str(p["name"]) for p in doc["parameters"]]
    rows, datasets = [], {}
    for q in doc["points"]:
        row: dict[str, Any] = {n: q["values"].get(n, math.nan) for n in names}
        row.update(label=q["label"], status="incomplete (not charted)", nrmse=math.nan, dh=math.nan, ds=math.nan)
        if (sweep / q["dir"] / "meta.json").is_file():
            ds = _labelled(read_dataset(sweep / q["dir"]), q["label"])
            row.update(status="complete", **point_metrics(measured, ds, window_deg=window_deg,
                                                          illuminant=illuminant))
            datasets[q["label"]] = ds
        rows.append(row)
    table = pd.DataFrame(rows)
    if not datasets:
        raise CompareError(f"the sweep {sweep} has no complete point yet; finish it (run the same "
                           "`simulate sweep` command again)")
    complete = table[table["status"] == "complete"].reset_index(drop=True)
    shown = [complete.loc[i, "label"] for i in _subset(complete)]
    comparison = compare_datasets(measured, [datasets[s] for s in shown], window_deg=window_deg,
                                  illuminant=illuminant)
    png = _chart(complete, names)
    section = Section("sweep", _section(doc, table, names, png, shown).rstrip("\n"),
                      figures={_FIGURE: png}, before="datasets")
    report = write_report(comparison, out_dir, svg=svg, force=force, sections=[section])
    atomic_write(Path(out_dir) / "sweep_metrics.csv",
                 table.to_csv(index=False, float_format="%.10g", lineterminator="\n").encode("utf-8"))
    return report
