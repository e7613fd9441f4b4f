"""The report's figures (matplotlib, Agg backend).

In-plane panels, spectra, the normalisation factor, swatches and colour strips;
:func:`save_figure` writes PNG (and SVG on request).

In figure labels ``$`` is escaped so that matplotlib does not read names as mathtext
(:func:`mpl_label`).

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
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from gonio.data import atomic_write
from gonio.data.schema import ANGLE_TOL_DEG

from ..bands import colour_at, spectra_colours
from ..comparison import Comparison
from .curves import BEAM_BLOCK_DEG, GRAZING_DEG, angle_text, beam_blocked, gapped

__all__ = ["FIGURE_DPI", "OWN_SCALE_RATIO", "own_scale_panels", "colour_strip_figure", "colour_strips", "factor_figure", "hue_trend",
           "inplane_figure", "mpl_label", "save_figure", "spectrum_figure", "swatch_entries",
           "swatch_figure"]

#: Resolution of the PNG figures (print quality; ``--svg`` adds vector copies).
FIGURE_DPI = 150
MARKER_PT = 4.0
MEASURED_COLOUR = "black"
LINESTYLES = ("-", "--", "-.", ":")


def mpl_label(text: str) -> str:
    """A matplotlib-safe label (no mathtext, not hidden by a leading underscore).

    Parameters
    ----------
    text : str
        The label as given (e.g. a dataset's name).

    Returns
    -------
    str
        The label with ``$`` escaped and a leading underscore preceded by a space.
    """
    text = str(text).replace("$", r"\$")
    return " " + text if text.startswith("_") else text


def save_figure(fig, path: Path, svg: bool = False, files: dict | None = None) -> bytes:
    """Write ``path`` (PNG at :data:`FIGURE_DPI`; also ``.svg`` beside it when ``svg``); return the PNG.

    ``files``: collect the bytes there (path -> bytes) instead of writing them, for a report written
    together (:func:`gonio.data.write_files_together`).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure; it is closed.
    path : Path
        The PNG file.
    svg : bool, default False
        Also write an SVG beside it.
    files : dict, optional
        Collects path -> bytes instead of writing them.

    Returns
    -------
    bytes
        The PNG.
    """
    import io

    import matplotlib.pyplot as plt
    from matplotlib.layout_engine import PlaceHolderLayoutEngine
    from PIL import Image

    # fig.tight_layout() leaves a placeholder layout engine on the figure, and a draw of a figure
    # that has a layout engine runs it once more (text measured again) before drawing; the layout
    # is final here, so the figure is drawn without one: one draw per file
    if isinstance(fig.get_layout_engine(), PlaceHolderLayoutEngine):
        fig.set_layout_engine(None)
    out = {}
    if svg:
        import matplotlib

        vector = io.BytesIO()
        # a fixed salt for the SVG's element ids: the same figure gives the same bytes
        with matplotlib.rc_context({"svg.hashsalt": "fabric-optics"}):
            fig.savefig(vector, format="svg", metadata={"Date": None})
        out[path.with_suffix(".svg")] = vector.getvalue()
    # the pixels savefig(format="png") would write (one Agg draw at FIGURE_DPI), encoded without
    # their alpha channel when the figure is opaque (every report figure is: a quarter fewer bytes
    # to compress and to embed, the same picture)
    fig.set_dpi(FIGURE_DPI)
    fig.canvas.draw()
    pixels = np.asarray(fig.canvas.buffer_rgba())
    opaque = bool(np.all(pixels[..., 3] == 255))
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels[..., :3]) if opaque else pixels).save(
        buffer, format="png", dpi=(FIGURE_DPI, FIGURE_DPI))
    plt.close(fig)
    data = buffer.getvalue()
    out[path] = data
    for target, content in out.items():
        if files is not None:
            files[target] = content
        else:
            atomic_write(target, content)
    return data


def tight_layout(fig, bottom_in: float = 0.0) -> None:
    """``fig.tight_layout()`` keeping a strip ``bottom_in`` inches high free at the bottom.

    The subplot parameters of ``fig.tight_layout(rect=(0, bottom_in / height, 1, 1))`` at half
    its cost for one row of panels: with ``rect`` matplotlib measures every panel's decorations
    twice (once for the margins, once more inside ``rect``), two equal measurements since the
    panels do not move in between; here they are measured once and the bottom margin moves up
    by the strip. With several rows (whose spacing is relative to the panel height)
    matplotlib's own ``rect`` is used.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    bottom_in : float, default 0
        Height of the free strip (inches).
    """
    strip = bottom_in / fig.get_figheight()
    specs = [ax.get_subplotspec() for ax in fig.axes]
    if strip and any(spec is None or spec.get_gridspec().nrows > 1 for spec in specs):
        fig.tight_layout(rect=(0.0, strip, 1.0, 1.0))
        return
    fig.tight_layout()
    if strip:
        fig.subplots_adjust(bottom=fig.subplotpars.bottom + strip)


def _bars_hidden(ax, x, y, u) -> bool:
    """True when every +-u error bar is shorter than the marker drawn over it."""
    if len(y) == 0:
        return False
    ax.get_ylim()          # the final (autoscaled) view limits: transData reads them
    fig = ax.figure
    lo = ax.transData.transform(np.column_stack([x, y - u]))[:, 1]
    hi = ax.transData.transform(np.column_stack([x, y + u]))[:, 1]
    marker_px = MARKER_PT * fig.dpi / 72.0
    return bool(np.all(np.abs(hi - lo) < marker_px))


#: A panel whose largest value exceeds this many times the median of the panels' largest
#: values gets its own value axis (a forward peak at 79 deg would flatten the 0-60 deg curves).
OWN_SCALE_RATIO = 2.0


def own_scale_panels(measured: pd.DataFrame, simulated: dict[str, pd.DataFrame],
                     angles: list[float], ratio: float | None = OWN_SCALE_RATIO) -> set[float]:
    """The incidences drawn on their own value axis.

    The grazing ones (>= ``GRAZING_DEG``) and, unless ``ratio`` is None, those whose peak exceeds
    ``ratio`` times the median panel peak.

    Parameters
    ----------
    measured : pandas.DataFrame
        The measured curves, with ``theta_i`` (degrees) and ``value``.
    simulated : dict of str to pandas.DataFrame
        The simulated curves by name, with the same columns.
    angles : list of float
        The incidence polar angles (degrees) of the panels.
    ratio : float or None, default OWN_SCALE_RATIO
        Peak over the median panel peak above which a panel gets its own axis; None: only the
        grazing ones.

    Returns
    -------
    set of float
        The incidence angles (degrees) drawn on their own axis.
    """
    frames = [measured] + list(simulated.values())
    peaks = []
    for theta_i in angles:
        values = [f.loc[np.abs(f["theta_i"] - theta_i) < 1e-6, "value"].to_numpy(float)
                  for f in frames if len(f)]
        both = np.concatenate(values) if values else np.array([])
        both = both[np.isfinite(both)]
        peaks.append(float(np.max(np.abs(both))) if both.size else 0.0)
    typical = float(np.median([p for a, p in zip(angles, peaks, strict=True) if a < GRAZING_DEG] or [0.0]))
    return {a for a, p in zip(angles, peaks, strict=True)
            if a >= GRAZING_DEG or (ratio is not None and typical > 0 and p > ratio * typical)}


def inplane_figure(measured: pd.DataFrame, simulated: dict[str, pd.DataFrame], title: str,
                    ylabel: str, measured_name: str, *, bands: bool = True,
                    blocked: set[float] | None = None, role: str = "measured",
                    own_scale_ratio: float | None = None):
    """The in-plane panels, and whether the measured error bars are hidden by the markers.

    Returns ``(figure, bars_hidden)``, ``bars_hidden`` True when the measured error bars are
    smaller than the markers in every panel.

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
    role : str
        What the points are, in the legend after the name (``"measured"``; a single-dataset
        report of a simulation says ``"simulated"``).
    bands : bool
        Shade +-1 ``u`` around every simulated line.
    blocked : set of float, optional
        Incidences whose beam-blocked cone is shaded (default: where the measurement has the
        gap, :func:`compare.report.curves.beam_blocked`). Grazing incidences (>=
        :data:`~compare.report.curves.GRAZING_DEG`) and, with ``own_scale_ratio``, panels far
        above the others (:func:`own_scale_panels`) get their own value axis, said in their
        title; the comparison report keeps the paper's shared axis for the others.
    own_scale_ratio : float, optional
        A panel whose peak exceeds this times the median panel peak gets its own value axis;
        None: only the grazing incidences do.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    if blocked is None:
        blocked = beam_blocked(measured)

    angles = sorted(set(measured["theta_i"].round(6)))
    n = max(len(angles), 1)
    ncols = min(n, 4)
    nrows = math.ceil(n / ncols)
    # one row leaves no room inside a panel for five legend entries: the legend goes under it
    legend_below = nrows == 1 and n > 1
    legend_in = 0.6        # height (inches) of the legend strip under a single row of panels
    fig, axes = plt.subplots(nrows, ncols,
                             figsize=(4.4 * ncols, 3.6 * nrows + (legend_in if legend_below else 0.0)),
                             squeeze=False)
    own = own_scale_panels(measured, simulated, angles, own_scale_ratio)
    shared = [ax for ax, a in zip(axes.ravel(), angles, strict=False) if a not in own]
    for ax in shared[1:]:
        ax.sharey(shared[0])
    hidden = []
    for k, (ax, theta_i) in enumerate(zip(axes.ravel(), angles, strict=False)):
        m = measured[np.abs(measured["theta_i"] - theta_i) < 1e-6].sort_values("s")
        if round(float(theta_i), 6) in blocked:
            ax.axvspan(-theta_i - BEAM_BLOCK_DEG, -theta_i + BEAM_BLOCK_DEG, color="0.92", lw=0)
        ax.axvline(-theta_i, color="0.5", lw=0.8, ls=":")
        ax.errorbar(m["s"], m["value"] / np.pi, yerr=m["u"] / np.pi, fmt="o", ms=MARKER_PT,
                    capsize=2, color=MEASURED_COLOUR, label=mpl_label(f"{measured_name} ({role})"),
                    zorder=3)
        for j, (name, rows) in enumerate(simulated.items()):
            colour = f"C{j}"
            r = rows[np.abs(rows["theta_i"] - theta_i) < 1e-6].sort_values("s")
            if r.empty:
                continue
            s = r["s"].to_numpy()
            xs, ys = gapped(s, r["value"].to_numpy() / np.pi, theta_i)
            ax.plot(xs, ys, LINESTYLES[j % len(LINESTYLES)], marker=".", color=colour,
                    label=mpl_label(name))
            if bands and "u" in r:
                _, us = gapped(s, r["u"].to_numpy() / np.pi, theta_i)
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
        alone = theta_i in own
        ax.set_title(angle_text(theta_i) + ((" (grazing: own scale)" if theta_i >= GRAZING_DEG
                                             else " (own scale)") if alone else ""))
        ax.set_xlabel("signed observation angle s (deg)")
        if k % ncols == 0 or alone:
            ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(angles):]:
        ax.set_visible(False)
    fig.suptitle(mpl_label(title))
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if blocked:
        handles.insert(0, Patch(color="0.92", lw=0))
        labels.insert(0, "beam-blocked (retro-direction)")
    if legend_below:
        # the first panel's legend (so it stays with the panel that owns the entries), placed in
        # a strip reserved at the bottom of the figure and kept out of tight_layout, which would
        # otherwise shrink the first panel to make room for it
        legend = axes[0, 0].legend(handles, labels, fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 0.0),
                                   bbox_transform=fig.transFigure, frameon=False,
                                   ncol=min(3, 2 + len(simulated)))
        legend.set_in_layout(False)
        tight_layout(fig, bottom_in=legend_in)
    else:
        axes[0, 0].legend(handles, labels, fontsize=8)
        tight_layout(fig)
    # the layout is final (tight_layout placed the axes) and _bars_hidden autoscales the
    # limits: the transforms it reads are those drawn, without a draw here
    for ax, theta_i in zip(axes.ravel(), angles, strict=False):
        if not ax.yaxis.offsetText.get_text():
            # nothing above the panel for its title to clear (no offset or power of ten on
            # the value axis, no ticks on top): its place is fixed, which saves measuring
            # every tick label again at each draw to find it
            ax.set_title(ax.get_title(), y=1.0)
        m = measured[np.abs(measured["theta_i"] - theta_i) < 1e-6]
        hidden.append(_bars_hidden(ax, m["s"].to_numpy(), m["value"].to_numpy() / np.pi,
                                   m["u"].to_numpy() / np.pi))
    return fig, bool(hidden) and all(hidden)


def spectrum_figure(comparison: Comparison):
    """The spectra (or channels) at the colour geometry.

    The measurement and each simulation scaled by the one luminance factor ``k_Y`` of the colour
    match. The per-wavelength normalised view is not drawn: ``k(lambda)`` makes every simulation
    equal the measurement at the normal by construction, so near the normal it would show the same
    curve for every dataset. Channels are points (R, G, B are not a continuum: no line joins them).

    Parameters
    ----------
    comparison : Comparison
        The comparison; its colour match must be known.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    import matplotlib.pyplot as plt

    cm = comparison.colour_matched()
    geo = cm.geometry
    rgb = comparison.bands.is_rgb
    style = "o" if rgb else "-"
    fig, ax = plt.subplots(figsize=(7.5, 4))
    first = next(iter(comparison.frames.values()))
    rows = first[(np.abs(first[["theta_i", "phi_i", "theta_o", "phi_o"]].to_numpy()
                         - np.array([geo["theta_i"], geo["phi_i"], geo["theta_o"],
                                     geo["phi_o"]])) < 1e-6).all(axis=1)]
    ax.errorbar(rows["wavelength_nm"], rows["beta_meas"], yerr=rows["u_meas"], fmt="o",
                ms=3 if not rgb else 6, capsize=2, color=MEASURED_COLOUR,
                label=mpl_label(f"{comparison.measured.name} (measured)"))
    for name, sc in cm.simulated.items():
        ax.plot(sc.wavelength_nm, sc.beta, style, ms=5, label=mpl_label(f"{name} x k_Y"))
    ax.set_xlabel("wavelength (nm)")
    ax.set_title("scaled by the luminance factor k_Y (colour match)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_ylabel("radiance coefficient beta")
    if rgb:
        ax.set_xticks(comparison.wavelength_nm,
                      [comparison.bands.label(b) for b in comparison.wavelength_nm])
        ax.set_xlabel(f"channel ({comparison.bands.colour_space})")
        ax.set_xlim(comparison.wavelength_nm.min() - 0.5, comparison.wavelength_nm.max() + 0.5)
    fig.suptitle(f"{'channels' if rgb else 'spectra'} at {angle_text(geo['theta_i'])}, "
                 f"phi_i={geo['phi_i']:g}, theta_o={geo['theta_o']:g}, phi_o={geo['phi_o']:g} deg")
    fig.tight_layout()
    return fig


def factor_figure(comparison: Comparison):
    """Figure ``factor.png``: each simulation's normalisation factor ``k(lambda)`` with its uncertainty.

    Parameters
    ----------
    comparison : Comparison
        The comparison.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.8))
    for name, norm in comparison.normalisations.items():
        ax.errorbar(norm.wavelength_nm, norm.factor, yerr=norm.u_factor,
                    fmt="o" if comparison.bands.is_rgb else "-o", ms=3,
                    capsize=2, label=mpl_label(name))
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
    """``(label, pixel, hsv)`` per swatch.

    ``pixel`` is the gamma-encoded sRGB shown on screen and ``hsv`` is computed from that same
    pixel, so a label describes what it sits under (the metrics' H, S, V are those of LINEAR sRGB;
    the table gives both).

    Parameters
    ----------
    comparison : Comparison
        The comparison; its colour match must be known.

    Returns
    -------
    list of (str, numpy.ndarray, tuple)
        The label, the displayed pixel (gamma-encoded sRGB, 0 to 1) and its H, S, V (in [0, 1]), the
        measurement first.
    """
    import colour

    from gonio.data.colour import display_srgb

    cm = comparison.colour_matched()
    entries = [(f"{comparison.measured.name} (measured)", cm.measured)]
    entries += [(name, sc.colour) for name, sc in cm.simulated.items()]
    out = []
    for name, c in entries:
        pixel = np.asarray(display_srgb(c.rgb), dtype=float)
        hsv = tuple(float(x) for x in colour.RGB_to_HSV(pixel))
        out.append((name, pixel, hsv))
    return out


def swatch_figure(comparison: Comparison):
    """Figure ``swatches.png``: the measured and simulated colour swatches at the colour geometry.

    Parameters
    ----------
    comparison : Comparison
        The comparison; its colour match must be known.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    entries = swatch_entries(comparison)
    fig, ax = plt.subplots(figsize=(2.6 * len(entries), 2.9))
    for j, (name, pixel, (h, s_, v)) in enumerate(entries):
        ax.add_patch(Rectangle((j + 0.05, 0.3), 0.9, 0.7, color=tuple(pixel)))
        ax.text(j + 0.5, 0.22, mpl_label(name), ha="center", va="top", fontsize=8, wrap=True)
        ax.text(j + 0.5, 0.05, f"shown: H {h:.3f} ({360 * h:.0f} deg) S {s_:.3f} V {v:.3f}",
                ha="center", va="top", fontsize=7)
    ax.set_xlim(0, len(entries))
    ax.set_ylim(-0.1, 1.05)
    ax.axis("off")
    fig.suptitle("display sRGB (gamma-encoded) swatches; H, S, V of these pixels", fontsize=9)
    fig.tight_layout()
    return fig


def colour_strips(comparison: Comparison) -> list[dict]:
    """The colour along each in-plane curve of every dataset (for :func:`colour_strip_figure`).

    One strip per (incidence, dataset), in the order measured, then the simulations; one swatch
    per in-plane geometry the dataset holds at that incidence (and the measurement's ``phi_i``).
    Each swatch is the colour of the dataset's own spectrum (or R, G, B channels) at that
    geometry through the project's pipeline (:meth:`gonio.data.Dataset.colour_at`, i.e.
    :func:`gonio.data.colour.spectrum_colour`: CIE 1931 2-degree observer, the comparison's
    illuminant, linear sRGB). Simulations are taken as written, not normalised per wavelength:
    ``k(lambda)`` makes every simulation's spectrum the measured one at the normal, so its
    colour there would agree by construction; a per-strip scale (below) is all that is needed.

    Parameters
    ----------
    comparison : Comparison
        The comparison.

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
            if ds.is_rgb:
                s_arr, rgb, h = _rgb_swatches(ds, rows, float(theta_i), float(phi_i), comparison.illuminant)
            else:
                s_arr, rgb, h = _spectral_swatches(rows, comparison.illuminant)
            if not s_arr.size:
                continue
            peak = float(np.max(rgb))
            if not (math.isfinite(peak) and peak > 0):
                continue
            strips.append({"theta_i": float(theta_i), "phi_i": float(phi_i), "label": label,
                           "measured": ds is comparison.measured, "s": s_arr, "rgb": rgb, "h": h,
                           "pixel": np.asarray(display_srgb(rgb / peak), dtype=float)})
    return strips


def _rgb_swatches(ds, rows: pd.DataFrame, theta_i: float, phi_i: float,
                  illuminant: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s, rgb, h)`` of an RGB dataset's in-plane ``rows`` at one incidence, one swatch per ``s``."""
    s_list, rgb_list, h_list = [], [], []
    for s, at in rows.groupby("s", sort=True):
        try:
            c = colour_at(ds, theta_i, phi_i, float(at["theta_o"].iloc[0]), float(at["phi_o"].iloc[0]),
                          illuminant=illuminant)
        except ValueError:          # an incomplete set of channels here: no swatch, a gap
            continue
        s_list.append(float(s))
        rgb_list.append(c.rgb)
        h_list.append(c.h)
    return np.asarray(s_list, dtype=float), np.asarray(rgb_list, dtype=float).reshape(-1, 3), np.asarray(h_list)


def _spectral_swatches(rows: pd.DataFrame, illuminant: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s, rgb, h)`` of a spectral dataset's in-plane ``rows`` at one incidence, one swatch per ``s``.

    Each swatch is the spectrum at the first geometry of its ``s`` (the rows sorted by wavelength,
    as :meth:`gonio.data.Dataset.in_plane` gives them), its colour what :func:`compare.bands.colour_at`
    gives for it; the spectra of one wavelength grid are converted together
    (:func:`compare.bands.spectra_colours`). A spectrum whose colour is refused is a gap.
    """
    spectra: dict[tuple[float, ...], list[tuple[int, np.ndarray]]] = {}
    s_values = []
    for k, (s, at) in enumerate(rows.groupby("s", sort=True)):
        s_values.append(float(s))
        theta_o = at["theta_o"].to_numpy(float)
        phi_o = at["phi_o"].to_numpy(float)
        dphi = np.abs(phi_o - phi_o[0])
        same = (np.abs(theta_o - theta_o[0]) < ANGLE_TOL_DEG) & (np.minimum(dphi, 360.0 - dphi) < ANGLE_TOL_DEG)
        wl = tuple(at["wavelength_nm"].to_numpy(float)[same].tolist())
        spectra.setdefault(wl, []).append((k, at["beta"].to_numpy(float)[same]))
    rgb = np.full((len(s_values), 3), np.nan)
    h = np.full(len(s_values), np.nan)
    for wl, items in spectra.items():
        index = [k for k, _ in items]
        try:
            rgb[index], h[index] = spectra_colours(wl, np.stack([b for _, b in items]), illuminant=illuminant)
        except ValueError:          # a spectrum too short to have a colour: no swatch, a gap
            continue
    keep = np.all(np.isfinite(rgb), axis=1)
    return np.asarray(s_values)[keep], rgb[keep], h[keep]


def colour_strip_figure(strips: list[dict]):
    """The colour strips: one panel per incidence (top to bottom), one strip per dataset in it.

    Each swatch is drawn at its observation angle ``s`` (so the strips line up with the in-plane
    panels and a missing geometry is a gap), the angles labelled under each panel.

    Parameters
    ----------
    strips : list of dict
        The strips of :func:`colour_strips`.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    panels: dict[tuple[float, float], list[dict]] = {}
    for strip in strips:
        panels.setdefault((strip["theta_i"], strip["phi_i"]), []).append(strip)
    several_phi = len({phi for _, phi in panels}) > 1
    heights = [0.34 * len(v) + 0.95 for v in panels.values()]
    fig, axes = plt.subplots(len(panels), 1, figsize=(11.0, sum(heights) + 0.5), squeeze=False,
                             gridspec_kw={"height_ratios": heights})
    for ax, ((theta_i, phi_i), rows) in zip(axes[:, 0], panels.items(), strict=True):
        every_s = np.unique(np.concatenate([r["s"] for r in rows]))
        step = float(np.min(np.diff(every_s))) if every_s.size > 1 else 10.0
        # every swatch of the panel one rectangle of one collection (a patch each would be
        # measured and drawn one by one: hundreds of artists)
        corners = np.array([[-0.45, -0.4], [0.45, -0.4], [0.45, 0.4], [-0.45, 0.4]]) * [step, 1.0]
        verts = np.concatenate([np.column_stack([strip["s"], np.full(strip["s"].size, -j)])[:, None, :]
                                + corners for j, strip in enumerate(rows)])
        ax.add_collection(PolyCollection(list(verts), facecolors=np.concatenate([r["pixel"] for r in rows]),
                                         edgecolors="none", linewidths=0), autolim=False)
        ax.axvline(-theta_i, color="0.5", lw=0.8, ls=":")
        ax.set_xlim(float(every_s.min()) - 0.6 * step, float(every_s.max()) + 0.6 * step)
        ax.set_ylim(-len(rows) + 0.5, 0.5)
        ax.set_yticks([-j for j in range(len(rows))], [mpl_label(r["label"]) for r in rows],
                      fontsize=7)
        ax.set_xticks(every_s, [f"{s:g}" for s in every_s], fontsize=7)
        ax.tick_params(length=0)
        for side in ax.spines.values():
            side.set_visible(False)
        # a fixed title place: the value axis holds labels, no offset text for it to clear
        ax.set_title(f"incidence {theta_i:g} deg" + (f", phi_i {phi_i:g} deg" if several_phi
                                                      else ""), fontsize=9, loc="left", y=1.0)
    axes[-1, 0].set_xlabel("signed observation angle s (deg): s < 0 detector on the source's "
                           "side (dotted: retro-direction), s > 0 the far side", fontsize=8)
    fig.suptitle("colour along the in-plane curves (display sRGB, each strip scaled to its "
                 "brightest swatch)", fontsize=9)
    fig.tight_layout()
    return fig


def hue_trend(strips: list[dict]) -> str:
    """One sentence: the hue at the two ends of every dataset's strip at the highest incidence.

    There the paper's purple-to-red change is largest; the caption states what the strips
    show in numbers rather than leaving it to the eye (display scaling changes the look).

    Parameters
    ----------
    strips : list of dict
        The strips of :func:`colour_strips`.

    Returns
    -------
    str
        The sentence, with a leading space; ``""`` when no strip has two swatches.
    """
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
