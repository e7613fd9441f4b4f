"""``compare report MEASURED --out DIR`` with no simulation: look at one dataset.

Draws the in-plane curves (``beta / pi`` against the signed observation angle, one panel per
incidence; per channel for RGB data, at a few wavelengths for spectra), a colour strip per
incidence (the colour at each observation angle, gamma-encoded for display only) and writes the
colour table (HSV and channel ratios on linear sRGB, docs/physics.md section 7) into ``report.html``
and ``metrics.json``. A relative dataset's V (absolute brightness) is not stated.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np

from gonio.data import Dataset, atomic_write, display_srgb

from .report import GENERATOR, prepare_out_dir, save_figure

__all__ = ["write_dataset_report"]


def _colours(ds: Dataset):
    """Colour summary at each in-plane geometry: list of dicts (theta_i, s, h, s, v, ...)."""
    frame = ds.in_plane()
    out = []
    for (ti, pi_, s), rows in frame.groupby(["theta_i", "phi_i", "s"], sort=True):
        try:
            c = ds.colour_at(ti, pi_, rows["theta_o"].iloc[0], rows["phi_o"].iloc[0])
        except ValueError:
            continue
        out.append({"theta_i": float(ti), "phi_i": float(pi_), "s_deg": float(s), **c.as_dict()})
    return out


def write_dataset_report(ds: Dataset, out_dir: str | os.PathLike, *, svg: bool = False,
                         force: bool = False) -> Path:
    """Write ``report.html``, ``metrics.json`` and ``figures/*.png`` for one dataset."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    old = prepare_out_dir(out, force)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    frame = ds.in_plane()
    incidences = sorted(set(frame["theta_i"]))
    band = ds.band_column
    bands = list(ds.bands)
    if not ds.is_rgb and len(bands) > 5:
        bands = [bands[int(k)] for k in np.linspace(0, len(bands) - 1, 5).round()]
    figures = []
    if incidences:
        fig, axes = plt.subplots(1, len(incidences), figsize=(3.2 * len(incidences), 3.2),
                                 squeeze=False, sharey=True)
        colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue", "Y": "black"}
        for ax, ti in zip(axes[0], incidences):
            for b in bands:
                rows = frame[(frame["theta_i"] == ti) & (frame[band] == b)]
                label = str(b) if ds.is_rgb else f"{b:g} nm"
                ax.errorbar(rows["s"], rows["beta"] / np.pi, yerr=rows["u_beta"] / np.pi,
                            label=label, color=colours.get(str(b)), lw=1, ms=2, marker="o")
            ax.set_title(f"theta_i = {ti:g} deg")
            ax.set_xlabel("signed observation angle s (deg)")
        axes[0][0].set_ylabel("beta / pi (1/sr)" + (" (relative)" if ds.relative else ""))
        axes[0][-1].legend(fontsize=7)
        fig.tight_layout()
        save_figure(fig, out / "figures" / "inplane.png", svg)
        figures.append("figures/inplane.png")
    table = _colours(ds) if (ds.is_rgb and set("RGB") <= set(ds.channels)) or \
        (not ds.is_rgb and len(ds.wavelengths_nm) >= 2) else []
    if table:
        fig, axes = plt.subplots(len(incidences), 1, figsize=(8, 0.6 * len(incidences) + 0.6),
                                 squeeze=False)
        scale = 1.0
        if ds.relative:    # only the shapes mean something: scale the brightest swatch to 1
            scale = 1.0 / max(max(e["rgb"]) for e in table)
        for ax, ti in zip(axes[:, 0], incidences):
            row = [e for e in table if e["theta_i"] == ti]
            if not row:
                continue
            strip = display_srgb(np.array([e["rgb"] for e in row]) * scale)[None, :, :]
            ax.imshow(strip, aspect="auto", extent=(row[0]["s_deg"], row[-1]["s_deg"], 0, 1))
            ax.set_yticks([])
            ax.set_ylabel(f"{ti:g} deg", rotation=0, labelpad=20, fontsize=8)
        axes[-1, 0].set_xlabel("signed observation angle s (deg)")
        fig.tight_layout()
        save_figure(fig, out / "figures" / "colour_strips.png", svg)
        figures.append("figures/colour_strips.png")
    for path in old:
        if path.name not in {Path(f).name for f in figures} and path.is_file():
            path.unlink()
    notes = []
    if ds.relative:
        notes.append("Relative dataset (raw detector units): shapes only; V (absolute "
                     "brightness) is not stated.")
    if ds.is_rgb:
        notes.append(f"RGB dataset: colour read directly from the channels ({ds.colour_space}).")
    metrics = {"dataset": ds.name, "kind": ds.kind, "relative": ds.relative,
               "bands": [str(b) for b in ds.bands], "notes": notes,
               "colour": [{k: v for k, v in e.items() if not (ds.relative and k == "v")}
                          for e in table]}
    atomic_write(out / "metrics.json", (json.dumps(metrics, indent=2, allow_nan=True) + "\n").encode())
    esc = html.escape
    rows_html = "".join(
        f"<tr><td>{e['theta_i']:g}</td><td>{e['s_deg']:g}</td><td>{e['h']:.3f}</td>"
        f"<td>{e['s']:.3f}</td><td>{'n/a (relative)' if ds.relative else format(e['v'], '.3f')}</td>"
        f"<td>{e['blue_red']:.3f}</td><td>{e['green_red']:.3f}</td></tr>"
        for e in table)
    body = (f"<!doctype html><html><head><meta charset='utf-8'>"
            f"<meta name='generator' content='{GENERATOR}'>"
            f"<meta name='report-files' content='{esc(' '.join(figures + ['metrics.json']))}'>"
            f"<title>Dataset report: {esc(ds.name)}</title></head><body>"
            f"<h1>Dataset: {esc(ds.name)}</h1><p>{esc(ds.source)} ({esc(ds.kind)}, "
            f"{len(ds.geometries())} geometries, bands {esc(', '.join(str(b) for b in ds.bands))})</p>"
            + "".join(f"<p><b>{esc(n)}</b></p>" for n in notes)
            + "".join(f"<p><img src='{f}' alt='{f[8:]}'></p>" for f in figures)
            + "<h2>Colour (linear sRGB, HSV)</h2><table border='1'><tr><th>theta_i</th><th>s (deg)</th>"
              "<th>H</th><th>S</th><th>V</th><th>BLUE/RED</th><th>GREEN/RED</th></tr>"
            + rows_html + "</table>"
            + "</body></html>\n")
    atomic_write(out / "report.html", body.encode("utf-8"))
    return out / "report.html"

