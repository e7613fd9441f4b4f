"""The comparison report: ``report.html`` (one self-contained file), ``figures/*.png``,
``metrics.json``.

Figures (matplotlib, Agg backend, written to ``figures/`` and embedded in the HTML as base64 PNG):

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
    labelled with H, S, V.

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
from pathlib import Path

import numpy as np
import pandas as pd

from gonio.dataset import atomic_write

from .colourmatch import luminance_weights
from .comparison import Comparison

__all__ = ["REPORT_WAVELENGTHS_NM", "write_report"]

log = logging.getLogger(__name__)

#: Single wavelengths plotted (nearest shared ones).
REPORT_WAVELENGTHS_NM = (450.0, 550.0, 650.0)
_MEASURED_COLOUR = "black"
_LINESTYLES = ("-", "--", "-.", ":")


def _label(text: str) -> str:
    """A matplotlib-safe label (no mathtext, not hidden by a leading underscore)."""
    text = str(text).replace("$", r"\$")
    return " " + text if text.startswith("_") else text




def _savefig(fig, path: Path) -> bytes:
    import io

    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
    data = buffer.getvalue()
    atomic_write(path, data)
    return data


def _sim_inplane(comparison: Comparison, name: str) -> pd.DataFrame:
    """Normalised in-plane simulated rows (``theta_i, s, wavelength_nm, beta, u_beta``)."""
    grid = comparison.wavelength_nm
    sim = comparison.simulated[name]
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
    rows = comparison.measured.in_plane()
    grid = comparison.wavelength_nm
    keep = np.min(np.abs(rows["wavelength_nm"].to_numpy()[:, None] - grid[None, :]), axis=1) < 1e-6
    rows = rows[keep]
    return pd.DataFrame({"theta_i": rows["theta_i"].to_numpy(), "s": rows["s"].to_numpy(),
                         "phi_i": rows["phi_i"].to_numpy(),
                         "wavelength_nm": rows["wavelength_nm"].to_numpy(),
                         "beta": rows["beta"].to_numpy(), "u_beta": rows["u_beta"].to_numpy()})


def _luminance_curve(rows: pd.DataFrame, grid: np.ndarray, weights: np.ndarray) -> pd.DataFrame:
    """``Y`` and ``u_Y`` per in-plane geometry (complete spectra on ``grid`` only)."""
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
    u_values = np.sqrt((u.to_numpy()[complete] ** 2) @ (weights ** 2))
    index = b.index.to_frame(index=False)[complete]
    return pd.DataFrame({"theta_i": index["theta_i"].to_numpy(), "s": index["s"].to_numpy(),
                         "value": values, "u": u_values})


def _single_wavelength(rows: pd.DataFrame, wavelength_nm: float) -> pd.DataFrame:
    sel = rows[np.abs(rows["wavelength_nm"].to_numpy() - wavelength_nm) < 1e-6]
    return pd.DataFrame({"theta_i": sel["theta_i"].to_numpy(), "s": sel["s"].to_numpy(),
                         "value": sel["beta"].to_numpy(), "u": sel["u_beta"].to_numpy()})


def _inplane_figure(measured: pd.DataFrame, simulated: dict[str, pd.DataFrame], title: str,
                    ylabel: str, measured_name: str):
    import matplotlib.pyplot as plt

    angles = sorted(set(measured["theta_i"].round(6)))
    n = max(len(angles), 1)
    ncols = min(n, 2)
    nrows = math.ceil(n / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(6.0 * ncols, 3.8 * nrows), squeeze=False,
                             sharey=True)
    for ax, theta_i in zip(axes.ravel(), angles):
        m = measured[np.abs(measured["theta_i"] - theta_i) < 1e-6].sort_values("s")
        ax.errorbar(m["s"], m["value"] / np.pi, yerr=m["u"] / np.pi, fmt="o", ms=4, capsize=2,
                    color=_MEASURED_COLOUR, label=_label(f"{measured_name} (measured)"))
        for j, (name, rows) in enumerate(simulated.items()):
            r = rows[np.abs(rows["theta_i"] - theta_i) < 1e-6].sort_values("s")
            if not r.empty:
                ax.plot(r["s"], r["value"] / np.pi, _LINESTYLES[j % len(_LINESTYLES)],
                        marker=".", label=_label(name))
        lo = min(-65.0, float(m["s"].min()) - 5 if len(m) else -65.0)
        hi = max(75.0, float(m["s"].max()) + 5 if len(m) else 75.0)
        ax.set_xlim(lo, hi)
        ax.axvline(-theta_i, color="0.8", lw=0.8, ls=":")
        ax.set_title(f"incidence {theta_i:g} deg")
        ax.set_xlabel("signed observation angle s (deg)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(angles):]:
        ax.set_visible(False)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(_label(title))
    fig.tight_layout()
    return fig


def _spectrum_figure(comparison: Comparison):
    import matplotlib.pyplot as plt

    cm = comparison.colour
    geo = cm.geometry
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
                ax.plot(sc.wavelength_nm, sc.beta, "-", label=_label(f"{name} x k_Y"))
            else:
                frame = comparison.frames[name]
                r = frame[(np.abs(frame[["theta_i", "phi_i", "theta_o", "phi_o"]].to_numpy()
                                  - np.array([geo["theta_i"], geo["phi_i"], geo["theta_o"],
                                              geo["phi_o"]])) < 1e-6).all(axis=1)]
                ax.plot(r["wavelength_nm"], r["beta_sim"], "-", label=_label(f"{name} x k(lambda)"))
        ax.set_xlabel("wavelength (nm)")
        ax.set_title("normalised per wavelength" if not scaled else
                     "scaled by the luminance factor k_Y (colour match)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("radiance coefficient beta")
    fig.suptitle(f"spectra at theta_i={geo['theta_i']:g}, phi_i={geo['phi_i']:g}, "
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
    ax.set_ylabel("k = beta_meas(0,0) / C(0,0)")
    ax.set_title("normalisation factor")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _swatch_figure(comparison: Comparison):
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    from gonio.colour import display_srgb

    cm = comparison.colour
    entries = [(f"{comparison.measured.name} (measured)", cm.measured)]
    entries += [(name, sc.colour) for name, sc in cm.simulated.items()]
    fig, ax = plt.subplots(figsize=(2.4 * len(entries), 2.8))
    for j, (name, c) in enumerate(entries):
        rgb = display_srgb(c.rgb)
        ax.add_patch(Rectangle((j + 0.05, 0.3), 0.9, 0.7, color=tuple(rgb)))
        ax.text(j + 0.5, 0.22, _label(name), ha="center", va="top", fontsize=8, wrap=True)
        ax.text(j + 0.5, 0.05, f"H {c.h:.3f} S {c.s:.3f} V {c.v:.3f}", ha="center", va="top",
                fontsize=8)
    ax.set_xlim(0, len(entries))
    ax.set_ylim(-0.1, 1.05)
    ax.axis("off")
    fig.tight_layout()
    return fig


def _fmt(x, digits: int = 4) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}g}" if math.isfinite(x) else "-"
    return html.escape(str(x))


def _html(comparison: Comparison, metrics: dict, figures: dict[str, bytes]) -> str:
    e = html.escape
    meas = comparison.measured
    parts = ["<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
             f"<title>Comparison report: {e(meas.name)}</title>",
             "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;}"
             "table{border-collapse:collapse;margin:0.5em 0 1.5em;}"
             "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right;}"
             "th{background:#eee;} td.l,th.l{text-align:left;} img{max-width:100%;}"
             "code{background:#f4f4f4;}</style></head><body>",
             f"<h1>Measurement vs simulation: {e(meas.name)}</h1>",
             "<h2>Datasets</h2><table><tr><th class='l'>role</th><th class='l'>name</th>"
             "<th class='l'>path</th><th class='l'>sample</th><th class='l'>source</th>"
             "<th>rows</th><th class='l'>created</th></tr>"]

    def meta_text(d) -> str:
        return json.dumps(d, ensure_ascii=False, sort_keys=True, default=str)

    rows = [("measured", meas.name, meas)] + [("simulated", n, ds) for n, ds in
                                             comparison.simulated.items()]
    for role, name, ds in rows:
        source = ds.meta.get("instrument", ds.meta.get("model", {}))
        parts.append(
            f"<tr><td class='l'>{e(role)}</td><td class='l'>{e(name)}</td>"
            f"<td class='l'><code>{e(str(ds.path) if ds.path else '-')}</code></td>"
            f"<td class='l'><code>{e(meta_text(ds.meta.get('sample', {})))}</code></td>"
            f"<td class='l'><code>{e(meta_text(source))}</code></td>"
            f"<td>{len(ds.table)}</td><td class='l'>{e(str(ds.meta.get('created', '-')))}</td>"
            "</tr>")
    grid = comparison.wavelength_nm
    parts.append("</table>")
    parts.append(f"<p>Compared on {grid.size} wavelengths, {grid[0]:g}..{grid[-1]:g} nm; "
                 f"colour under illuminant {e(comparison.illuminant)} "
                 "(CIE 1931 2-degree observer, linear sRGB).</p>")
    norm = metrics["normalisation"]
    mn = comparison.measured_normal
    parts.append("<h2>Normalisation at the normal direction</h2>")
    parts.append(f"<p>{e(norm['method'])}</p>")
    parts.append(f"<p>Measured normal/normal value: <b>{e(mn.how)}</b> from s = "
                 f"{e(', '.join(f'{s:g}' for s in mn.s_used))} deg; median beta(0,0) = "
                 f"{np.median(mn.value):.4g}, median u = {np.median(mn.u):.2g} "
                 f"(of which model term {np.median(mn.u_model):.2g}).</p>")
    parts.append("<table><tr><th class='l'>simulation</th><th class='l'>C(0,0)</th>"
                 "<th>median k</th><th>k range</th><th>luminance k_Y</th></tr>")
    for name, n in comparison.normalisations.items():
        parts.append(f"<tr><td class='l'>{e(name)}</td><td class='l'>{e(n.simulated.how)}</td>"
                     f"<td>{np.median(n.factor):.4g}</td>"
                     f"<td>{n.factor.min():.4g} .. {n.factor.max():.4g}</td>"
                     f"<td>{_fmt(metrics['normalisation']['factor'][name]['luminance'])}</td></tr>")
    parts.append("</table>")
    parts.append("<h2>Curve errors</h2><p>Residuals k C - beta_meas over all shared geometries "
                 "and wavelengths of each incidence angle (units of beta).</p>")
    parts.append("<table><tr><th class='l'>simulation</th><th>theta_i</th><th>RMSE</th>"
                 "<th>NRMSE</th><th>max |d|</th><th class='l'>where (theta_i, phi_i, theta_o, "
                 "phi_o; s; wavelength)</th></tr>")
    for name, per_angle in metrics["curves"].items():
        for angle, m in per_angle.items():
            at = m["max_abs_at"]
            where = (f"{at['theta_i']:g}, {at['phi_i']:g}, {at['theta_o']:g}, {at['phi_o']:g}; "
                     f"s={_fmt(at['s'])}; {at['wavelength_nm']:g} nm")
            parts.append(f"<tr><td class='l'>{e(name)}</td><td>{e(angle)}</td>"
                         f"<td>{_fmt(m['rmse'])}</td><td>{_fmt(m['nrmse'])}</td>"
                         f"<td>{_fmt(m['max_abs'])}</td><td class='l'>{e(where)}</td></tr>")
        o = metrics["overall"][name]
        parts.append(f"<tr><th class='l'>{e(name)}</th><th>all</th><th>{_fmt(o['rmse'])}</th>"
                     f"<th>{_fmt(o['nrmse'])}</th><th></th><th></th></tr>")
    parts.append("</table>")
    colour = metrics["colour"]
    geo = colour["geometry"]
    parts.append(
        "<h2>Colour match</h2>"
        f"<p>At theta_i={geo['theta_i']:g}, phi_i={geo['phi_i']:g}, theta_o={geo['theta_o']:g}, "
        f"phi_o={geo['phi_o']:g} deg (s = {_fmt(geo['s'])}), the shared geometry closest to "
        "normal incidence and observation. Simulations scaled by k_Y (luminance ratio of the "
        "normal/normal spectra); differences are simulated minus measured, dh on the hue circle."
        "</p><table><tr><th class='l'>dataset</th><th>H</th><th>S</th><th>V</th>"
        "<th>BLUE/RED</th><th>GREEN/RED</th><th>dh</th><th>ds</th><th>dv</th></tr>")
    for name, c in colour.items():
        if name == "geometry":
            continue
        shown = f"{meas.name} (measured)" if name == "measured" else name
        parts.append(f"<tr><td class='l'>{e(shown)}</td>" + "".join(
            f"<td>{_fmt(c.get(k))}</td>" for k in ("h", "s", "v", "blue_red", "green_red",
                                                   "dh", "ds", "dv")) + "</tr>")
    parts.append("</table><h2>Figures</h2>")
    for fname, data in figures.items():
        b64 = base64.b64encode(data).decode("ascii")
        parts.append(f"<figure><img alt='{e(fname)}' src='data:image/png;base64,{b64}'>"
                     f"<figcaption>{e(fname)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_report(comparison: Comparison, out_dir: str | os.PathLike) -> Path:
    """Write ``report.html``, ``metrics.json`` and ``figures/*.png`` into ``out_dir``.

    Returns
    -------
    pathlib.Path
        The path of ``report.html``.
    """
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out_dir)
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    metrics = comparison.metrics()
    grid = comparison.wavelength_nm
    weights = luminance_weights(grid, comparison.illuminant)
    measured = _measured_inplane(comparison)
    simulated = {name: _sim_inplane(comparison, name) for name in comparison.simulated}
    figures: dict[str, bytes] = {}
    if not measured.empty:
        figures["inplane_luminance.png"] = _savefig(_inplane_figure(
            _luminance_curve(measured, grid, weights),
            {n: _luminance_curve(r, grid, weights) for n, r in simulated.items()},
            f"luminance-weighted radiance coefficient ({comparison.illuminant})",
            "Y[beta] / pi  (1/sr)", comparison.measured.name), fig_dir / "inplane_luminance.png")
        picks = sorted({float(grid[np.argmin(np.abs(grid - w))]) for w in REPORT_WAVELENGTHS_NM})
        for wl in picks:
            fname = f"inplane_{wl:g}nm.png"
            figures[fname] = _savefig(_inplane_figure(
                _single_wavelength(measured, wl),
                {n: _single_wavelength(r, wl) for n, r in simulated.items()},
                f"radiance coefficient at {wl:g} nm", "beta / pi  (1/sr)",
                comparison.measured.name), fig_dir / fname)
    else:
        log.warning("the measured dataset has no in-plane points: no in-plane figures")
    figures["spectrum.png"] = _savefig(_spectrum_figure(comparison), fig_dir / "spectrum.png")
    figures["factor.png"] = _savefig(_factor_figure(comparison), fig_dir / "factor.png")
    figures["swatches.png"] = _savefig(_swatch_figure(comparison), fig_dir / "swatches.png")
    atomic_write(out / "metrics.json",
                  (json.dumps(metrics, indent=2, allow_nan=False) + "\n").encode("utf-8"))
    report = out / "report.html"
    atomic_write(report, _html(comparison, metrics, figures).encode("utf-8"))
    return report
