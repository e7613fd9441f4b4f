"""The comparison report: ``report.html`` (one self-contained file), ``figures/*.png``,
``metrics.json``.

Written for a researcher: every figure has a caption (what is plotted, error bars and whether they
are smaller than the markers, the shaded beam-blocked cone around the labelled retro-direction,
the mirror direction); model lines are broken where the curve has no point (never drawn across
the beam-blocked gap); H is given in turns and degrees; swatches are labelled with the H, S, V of
the pixel shown; datasets are summarised in words (no link URLs with temporary ports); PNG at
:data:`FIGURE_DPI` (150) and, on request, SVG. Incomplete data and a dataset compared with itself
get a banner. The normalisation's uncertainty is explained and its effect on the overall NRMSE
(``k -+ u_k``) shown; ``metrics.json`` itself is unchanged (its NRMSE uses ``k``).

``write_report`` writes only into a new or empty folder or over a previous report (recognised by
the ``<meta name="generator">`` of its ``report.html``; only that report's files are replaced, its
figures that the new one does not draw removed); any other non-empty folder needs ``force``.

Figures (matplotlib, Agg backend, written to ``figures/`` and embedded in the HTML as base64 PNG):

The in-plane figures have the layout of the paper's Figure 7: one panel per incidence angle side
by side, the measurement as points with error bars, each simulation as a line with its own +-1
standard uncertainty shaded around it (``k u_C``; the luminance curve sums the wavelengths'
uncertainties linearly, the white Monte Carlo's errors being correlated across wavelengths).

``inplane_luminance.png``
    One panel per incidence angle present (0, 30, 45, 60 deg for the red-cotton plan), the
    luminance-weighted radiance coefficient ``Y[beta] / pi`` (the CIE ``Y`` of the spectrum
    under the report's illuminant, ``Y = 1`` for the ideal white diffuser, i.e. a band average
    weighted by what the eye sees) against the signed observation angle ``s``; measured as points
    with error bars (``u_Y / pi``, ``u_beta`` propagated through the linear ``Y`` weights), each
    simulation (normalised per wavelength) as a line.
``inplane_<W>nm.png``
    The same at single wavelengths: the shared wavelengths nearest 450, 550 and 650 nm
    (``beta / pi``, error bars ``u_beta / pi``).
``spectrum.png``
    Spectra at the colour geometry: left, the simulations normalised per wavelength; right, scaled
    by the one luminance factor ``k_Y`` used for the colour match (:mod:`compare.colourmatch`).
``factor.png``
    The normalisation factor ``k(lambda)`` of each simulation with its standard uncertainty.
``swatches.png``
    Colour swatches (display sRGB) of the measurement and each simulation at the colour geometry,
    labelled with the H, S, V of the displayed (gamma-encoded) pixel.
``colour_strips.png``
    The colour along every in-plane curve: per incidence, one strip per dataset, one swatch per
    observation angle (the dataset's own spectrum there -> linear sRGB via
    :mod:`gonio.data.colour`, scaled to the strip's brightest swatch, gamma-encoded for display);
    the caption gives the hue at both ends of each highest-incidence strip.

Simulated curves are drawn at the simulation's own in-plane geometries when its wavelength grid
contains the comparison grid (so points the instrument cannot measure, like the normal/normal one,
are shown), otherwise at the measured geometries (interpolated).

Every user-supplied string (sample names, paths, meta fields) is escaped with
:func:`html.escape` before it enters the HTML; in figure labels ``$`` is escaped so that
matplotlib does not read names as mathtext.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import math
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from gonio.data import atomic_write

from .colourmatch import band_luminance_weights
from .comparison import Comparison
from .errors import CompareError

__all__ = ["FIGURE_DPI", "REPORT_WAVELENGTHS_NM", "source_summary", "swatch_entries",
           "write_report"]

log = logging.getLogger(__name__)

#: Single wavelengths plotted (nearest shared ones).
REPORT_WAVELENGTHS_NM = (450.0, 550.0, 650.0)
#: Resolution of the PNG figures (print quality; ``--svg`` adds vector copies).
FIGURE_DPI = 150
#: Half-width (deg) of the cone around the source direction the detector cannot enter.
BEAM_BLOCK_DEG = 5.0
_MARKER_PT = 4.0
#: ``<meta name="generator">`` of every report: how a folder holding a previous report is known.
GENERATOR = "fabric-optics compare report"
_MEASURED_COLOUR = "black"
_LINESTYLES = ("-", "--", "-.", ":")


def _label(text: str) -> str:
    """A matplotlib-safe label (no mathtext, not hidden by a leading underscore)."""
    text = str(text).replace("$", r"\$")
    return " " + text if text.startswith("_") else text




def _savefig(fig, path: Path, svg: bool = False) -> bytes:
    """Write ``path`` (PNG at :data:`FIGURE_DPI`; also ``.svg`` beside it when ``svg``)."""
    import io

    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=FIGURE_DPI, metadata={"Software": None})
    if svg:
        vector = io.BytesIO()
        fig.savefig(vector, format="svg", metadata={"Date": None})
        atomic_write(path.with_suffix(".svg"), vector.getvalue())
    plt.close(fig)
    data = buffer.getvalue()
    atomic_write(path, data)
    return data


def _sim_inplane(comparison: Comparison, name: str) -> pd.DataFrame:
    """Normalised in-plane simulated rows (``theta_i, s, wavelength_nm, beta, u_beta``)."""
    grid = comparison.wavelength_nm
    sim = comparison.view(name)
    norm = comparison.normalisations[name]
    sim_wl = sim.wavelengths_nm
    on_grid = np.all(np.min(np.abs(sim_wl[None, :] - grid[:, None]), axis=1) < 1e-6)
    if on_grid:
        rows = sim.in_plane()
        rows = rows[np.min(np.abs(rows["wavelength_nm"].to_numpy()[:, None] - grid[None, :]),
                           axis=1) < 1e-6].copy()
        rows["wavelength_nm"] = grid[np.argmin(np.abs(rows["wavelength_nm"].to_numpy()[:, None]
                                                      - grid[None, :]), axis=1)]
        k = norm.factor_at(rows["wavelength_nm"].to_numpy())
        return pd.DataFrame({"theta_i": rows["theta_i"].to_numpy(), "s": rows["s"].to_numpy(),
                             "phi_i": rows["phi_i"].to_numpy(),
                             "wavelength_nm": rows["wavelength_nm"].to_numpy(),
                             "beta": k * rows["beta"].to_numpy(),
                             "u_beta": k * rows["u_beta"].to_numpy()})
    frame = comparison.frames[name]
    frame = frame[np.isfinite(frame["s"].to_numpy())]
    return pd.DataFrame({"theta_i": frame["theta_i"].to_numpy(), "s": frame["s"].to_numpy(),
                         "phi_i": frame["phi_i"].to_numpy(),
                         "wavelength_nm": frame["wavelength_nm"].to_numpy(),
                         "beta": frame["beta_sim"].to_numpy(),
                         "u_beta": frame["u_sim"].to_numpy()})


def _measured_inplane(comparison: Comparison) -> pd.DataFrame:
    rows = comparison.measured_compared.in_plane()
    grid = comparison.wavelength_nm
    keep = np.min(np.abs(rows["wavelength_nm"].to_numpy()[:, None] - grid[None, :]), axis=1) < 1e-6
    rows = rows[keep]
    return pd.DataFrame({"theta_i": rows["theta_i"].to_numpy(), "s": rows["s"].to_numpy(),
                         "phi_i": rows["phi_i"].to_numpy(),
                         "wavelength_nm": rows["wavelength_nm"].to_numpy(),
                         "beta": rows["beta"].to_numpy(), "u_beta": rows["u_beta"].to_numpy()})


def _luminance_curve(rows: pd.DataFrame, grid: np.ndarray, weights: np.ndarray,
                     correlated: bool = False) -> pd.DataFrame:
    """``Y`` and ``u_Y`` per in-plane geometry (complete spectra on ``grid`` only).

    ``u_Y`` combines the ``u_beta`` of the wavelengths in quadrature (independent errors: the
    instrument reads each wavelength separately) or, when ``correlated``, linearly,
    ``u_Y = sum |w| u_beta``: the simulations are "white" Monte Carlo, one set of photons
    re-weighted for every wavelength, so their errors move together across the spectrum and the
    quadrature sum would understate the band by up to ``sqrt(n_wavelengths)``.
    """
    if rows.empty:
        return pd.DataFrame(columns=["theta_i", "s", "value", "u"])
    idx = np.argmin(np.abs(rows["wavelength_nm"].to_numpy()[:, None] - grid[None, :]), axis=1)
    key = ["theta_i", "phi_i", "s"]
    rows = rows.assign(j=idx)
    b = rows.pivot_table(index=key, columns="j", values="beta", aggfunc="mean")
    u = rows.pivot_table(index=key, columns="j", values="u_beta", aggfunc="mean")
    b = b.reindex(columns=range(grid.size))
    u = u.reindex(columns=range(grid.size))
    complete = b.notna().all(axis=1).to_numpy()
    values = b.to_numpy()[complete] @ weights
    if correlated:
        u_values = u.to_numpy()[complete] @ np.abs(weights)
    else:
        u_values = np.sqrt((u.to_numpy()[complete] ** 2) @ (weights ** 2))
    index = b.index.to_frame(index=False)[complete]
    return pd.DataFrame({"theta_i": index["theta_i"].to_numpy(), "s": index["s"].to_numpy(),
                         "value": values, "u": u_values})


def _single_wavelength(rows: pd.DataFrame, wavelength_nm: float) -> pd.DataFrame:
    sel = rows[np.abs(rows["wavelength_nm"].to_numpy() - wavelength_nm) < 1e-6]
    return pd.DataFrame({"theta_i": sel["theta_i"].to_numpy(), "s": sel["s"].to_numpy(),
                         "value": sel["beta"].to_numpy(), "u": sel["u_beta"].to_numpy()})


def _gapped(s: np.ndarray, y: np.ndarray, theta_i: float) -> tuple[np.ndarray, np.ndarray]:
    """``s, y`` with NaN inserted where a line must not be drawn: across the beam-blocked
    retro-direction when the curve has no point there, and across holes wider than 1.5 times the
    usual spacing (missing points are not interpolated by eye)."""
    if s.size < 2:
        return s, y
    gaps = np.diff(s)
    usual = float(np.median(gaps))
    retro = -theta_i
    has_retro = bool(np.any(np.abs(s - retro) < BEAM_BLOCK_DEG))
    cut = gaps > 1.5 * usual + 1e-9
    if not has_retro:
        cut |= (s[:-1] < retro) & (s[1:] > retro)
    if not cut.any():
        return s, y
    where = np.flatnonzero(cut) + 1
    return (np.insert(s.astype(float), where, np.nan), np.insert(y.astype(float), where, np.nan))


def _bars_hidden(ax, x, y, u) -> bool:
    """True when every +-u error bar is shorter than the marker drawn over it."""
    if len(y) == 0:
        return False
    fig = ax.figure
    lo = ax.transData.transform(np.column_stack([x, y - u]))[:, 1]
    hi = ax.transData.transform(np.column_stack([x, y + u]))[:, 1]
    marker_px = _MARKER_PT * fig.dpi / 72.0
    return bool(np.all(np.abs(hi - lo) < marker_px))


def _inplane_figure(measured: pd.DataFrame, simulated: dict[str, pd.DataFrame], title: str,
                    ylabel: str, measured_name: str, *, bands: bool = True):
    """The in-plane panels; returns ``(figure, bars_hidden)``, ``bars_hidden`` True when the
    measured error bars are smaller than the markers in every panel.

    The layout is the paper's Figure 7: one panel per incidence angle side by side (rows of at
    most four), sharing the value axis, against the signed observation angle ``s`` over at least
    -65..75 deg; the measurement as points with +-1 standard uncertainty bars, each simulation
    as a line with, when ``bands``, its own +-1 standard uncertainty shaded around it (the
    ``u`` column of the simulated frames).

    Parameters
    ----------
    measured, simulated : DataFrame, dict of name -> DataFrame
        Columns ``theta_i, s, value, u``; ``value`` and ``u`` are divided by pi when drawn.
    title, ylabel, measured_name : str
        Figure title, value-axis label and the measurement's name (legend).
    bands : bool
        Shade +-1 ``u`` around every simulated line.
    """
    import matplotlib.pyplot as plt

    angles = sorted(set(measured["theta_i"].round(6)))
    n = max(len(angles), 1)
    ncols = min(n, 4)
    nrows = math.ceil(n / ncols)
    # one row leaves no room inside a panel for five legend entries: the legend goes under it
    legend_below = nrows == 1 and n > 1
    legend_in = 0.6        # height (inches) of the legend strip under a single row of panels
    fig, axes = plt.subplots(nrows, ncols,
                             figsize=(4.4 * ncols, 3.6 * nrows + (legend_in if legend_below else 0.0)),
                             squeeze=False, sharey=True)
    hidden = []
    for k, (ax, theta_i) in enumerate(zip(axes.ravel(), angles)):
        m = measured[np.abs(measured["theta_i"] - theta_i) < 1e-6].sort_values("s")
        ax.axvspan(-theta_i - BEAM_BLOCK_DEG, -theta_i + BEAM_BLOCK_DEG, color="0.92", lw=0,
                   label="beam-blocked (retro-direction)" if k == 0 else None)
        ax.axvline(-theta_i, color="0.5", lw=0.8, ls=":")
        ax.errorbar(m["s"], m["value"] / np.pi, yerr=m["u"] / np.pi, fmt="o", ms=_MARKER_PT,
                    capsize=2, color=_MEASURED_COLOUR, label=_label(f"{measured_name} (measured)"),
                    zorder=3)
        for j, (name, rows) in enumerate(simulated.items()):
            colour = f"C{j}"
            r = rows[np.abs(rows["theta_i"] - theta_i) < 1e-6].sort_values("s")
            if r.empty:
                continue
            s = r["s"].to_numpy()
            xs, ys = _gapped(s, r["value"].to_numpy() / np.pi, theta_i)
            ax.plot(xs, ys, _LINESTYLES[j % len(_LINESTYLES)], marker=".", color=colour,
                    label=_label(name))
            if bands and "u" in r:
                _, us = _gapped(s, r["u"].to_numpy() / np.pi, theta_i)
                # NaN (the line's gaps) splits the band too: nothing shaded across a gap
                ax.fill_between(xs, ys - us, ys + us, color=colour, alpha=0.22, lw=0)
        lo = min(-65.0, float(m["s"].min()) - 5 if len(m) else -65.0)
        hi = max(75.0, float(m["s"].max()) + 5 if len(m) else 75.0)
        ax.set_xlim(lo, hi)
        ax.text(-theta_i, 0.97, " retro", transform=ax.get_xaxis_transform(), rotation=90,
                ha="right", va="top", fontsize=7, color="0.35")
        if theta_i > 0:
            ax.axvline(theta_i, color="0.75", lw=0.8, ls="--")
            ax.text(theta_i, 0.97, " mirror", transform=ax.get_xaxis_transform(), rotation=90,
                    ha="right", va="top", fontsize=7, color="0.35")
        ax.set_title(f"incidence {theta_i:g} deg")
        ax.set_xlabel("signed observation angle s (deg)")
        if k % ncols == 0:
            ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(angles):]:
        ax.set_visible(False)
    fig.suptitle(_label(title))
    if legend_below:
        # the first panel's legend (so it stays with the panel that owns the entries), placed in
        # a strip reserved at the bottom of the figure and kept out of tight_layout, which would
        # otherwise shrink the first panel to make room for it
        legend = axes[0, 0].legend(fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 0.0),
                                   bbox_transform=fig.transFigure, frameon=False,
                                   ncol=min(3, 2 + len(simulated)))
        legend.set_in_layout(False)
        fig.tight_layout(rect=(0.0, legend_in / fig.get_figheight(), 1.0, 1.0))
    else:
        axes[0, 0].legend(fontsize=8)
        fig.tight_layout()
    fig.draw_without_rendering()   # final limits and layout: the transforms below are drawn
    for ax, theta_i in zip(axes.ravel(), angles):
        m = measured[np.abs(measured["theta_i"] - theta_i) < 1e-6]
        hidden.append(_bars_hidden(ax, m["s"].to_numpy(), m["value"].to_numpy() / np.pi,
                                   m["u"].to_numpy() / np.pi))
    return fig, bool(hidden) and all(hidden)


def _spectrum_figure(comparison: Comparison):
    import matplotlib.pyplot as plt

    cm = comparison.colour
    geo = cm.geometry
    rgb = comparison.bands.is_rgb
    per, k_name, style = ("channel", "k(c)", "-o") if rgb else ("wavelength", "k(lambda)", "-")
    fig, axes = plt.subplots(1, 2, figsize=(12, 4), sharey=True)
    for ax, scaled in zip(axes, (False, True)):
        first = next(iter(comparison.frames.values()))
        rows = first[(np.abs(first[["theta_i", "phi_i", "theta_o", "phi_o"]].to_numpy()
                             - np.array([geo["theta_i"], geo["phi_i"], geo["theta_o"],
                                         geo["phi_o"]])) < 1e-6).all(axis=1)]
        ax.errorbar(rows["wavelength_nm"], rows["beta_meas"], yerr=rows["u_meas"], fmt="o",
                    ms=3, capsize=2, color=_MEASURED_COLOUR,
                    label=_label(f"{comparison.measured.name} (measured)"))
        for name, sc in cm.simulated.items():
            if scaled:
                ax.plot(sc.wavelength_nm, sc.beta, style, label=_label(f"{name} x k_Y"))
            else:
                frame = comparison.frames[name]
                r = frame[(np.abs(frame[["theta_i", "phi_i", "theta_o", "phi_o"]].to_numpy()
                                  - np.array([geo["theta_i"], geo["phi_i"], geo["theta_o"],
                                              geo["phi_o"]])) < 1e-6).all(axis=1)]
                ax.plot(r["wavelength_nm"], r["beta_sim"], style, label=_label(f"{name} x {k_name}"))
        ax.set_xlabel("wavelength (nm)")
        ax.set_title(f"normalised per {per}" if not scaled else
                     "scaled by the luminance factor k_Y (colour match)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("radiance coefficient beta")
    if comparison.bands.is_rgb:
        for ax in axes:
            ax.set_xticks(comparison.wavelength_nm,
                          [comparison.bands.label(b) for b in comparison.wavelength_nm])
            ax.set_xlabel(f"channel ({comparison.bands.colour_space})")
    fig.suptitle(f"{'channels' if comparison.bands.is_rgb else 'spectra'} at theta_i={geo['theta_i']:g}, phi_i={geo['phi_i']:g}, "
                 f"theta_o={geo['theta_o']:g}, phi_o={geo['phi_o']:g} deg")
    fig.tight_layout()
    return fig


def _factor_figure(comparison: Comparison):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.8))
    for name, norm in comparison.normalisations.items():
        ax.errorbar(norm.wavelength_nm, norm.factor, yerr=norm.u_factor, fmt="-o", ms=3,
                    capsize=2, label=_label(name))
    ax.set_xlabel("wavelength (nm)")
    if comparison.bands.is_rgb:
        ax.set_xticks(comparison.wavelength_nm,
                      [comparison.bands.label(b) for b in comparison.wavelength_nm])
        ax.set_xlabel(f"channel ({comparison.bands.colour_space})")
    ax.set_ylabel("k = beta_meas(0,0) / C(0,0)")
    ax.set_title("normalisation factor")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def swatch_entries(comparison: Comparison) -> list[tuple[str, np.ndarray, tuple]]:
    """``(label, pixel, hsv)`` per swatch: ``pixel`` is the gamma-encoded sRGB shown on screen
    and ``hsv`` is computed from that same pixel, so a label describes what it sits under (the
    metrics' H, S, V are those of LINEAR sRGB; the table gives both)."""
    import colour

    from gonio.data.colour import display_srgb

    cm = comparison.colour
    entries = [(f"{comparison.measured.name} (measured)", cm.measured)]
    entries += [(name, sc.colour) for name, sc in cm.simulated.items()]
    out = []
    for name, c in entries:
        pixel = np.asarray(display_srgb(c.rgb), dtype=float)
        hsv = tuple(float(x) for x in colour.RGB_to_HSV(pixel))
        out.append((name, pixel, hsv))
    return out


def _swatch_figure(comparison: Comparison):
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    entries = swatch_entries(comparison)
    fig, ax = plt.subplots(figsize=(2.6 * len(entries), 2.9))
    for j, (name, pixel, (h, s_, v)) in enumerate(entries):
        ax.add_patch(Rectangle((j + 0.05, 0.3), 0.9, 0.7, color=tuple(pixel)))
        ax.text(j + 0.5, 0.22, _label(name), ha="center", va="top", fontsize=8, wrap=True)
        ax.text(j + 0.5, 0.05, f"shown: H {h:.3f} ({360 * h:.0f} deg) S {s_:.3f} V {v:.3f}",
                ha="center", va="top", fontsize=7)
    ax.set_xlim(0, len(entries))
    ax.set_ylim(-0.1, 1.05)
    ax.axis("off")
    fig.suptitle("display sRGB (gamma-encoded) swatches; H, S, V of these pixels", fontsize=9)
    fig.tight_layout()
    return fig


def _colour_strips(comparison: Comparison) -> list[dict]:
    """The colour along each in-plane curve of every dataset (for :func:`_colour_strip_figure`).

    One strip per (incidence, dataset), in the order measured, then the simulations; one swatch
    per in-plane geometry the dataset holds at that incidence (and the measurement's ``phi_i``).
    Each swatch is the colour of the dataset's own spectrum (or R, G, B channels) at that
    geometry through the project's pipeline (:meth:`gonio.data.Dataset.colour_at`, i.e.
    :func:`gonio.data.colour.spectrum_colour`: CIE 1931 2-degree observer, the comparison's
    illuminant, linear sRGB). Simulations are taken as written, not normalised per wavelength:
    ``k(lambda)`` makes every simulation's spectrum the measured one at the normal, so its
    colour there would agree by construction; a per-strip scale (below) is all that is needed.

    Returns
    -------
    list of dict
        Keys ``theta_i``, ``phi_i``, ``label``, ``measured`` (bool), ``s`` (deg, sorted), ``rgb`` (linear sRGB,
        shape (n, 3)), ``h`` (hue of the linear sRGB, turns) and ``pixel``: the displayed,
        gamma-encoded sRGB of ``rgb * scale``, ``scale`` putting the largest channel of the
        strip's brightest swatch at 1 (brightness compares along a strip, not across strips).
    """
    from gonio.data import display_srgb

    datasets = [(f"{comparison.measured.name} (measured)", comparison.measured)]
    datasets += list(comparison.simulated.items())
    frames = {label: ds.in_plane() for label, ds in datasets}
    measured = frames[datasets[0][0]]
    keys = measured[["theta_i", "phi_i"]].round(6).drop_duplicates().sort_values(
        ["theta_i", "phi_i"]).to_numpy()
    strips = []
    for theta_i, phi_i in keys:
        for label, ds in datasets:
            frame = frames[label]
            rows = frame[(np.abs(frame["theta_i"].to_numpy() - theta_i) < 1e-6)
                         & (np.abs(frame["phi_i"].to_numpy() - phi_i) < 1e-6)]
            s_list, rgb_list, h_list = [], [], []
            for s, at in rows.groupby("s", sort=True):
                try:
                    c = ds.colour_at(float(theta_i), float(phi_i), float(at["theta_o"].iloc[0]),
                                     float(at["phi_o"].iloc[0]), illuminant=comparison.illuminant)
                except ValueError:          # an incomplete spectrum here: no swatch, a gap
                    continue
                s_list.append(float(s))
                rgb_list.append(c.rgb)
                h_list.append(c.h)
            if not s_list:
                continue
            rgb = np.asarray(rgb_list, dtype=float)
            peak = float(np.max(rgb))
            if not (math.isfinite(peak) and peak > 0):
                continue
            strips.append({"theta_i": float(theta_i), "phi_i": float(phi_i), "label": label,
                           "measured": ds is comparison.measured, "s": np.asarray(s_list), "rgb": rgb, "h": np.asarray(h_list),
                           "pixel": np.asarray(display_srgb(rgb / peak), dtype=float)})
    return strips


def _colour_strip_figure(strips: list[dict]):
    """One panel per incidence (top to bottom), one strip per dataset in it, each swatch drawn
    at its observation angle ``s`` (so the strips line up with the in-plane panels and a
    missing geometry is a gap), the angles labelled under each panel."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    panels: dict[tuple[float, float], list[dict]] = {}
    for strip in strips:
        panels.setdefault((strip["theta_i"], strip["phi_i"]), []).append(strip)
    several_phi = len({phi for _, phi in panels}) > 1
    heights = [0.34 * len(v) + 0.95 for v in panels.values()]
    fig, axes = plt.subplots(len(panels), 1, figsize=(11.0, sum(heights) + 0.5), squeeze=False,
                             gridspec_kw={"height_ratios": heights})
    for ax, ((theta_i, phi_i), rows) in zip(axes[:, 0], panels.items()):
        every_s = np.unique(np.concatenate([r["s"] for r in rows]))
        step = float(np.min(np.diff(every_s))) if every_s.size > 1 else 10.0
        for j, strip in enumerate(rows):
            for s, pixel in zip(strip["s"], strip["pixel"]):
                ax.add_patch(Rectangle((s - 0.45 * step, -j - 0.4), 0.9 * step, 0.8,
                                       color=tuple(pixel), lw=0))
        ax.axvline(-theta_i, color="0.5", lw=0.8, ls=":")
        ax.set_xlim(float(every_s.min()) - 0.6 * step, float(every_s.max()) + 0.6 * step)
        ax.set_ylim(-len(rows) + 0.5, 0.5)
        ax.set_yticks([-j for j in range(len(rows))], [_label(r["label"]) for r in rows],
                      fontsize=7)
        ax.set_xticks(every_s, [f"{s:g}" for s in every_s], fontsize=7)
        ax.tick_params(length=0)
        for side in ax.spines.values():
            side.set_visible(False)
        ax.set_title(f"incidence {theta_i:g} deg" + (f", phi_i {phi_i:g} deg" if several_phi
                                                      else ""), fontsize=9, loc="left")
    axes[-1, 0].set_xlabel("signed observation angle s (deg): s < 0 detector on the source's "
                           "side (dotted: retro-direction), s > 0 the far side", fontsize=8)
    fig.suptitle("colour along the in-plane curves (display sRGB, each strip scaled to its "
                 "brightest swatch)", fontsize=9)
    fig.tight_layout()
    return fig


def _hue_trend(strips: list[dict]) -> str:
    """One sentence: the hue at the two ends of every dataset's strip at the highest incidence
    (where the paper's purple-to-red change is largest), so the caption states what the strips
    show in numbers rather than leaving it to the eye (display scaling changes the look)."""
    if not strips:
        return ""
    top = max(s["theta_i"] for s in strips)
    ends = [f"{s['label']} {360 * s['h'][0]:.1f} at s = {s['s'][0]:g} -> "
            f"{360 * s['h'][-1]:.1f} at s = {s['s'][-1]:g}"
            for s in strips if s["theta_i"] == top and s["s"].size >= 2]
    if not ends:
        return ""
    return (f" Hue of linear sRGB (deg; 0/360 red, 300 magenta) at the ends of the incidence "
            f"{top:g} deg strips: " + "; ".join(ends) + ".")


def source_summary(ds) -> str:
    """A readable one-line summary of what produced ``ds`` (no link URLs or temporary ports)."""
    meta = ds.meta
    parts = []
    source = meta.get("instrument") if ds.kind == "measured" else meta.get("model")
    source = source if isinstance(source, dict) else {}
    if ds.kind == "measured":
        idn = source.get("idn")
        if idn:
            fw = source.get("firmware")
            parts.append(f"instrument {idn}" + (f" (firmware {fw})" if fw else ""))
    else:
        name = source.get("name") or source.get("method")
        if name:
            parts.append(f"model {name}")
        sample = source.get("sample")
        if isinstance(sample, dict) and sample.get("model"):
            parts.append(str(sample["model"]))
    prov = meta.get("provenance") if isinstance(meta.get("provenance"), dict) else {}
    plan = prov.get("plan")
    if isinstance(plan, dict) and plan.get("name"):
        sha = str(plan.get("sha256") or "")[:12]
        parts.append(f"plan {plan['name']}" + (f" (sha256 {sha}...)" if sha else ""))
    elif isinstance(plan, str):
        parts.append(f"plan {plan}")
    if "seed" in prov:
        parts.append(f"seed {prov['seed']}")
    if "points_planned" in prov:
        parts.append(ds.completeness())
    elif not ds.complete:
        parts.append("INCOMPLETE")
    software = meta.get("software") if isinstance(meta.get("software"), dict) else {}
    if software.get("package"):
        parts.append(f"{software['package']} {software.get('version', '')}".strip())
    return "; ".join(str(p) for p in parts) or "-"


def _sample_summary(ds) -> str:
    sample = ds.meta.get("sample") if isinstance(ds.meta.get("sample"), dict) else {}
    fields = [f"{k}: {v}" for k, v in sample.items()
              if k != "name" and isinstance(v, (str, int, float))]
    return str(sample.get("name", ds.name)) + (f" ({'; '.join(fields)})" if fields else "")


def _fmt(x, digits: int = 4) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}g}" if math.isfinite(x) else "-"
    return html.escape(str(x))


def _banners(comparison: Comparison) -> list[str]:
    from .comparison import incomplete_datasets, same_dataset

    out = [f"Incomplete data: {line}. Curves and colours cover only what was measured."
           for line in incomplete_datasets(comparison.measured, comparison.simulated.values())]
    for name, ds in comparison.simulated.items():
        same = same_dataset(comparison.measured, ds)
        if same:
            out.append(f"'{name}' is the measured dataset itself ({same}): every figure agrees "
                       "trivially.")
    return out


def _html(comparison: Comparison, metrics: dict, figures: dict[str, tuple[bytes, str]]) -> str:
    e = html.escape
    meas = comparison.measured
    files = " ".join(f"figures/{name}" for name in figures)
    parts = ["<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
             f"<meta name='generator' content='{GENERATOR}'>",
             f"<meta name='report-files' content='{e(files)}'>",
             f"<title>Comparison report: {e(meas.name)}</title>",
             "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;}"
             "table{border-collapse:collapse;margin:0.5em 0 1.5em;}"
             "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right;}"
             "th{background:#eee;} td.l,th.l{text-align:left;} img{max-width:100%;}"
             "code{background:#f4f4f4;} figure{margin:1.5em 0;}"
             "figcaption{max-width:60em;font-size:0.95em;}"
             ".note{background:#e8f1fb;border:1px solid #4a7ab5;padding:0.5em 1em;}"
             ".banner{background:#fff3cd;border:2px solid #c77c00;padding:0.6em 1em;"
             "font-weight:bold;}</style></head><body>",
             f"<h1>Measurement vs simulation: {e(meas.name)}</h1>"]
    for text in _banners(comparison):
        parts.append(f"<p class='banner'>{e(text)}</p>")
    parts.append("<h2>Datasets</h2><table><tr><th class='l'>role</th><th class='l'>name</th>"
                 "<th class='l'>path</th><th class='l'>sample</th><th class='l'>source</th>"
                 "<th>rows</th><th class='l'>created</th></tr>")
    rows = [("measured", meas.name, meas)] + [("simulated", n, ds) for n, ds in
                                             comparison.simulated.items()]
    for role, name, ds in rows:
        parts.append(
            f"<tr><td class='l'>{e(role)}</td><td class='l'>{e(name)}</td>"
            f"<td class='l'><code>{e(str(ds.path) if ds.path else '-')}</code></td>"
            f"<td class='l'>{e(_sample_summary(ds))}</td>"
            f"<td class='l'>{e(source_summary(ds))}</td>"
            f"<td>{len(ds.table)}</td><td class='l'>{e(str(ds.meta.get('created', '-')))}</td>"
            "</tr>")
    grid = comparison.wavelength_nm
    parts.append("</table>")
    bands = comparison.bands
    if bands.is_rgb:
        parts.append(f"<p>Compared per channel on {e(', '.join(bands.channels or ()))} "
                     f"({e(str(bands.colour_space))}, the measurement's colour space)"
                     + ("; colour read directly from the channels (linear sRGB, HSV).</p>"
                        if bands.has_colour else "; no colour statement (photometric).</p>"))
    else:
        parts.append(f"<p>Compared on {grid.size} wavelengths, {grid[0]:g}..{grid[-1]:g} nm; "
                     f"colour under illuminant {e(comparison.illuminant)} "
                     "(CIE 1931 2-degree observer, linear sRGB).</p>")
    for text in comparison.notes():
        parts.append(f"<p class='note'><b>Note:</b> {e(text[0].upper() + text[1:])}.</p>")
    norm = metrics["normalisation"]
    mn = comparison.measured_normal
    parts.append("<h2>Normalisation at the normal direction</h2>")
    parts.append(f"<p>{e(norm['method'])}</p>")
    parts.append(f"<p>Measured normal/normal value: <b>{e(mn.how)}</b> from s = "
                 f"{e(', '.join(f'{s:g}' for s in mn.s_used))} deg; median beta(0,0) = "
                 f"{np.median(mn.value):.4g}, median u = {np.median(mn.u):.2g} "
                 f"(of which model term {np.median(mn.u_model):.2g}).</p>")
    parts.append(
        "<p>The factor's standard uncertainty u_k = k sqrt((u_meas/beta_meas(0,0))^2 + "
        "(u_C/C(0,0))^2) combines the uncertainty of the measured normal value (data and "
        "model terms above) and of the simulation's. It is <b>not</b> folded into the curve "
        "errors below (they use k itself), because it is one scale error shared by every point "
        "of a wavelength and does not average out; instead the last column gives the overall "
        "NRMSE with every k moved to k - u_k and to k + u_k.</p>")
    parts.append("<table><tr><th class='l'>simulation</th><th class='l'>C(0,0)</th>"
                 "<th>median k</th><th>k range</th><th>median u_k / k</th>"
                 "<th>luminance k_Y</th><th>overall NRMSE at k - u_k .. k + u_k</th></tr>")
    for name, n in comparison.normalisations.items():
        lo, hi = comparison.nrmse_with_factor_shifted(name)
        parts.append(f"<tr><td class='l'>{e(name)}</td><td class='l'>{e(n.simulated.how)}</td>"
                     f"<td>{np.median(n.factor):.4g}</td>"
                     f"<td>{n.factor.min():.4g} .. {n.factor.max():.4g}</td>"
                     f"<td>{np.median(n.u_factor / n.factor):.2g}</td>"
                     f"<td>{_fmt(metrics['normalisation']['factor'][name]['luminance'])}</td>"
                     f"<td>{_fmt(lo)} .. {_fmt(hi)}</td></tr>")
    parts.append("</table>")
    parts.append("<h2>Curve errors</h2><p>Residuals k C - beta_meas over all shared geometries "
                 "and wavelengths of each incidence angle (units of beta; NRMSE = RMSE / mean "
                 "measured beta). The normalisation's uncertainty is not included (see above).</p>")
    parts.append("<table><tr><th class='l'>simulation</th><th>theta_i (deg)</th><th>RMSE</th>"
                 "<th>NRMSE</th><th>max |d|</th><th class='l'>where (theta_i, phi_i, theta_o, "
                 f"phi_o; s; {comparison.bands.noun})</th></tr>")
    for name, per_angle in metrics["curves"].items():
        for angle, m in per_angle.items():
            at = m["max_abs_at"]
            where = (f"{at['theta_i']:g}, {at['phi_i']:g}, {at['theta_o']:g}, {at['phi_o']:g}; "
                     f"s={_fmt(at['s'])}; "
                     + (f"channel {at['channel']}" if 'channel' in at
                        else f"{at['wavelength_nm']:g} nm"))
            parts.append(f"<tr><td class='l'>{e(name)}</td><td>{e(angle)}</td>"
                         f"<td>{_fmt(m['rmse'])}</td><td>{_fmt(m['nrmse'])}</td>"
                         f"<td>{_fmt(m['max_abs'])}</td><td class='l'>{e(where)}</td></tr>")
        o = metrics["overall"][name]
        parts.append(f"<tr><th class='l'>{e(name)}</th><th>all</th><th>{_fmt(o['rmse'])}</th>"
                     f"<th>{_fmt(o['nrmse'])}</th><th></th><th></th></tr>")
    parts.append("</table>")
    colour = metrics["colour"]
    if not colour:
        parts.append("<h2>Colour match</h2><p class='note'>No colour statement: the measurement "
                     "is photometric (Y only).</p>")
    else:
        _colour_html(parts, comparison, colour)
    parts.append("<h2>Figures</h2>")
    for j, (fname, (data, caption)) in enumerate(figures.items(), start=1):
        b64 = base64.b64encode(data).decode("ascii")
        parts.append(f"<figure><img alt='{e(caption.split('.')[0])}' "
                     f"src='data:image/png;base64,{b64}'>"
                     f"<figcaption><b>Figure {j}.</b> {e(caption)} "
                     f"<span style='color:#777'>(figures/{e(fname)})</span></figcaption>"
                     "</figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _colour_html(parts: list[str], comparison: Comparison, colour: dict) -> None:
    e = html.escape
    meas = comparison.measured
    geo = colour["geometry"]
    scaled = ("Simulations scaled by k_Y (luminance ratio of the normal/normal "
              + ("channels" if comparison.bands.is_rgb else "spectra") + ")")
    parts.append(
        "<h2>Colour match</h2>"
        f"<p>At theta_i={geo['theta_i']:g}, phi_i={geo['phi_i']:g}, theta_o={geo['theta_o']:g}, "
        f"phi_o={geo['phi_o']:g} deg (s = {_fmt(geo['s'])}), the shared geometry closest to "
        "normal incidence and observation. " + scaled + "; differences are simulated minus measured, dh on the hue circle. "
        "H, S, V and the ratios are those of LINEAR sRGB (D65 white = (1, 1, 1)); <b>H is a "
        "fraction of a full turn of the hue circle, in [0, 1)</b> (0 red, 1/3 green, 2/3 blue; "
        "multiply by 360 for degrees), S and V in [0, 1].</p>"
        "<table><tr><th class='l'>dataset</th><th>H (turns)</th><th>H (deg)</th><th>S</th>"
        "<th>V</th><th>BLUE/RED</th><th>GREEN/RED</th><th>dh (turns)</th><th>ds</th>"
        "<th>dv</th></tr>")
    for name, c in colour.items():
        if name == "geometry":
            continue
        shown = f"{meas.name} (measured)" if name == "measured" else name
        h_deg = None if c.get("h") is None else 360.0 * c["h"]
        parts.append(f"<tr><td class='l'>{e(shown)}</td><td>{_fmt(c.get('h'))}</td>"
                     f"<td>{_fmt(h_deg, 3)}</td>" + "".join(
                         f"<td>{_fmt(c.get(k))}</td>" for k in ("s", "v", "blue_red",
                                                               "green_red", "dh", "ds", "dv"))
                     + "</tr>")
    parts.append("</table>")
    if comparison.relative:
        parts.append("<p class='note'><b>V and dv refused:</b> the measurement is relative (raw "
                     "detector units), so no absolute colour statement is made; H, S and the "
                     "ratios do not depend on the scale.</p>")


_PREVIOUS_FILES = re.compile(r"<meta name='report-files' content='([^']*)'>")
_LEGACY_FIGURES = re.compile(r"<img alt='([A-Za-z0-9_.-]+\.png)' src='data:image/png")


def _prepare_out_dir(out: Path, force: bool) -> list[Path]:
    """Check that ``out`` may receive a report; return the previous report's figure files.

    ``out`` may be missing, empty, or hold a previous report (its ``report.html`` names this
    generator): then only the previous report's own files are replaced or removed. Any other
    non-empty folder is refused unless ``force`` (then same-named files are replaced).
    """
    if not out.exists():
        return []
    if not out.is_dir():
        raise CompareError(f"--out {out} exists and is not a directory; choose a folder for the "
                           "report")
    entries = sorted(p.name for p in out.iterdir())
    if not entries:
        return []
    previous = out / "report.html"
    head = ""
    if previous.is_file():
        with open(previous, "rb") as handle:
            head = handle.read(65536).decode("utf-8", errors="replace")
    names = None
    if f"<meta name='generator' content='{GENERATOR}'>" in head:
        match = _PREVIOUS_FILES.search(head)
        names = html.unescape(match.group(1)).split() if match else []
    elif "<title>Comparison report: " in head and "<h1>Measurement vs simulation: " in head:
        # a report of the first version (no generator tag): its figures are named by img alt
        text = previous.read_text(encoding="utf-8", errors="replace")
        names = [f"figures/{n}" for n in _LEGACY_FIGURES.findall(text)]
    if names is not None:
        return [out / n for n in names if n.startswith("figures/") and "/" not in n[8:]
                and n[8:] not in ("", ".", "..")]
    if force:
        log.warning("--force: writing the report into %s, which holds other files (%s); "
                    "report.html, metrics.json and figures/ files of the same names are "
                    "replaced", out, ", ".join(entries[:5]) + (" ..." if len(entries) > 5 else ""))
        return []
    shown = ", ".join(entries[:5]) + (f" and {len(entries) - 5} more" if len(entries) > 5 else "")
    raise CompareError(f"--out {out} is not empty and holds no previous report ({shown}); "
                       "choose a new or empty folder, or pass --force to write report.html, "
                       "metrics.json and figures/ into it, replacing files of those names")


def write_report(comparison: Comparison, out_dir: str | os.PathLike, *, svg: bool = False,
                 force: bool = False) -> Path:
    """Write ``report.html``, ``metrics.json`` and ``figures/*.png`` into ``out_dir``.

    ``out_dir`` must be new, empty or hold a previous report (whose files alone are replaced;
    figures of the previous report that this one does not draw are removed); any other folder
    is refused with a :class:`~compare.errors.CompareError` unless ``force``. ``svg`` also writes
    ``figures/*.svg``.

    Returns
    -------
    pathlib.Path
        The path of ``report.html``.
    """
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out_dir)
    previous = _prepare_out_dir(out, force)
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    metrics = comparison.metrics()
    grid = comparison.wavelength_nm
    bands = comparison.bands
    weights = band_luminance_weights(bands, grid, comparison.illuminant)
    measured = _measured_inplane(comparison)
    simulated = {name: _sim_inplane(comparison, name) for name in comparison.simulated}
    figures: dict[str, tuple[bytes, str]] = {}
    sims = ", ".join(comparison.simulated)
    lines = ("Lines: " + sims + " (normalised per wavelength by k), broken where a curve has "
             "no point, e.g. across the beam-blocked cone around the retro-direction (shaded, "
             f"|s + theta_i| < {BEAM_BLOCK_DEG:g} deg, where the detector would block the "
             "source); the dashed line marks the mirror direction. Shaded around each line: "
             "+-1 standard uncertainty of that simulation (its Monte Carlo standard error "
             "times k; for Y[beta] summed linearly over the wavelengths, since one set of "
             "photons serves every wavelength and their errors are correlated).")

    def bars_note(hidden: bool, what: str) -> str:
        if hidden:
            return (f" The error bars ({what}) are smaller than the markers at this scale.")
        return f" Error bars: {what}."

    def inplane(fname, meas_rows, sim_rows, title, ylabel, caption):
        fig, hidden = _inplane_figure(meas_rows, sim_rows, title, ylabel,
                                      comparison.measured.name)
        data = _savefig(fig, fig_dir / fname, svg)
        figures[fname] = (data, caption + bars_note(hidden, "+-1 standard uncertainty of the "
                                                    "measurement") + " " + lines)

    if not measured.empty:
        inplane("inplane_luminance.png", _luminance_curve(measured, grid, weights),
                {n: _luminance_curve(r, grid, weights, correlated=True)
                 for n, r in simulated.items()},
                f"luminance-weighted radiance coefficient ({comparison.illuminant})",
                "Y[beta] / pi  (1/sr)",
                "In-plane luminance-weighted BRDF Y[beta]/pi ("
                + (f"the Y channel, or the luminance row of {bands.colour_space} over R, G, B"
                   if bands.is_rgb else f"CIE Y under illuminant {comparison.illuminant}")
                + ", 1 for the ideal white diffuser, divided by pi) against "
                "the signed observation angle s, one panel per incidence angle. Points: "
                f"the measurement '{comparison.measured.name}'.")
        if bands.is_rgb:
            picks = [float(b) for b in grid]
        else:
            picks = sorted({float(grid[np.argmin(np.abs(grid - w))])
                            for w in REPORT_WAVELENGTHS_NM})
        for wl in picks:
            at = f"channel {bands.label(wl)}" if bands.is_rgb else f"{wl:g} nm"
            fname = f"inplane_{bands.label(wl)}.png" if bands.is_rgb else f"inplane_{wl:g}nm.png"
            inplane(fname, _single_wavelength(measured, wl),
                    {n: _single_wavelength(r, wl) for n, r in simulated.items()},
                    f"radiance coefficient, {at}", "beta / pi  (1/sr)",
                    f"In-plane BRDF beta/pi, {at}, against the signed observation angle "
                    "s, one panel per incidence angle. Points: the measurement "
                    f"'{comparison.measured.name}'.")
    else:
        log.warning("the measured dataset has no in-plane points: no in-plane figures")
    if comparison.colour is not None:
        _colour_figures(comparison, figures, fig_dir, svg)
    figures["factor.png"] = (_savefig(_factor_figure(comparison), fig_dir / "factor.png", svg),
        "Normalisation factor k(lambda) = beta_meas(0,0) / C(0,0) of each simulation"
        + (" (per channel)" if bands.is_rgb else "") + ". Error bars: "
        "its standard uncertainty u_k = k sqrt((u_meas/beta_meas)^2 + (u_C/C)^2), from the "
        "estimate of the measured normal value (data and quadratic-vs-linear model term) and "
        "the simulation's normal value; not folded into the curve errors (see the "
        "normalisation table).")
    atomic_write(out / "metrics.json",
                  (json.dumps(metrics, indent=2, allow_nan=False) + "\n").encode("utf-8"))
    report = out / "report.html"
    atomic_write(report, _html(comparison, metrics, figures).encode("utf-8"))
    written = {fig_dir / name for name in figures}
    for old in previous:
        for stale in (old, old.with_suffix(".svg")):
            if stale not in written and stale.suffix in (".png", ".svg") and stale.is_file():
                stale.unlink()
    return report


def _colour_figures(comparison: Comparison, figures: dict, fig_dir: Path, svg: bool) -> None:
    geo = comparison.colour.geometry
    figures["spectrum.png"] = (_savefig(_spectrum_figure(comparison), fig_dir / "spectrum.png",
                                        svg),
        ("Channels" if comparison.bands.is_rgb else "Spectra")
        + f" at the colour geometry (theta_i={geo['theta_i']:g}, theta_o={geo['theta_o']:g}"
        " deg). Points with +-1 standard uncertainty: the measurement. Left: each simulation "
        f"normalised per {comparison.bands.noun} (equal to the measurement at the normal by construction); "
        "right: scaled by the single luminance factor k_Y used for the colour match.")
    figures["swatches.png"] = (_savefig(_swatch_figure(comparison), fig_dir / "swatches.png",
                                        svg),
        "Colour swatches at the colour geometry as shown on screen (gamma-encoded sRGB); the "
        "H, S, V printed under each are those of the displayed pixel. The table's H, S, V "
        "are of linear sRGB, hence different numbers for the same colour.")
    strips = _colour_strips(comparison)
    if strips:
        figures["colour_strips.png"] = (
            _savefig(_colour_strip_figure(strips), fig_dir / "colour_strips.png", svg),
            "Colour strips: the colour of each dataset along each in-plane curve, one strip per "
            "dataset and incidence angle, one swatch per observation angle s (labelled under "
            "each panel, deg) placed at s. Each swatch is the dataset's spectrum at that "
            f"geometry -> CIE XYZ (CIE 1931 2-degree observer, illuminant "
            f"{comparison.illuminant}) -> linear sRGB (gonio.data.colour), scaled so that the "
            "largest channel of the strip's brightest swatch is 1, then gamma-encoded for the "
            "screen: hue and saturation compare everywhere, brightness only along a strip. "
            "Simulations are shown with their own spectra, not normalised per wavelength "
            "(that would force the measured colour at the normal). A missing swatch is a "
            "geometry the dataset does not hold, e.g. the beam-blocked retro-direction (dotted "
            "line). Read left to right, the detector goes from the source's side (s < 0) to "
            "the far side (s > 0); the paper observes red cotton turning from purple to dark "
            "red as the light moves from the camera's side to the far side." + _hue_trend(strips))
