"""``compare report DATASET --out DIR`` with no simulation: look at one dataset.

The page has the comparison report's standard (:mod:`compare.report`: the same style, a "what
this is" box read from meta.json, numbered captions, every figure embedded so ``report.html`` is
self-contained, the files also in ``figures/``):

- in-plane curves ``beta / pi`` against the signed observation angle ``s``, one figure per
  channel (RGB data) or at the wavelengths nearest 450, 550 and 650 nm (spectra), one panel per
  incidence titled ``θi = 27.8°`` (rows of at most four panels: no 3 840-pixel strip); grazing
  incidences (>= :data:`compare.report.curves.GRAZING_DEG`, e.g. an RGL file's 90 deg) get
  panels with their own value axis, so a 90 deg curve reaching 5 does not flatten the 0-60 deg
  ones; the beam-blocked cone is shaded only where the data have that gap;
- a colour strip per incidence (the colour at each observation angle, gamma-encoded for display
  only; spectra on grids ASTM E308 does not integrate are interpolated first,
  :func:`compare.bands.colour_at`);
- the colour table (HSV and channel ratios on linear sRGB, docs/physics.md section 7), collapsed
  (``<details>``) since it has a row per in-plane geometry (648 for an RGL file).

``metrics.json`` holds the dataset's name, kind, bands, notes and the colour table. A relative
dataset's V (absolute brightness) is not stated. A ``beta`` that is not finite or absurd is an
input error (:func:`compare.comparison.check_values`).
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np

from gonio.data import Dataset, display_srgb
from gonio.version import software

from .bands import colour_at
from .comparison import check_values
from .report import prepare_out_dir, save_figure
from .report.build import write_together
from .report.curves import GRAZING_DEG, REPORT_WAVELENGTHS_NM, angle_text, beam_blocked
from .report.figures import OWN_SCALE_RATIO, inplane_figure, own_scale_panels
from .report.page import Section, assemble, describe_dataset, figures_section, head_html

__all__ = ["write_dataset_report"]


def _colours(ds: Dataset):
    """Colour summary at each in-plane geometry: list of dicts (theta_i, s, h, s, v, ...)."""
    frame = ds.in_plane()
    out = []
    for (ti, pi_, s), rows in frame.groupby(["theta_i", "phi_i", "s"], sort=True):
        try:
            c = colour_at(ds, ti, pi_, rows["theta_o"].iloc[0], rows["phi_o"].iloc[0])
        except ValueError:
            continue
        out.append({"theta_i": float(ti), "phi_i": float(pi_), "s_deg": float(s), **c.as_dict()})
    return out


def _picks(ds: Dataset) -> list:
    """The bands drawn: every channel, or the wavelengths nearest 450, 550 and 650 nm."""
    if ds.is_rgb:
        return list(ds.channels)
    wl = ds.wavelengths_nm
    return sorted({float(wl[np.argmin(np.abs(wl - w))]) for w in REPORT_WAVELENGTHS_NM})


def _strip_figure(table: list[dict], incidences: list[float], relative: bool):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(incidences), 1, figsize=(8, 0.6 * len(incidences) + 0.9),
                             squeeze=False)
    scale = 1.0
    if relative:    # only the shapes mean something: scale the brightest swatch to 1
        scale = 1.0 / max(max(e["rgb"]) for e in table)
    for ax, ti in zip(axes[:, 0], incidences, strict=True):
        row = [e for e in table if e["theta_i"] == ti]
        ax.set_yticks([])
        ax.set_ylabel(angle_text(ti), rotation=0, labelpad=30, fontsize=8)
        if not row:
            continue
        strip = display_srgb(np.array([e["rgb"] for e in row]) * scale)[None, :, :]
        ax.imshow(strip, aspect="auto", extent=(row[0]["s_deg"], row[-1]["s_deg"], 0, 1))
    axes[-1, 0].set_xlabel("signed observation angle s (deg)")
    fig.suptitle("colour along the in-plane curves (display sRGB)", fontsize=9)
    fig.tight_layout()
    return fig


def write_dataset_report(ds: Dataset, out_dir: str | os.PathLike, *, svg: bool = False,
                         force: bool = False) -> Path:
    """Write ``report.html``, ``metrics.json`` and ``figures/*.png`` for one dataset, together.

    A report that cannot be written is one :class:`~compare.errors.CompareError` and leaves
    ``out_dir`` as it was.

    Parameters
    ----------
    ds : gonio.data.Dataset
        The dataset to look at.
    out_dir : path-like
        The report's folder (the output-folder policy of :func:`compare.report.write_report`).
    svg : bool
        Also write ``figures/*.svg``.
    force : bool
        Write into a folder that holds other files.

    Returns
    -------
    pathlib.Path
        The path of ``report.html``.
    """
    import matplotlib

    matplotlib.use("Agg")

    check_values(ds, ds.kind)
    out = Path(out_dir)
    old = prepare_out_dir(out, force)
    fig_dir = Path("figures")
    files: dict[Path, bytes] = {}     # written together at the end
    frame = ds.in_plane()
    incidences = sorted(set(frame["theta_i"]))
    band = ds.band_column
    figures: dict[str, tuple[bytes, str]] = {}
    unit = "beta / pi (1/sr)" + (" (relative)" if ds.relative else "")
    blocked = beam_blocked(frame, ds)
    for b in _picks(ds) if incidences else []:
        rows = frame[frame[band] == b]
        at = f"channel {b}" if ds.is_rgb else f"{b:g} nm"
        curve = rows.rename(columns={"beta": "value", "u_beta": "u"})
        own = sorted(own_scale_panels(curve, {}, incidences))
        fig, hidden = inplane_figure(curve, {}, f"{ds.name}: radiance coefficient, {at}", unit,
                                     ds.name, blocked=blocked, role=ds.kind,
                                     own_scale_ratio=OWN_SCALE_RATIO)
        fname = f"inplane_{b}.png" if ds.is_rgb else f"inplane_{b:g}nm.png"
        caption = (f"In-plane BRDF beta/pi of '{ds.name}', {at}, one panel per incidence (how "
                   "to read it: the note above the figures). "
                   + ("Error bars: +-1 standard uncertainty; they are smaller than the markers "
                      "at this scale." if hidden else "Error bars: +-1 standard uncertainty.")
                   + (f" On their own value axis: incidences {', '.join(_deg(x) for x in own)} deg."
                      if own else ""))
        figures[fname] = (save_figure(fig, fig_dir / fname, svg, files), caption)
    table = _colours(ds) if (ds.is_rgb and set("RGB") <= set(ds.channels)) or \
        (not ds.is_rgb and len(ds.wavelengths_nm) >= 2) else []
    if table:
        figures["colour_strips.png"] = (
            save_figure(_strip_figure(table, incidences, ds.relative),
                        fig_dir / "colour_strips.png", svg, files),
            f"Colour of '{ds.name}' along each in-plane curve, one strip per incidence, from the "
            "source's side (left) to the far side: the colour at each observation angle ("
            + ("the channels" if ds.is_rgb else "spectrum -> CIE XYZ, D65 -> linear sRGB")
            + "), gamma-encoded for display only"
            + ("; scaled so the brightest swatch is white-level 1 (relative data)"
               if ds.relative else "") + ".")
    preface = ("Reading the in-plane figures: the radiance coefficient beta/pi against the "
               "signed observation angle s (s < 0: detector on the source's side, s > 0 the far "
               "side), one panel per incidence, the panels sharing one value axis except those "
               f"titled 'own scale' (grazing incidences, >= {GRAZING_DEG:g} deg, and panels whose "
               f"values exceed {OWN_SCALE_RATIO:g} times the typical panel's: on the shared axis "
               "they would flatten every other curve). Dotted line: the retro-direction; dashed: "
               "the mirror direction"
               + ("; shaded: the beam-blocked cone, where the data have that gap." if blocked
                  else "; nothing is shaded: the data have no beam-blocked gap.")
               if figures else "")
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
    files[Path("metrics.json")] = (json.dumps({**metrics, "software": software()}, indent=2, allow_nan=True) + "\n").encode()
    files[Path("report.html")] = _page(ds, incidences, notes, table, figures, preface).encode("utf-8")
    write_together(out, files, "report")
    written = {out / name for name in files}
    for path in old:
        for stale in (path, path.with_suffix(".svg")):
            if stale not in written and stale.suffix in (".png", ".svg") and stale.is_file():
                stale.unlink()
    return out / "report.html"


def _deg(x: float) -> str:
    return f"{round(float(x), 1):g}"


def _page(ds: Dataset, incidences: list, notes: list[str], table: list[dict],
          figures: dict[str, tuple[bytes, str]], preface: str) -> str:
    esc = html.escape
    bands = ", ".join(str(b) for b in ds.bands) if ds.is_rgb else (
        f"{ds.wavelengths_nm[0]:g}..{ds.wavelengths_nm[-1]:g} nm, {ds.wavelengths_nm.size} "
        "wavelengths")
    files = [f"figures/{f}" for f in figures] + ["metrics.json"]
    head = head_html(f"Dataset report: {ds.name}", f"Dataset: {ds.name}", files)
    howto = Section("howto", "\n".join([
        "<div class='howto'><h2>What this is</h2>",
        f"<p>'{esc(ds.name)}' is {esc(describe_dataset(ds))}; read from <code>{esc(ds.source)}"
        f"</code>: {len(ds.geometries())} geometries, incidences "
        f"{esc(', '.join(_deg(x) for x in incidences))} deg, {esc(bands)}.</p>",
        "<p>This page looks at the dataset alone (no model): its in-plane curves, its colour "
        "along them and a colour table. To judge a model against it, run <code>compare report "
        "MEASURED SIM_DIR --out DIR</code>.</p>"]
        + [f"<p class='note'>{esc(n)}</p>" for n in notes] + ["</div>"]))
    rows_html = "".join(
        f"<tr><td>{e['theta_i']:g}</td><td>{e['s_deg']:g}</td><td>{e['h']:.3f}</td>"
        f"<td>{e['s']:.3f}</td><td>{'n/a (relative)' if ds.relative else format(e['v'], '.3f')}</td>"
        f"<td>{e['blue_red']:.3f}</td><td>{e['green_red']:.3f}</td></tr>"
        for e in table)
    colour = Section("colour", "\n".join([
        "<h2>Colour (linear sRGB, HSV)</h2>",
        "<p>H is a fraction of a full turn of the hue circle (0 red, 1/3 green, 2/3 blue), S and "
        "V in [0, 1], of LINEAR sRGB (D65 white = (1, 1, 1)); BLUE/RED and GREEN/RED are channel "
        "ratios.</p>",
        f"<details><summary>The colour at each of the {len(table)} in-plane geometries "
        "(click to open)</summary>",
        "<table><tr><th>theta_i (deg)</th><th>s (deg)</th><th>H</th><th>S</th><th>V</th>"
        f"<th>BLUE/RED</th><th>GREEN/RED</th></tr>{rows_html}</table></details>"])
        if table else "<h2>Colour</h2><p class='note'>No colour: the dataset has no complete "
                      "spectrum or R, G, B channels at an in-plane geometry.</p>")
    return assemble(head, [howto, figures_section(figures, preface), colour])

