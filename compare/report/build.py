"""``write_report``: the comparison report's orchestration (data, figures, page, folder)."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gonio.data import write_files_together
from gonio.version import software

from ..colourmatch import band_luminance_weights
from ..comparison import Comparison
from ..errors import CompareError
from .curves import (
    BEAM_BLOCK_DEG,
    GRAZING_DEG,
    REPORT_WAVELENGTHS_NM,
    beam_blocked,
    luminance_curve,
    measured_inplane,
    sim_inplane,
    single_wavelength,
)
from .figures import (
    colour_strip_figure,
    colour_strips,
    factor_figure,
    hue_trend,
    inplane_figure,
    save_figure,
    spectrum_figure,
    swatch_figure,
)
from .outdir import prepare_out_dir
from .page import Section, page_html
from .shape import shape_section

__all__ = ["write_report"]

log = logging.getLogger("compare.report")


def write_report(comparison: Comparison, out_dir: str | os.PathLike, *, svg: bool = False,
                 force: bool = False, sections: Sequence[Section] = ()) -> Path:
    """Write ``report.html``, ``metrics.json`` and ``figures/*.png`` into ``out_dir``.

    All files are written together (:func:`gonio.data.write_files_together`): a report that cannot be
    written (a full disk) is one :class:`~compare.errors.CompareError` and leaves ``out_dir`` as it was
    (nothing of this report in it, a previous report unchanged).

    ``out_dir`` must be new, empty or hold a previous report (whose files alone are replaced;
    figures of the previous report that this one does not draw are removed); any other folder
    is refused with a :class:`~compare.errors.CompareError` unless ``force``. ``svg`` also writes
    ``figures/*.svg``. ``sections`` are added to the page (each before the standard section it
    names, :class:`compare.report.Section`), their figures written into ``figures/``.

    Parameters
    ----------
    comparison : compare.comparison.Comparison
        The comparison to report (:func:`compare.comparison.compare_datasets`).
    out_dir : path-like
        The report's folder.
    svg : bool
        Also write ``figures/*.svg``.
    force : bool
        Write into a folder that holds other files.
    sections : sequence of Section
        Sections added to the page.

    Returns
    -------
    pathlib.Path
        The path of ``report.html``.
    """
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out_dir)
    previous = prepare_out_dir(out, force)
    fig_dir = Path("figures")
    files: dict[Path, bytes] = {}     # written together at the end
    metrics = comparison.metrics()
    grid = comparison.wavelength_nm
    bands = comparison.bands
    weights = band_luminance_weights(bands, grid, comparison.illuminant)
    measured = measured_inplane(comparison)
    simulated = {name: sim_inplane(comparison, name) for name in comparison.simulated}
    figures: dict[str, tuple[bytes, str]] = {}
    sims = ", ".join(comparison.simulated)
    blocked = beam_blocked(measured, comparison.measured) if not measured.empty else set()
    gap = (f"across the beam-blocked cone around the retro-direction (shaded, |s + theta_i| < "
           f"{BEAM_BLOCK_DEG:g} deg, where the detector would block the source; drawn only at "
           "the incidences where the measurement has that gap)" if blocked else
           "e.g. where the measurement has no point (it has no beam-blocked gap, the "
           "instrument's or a measurement without one: none is shaded)")
    preface = ("Reading the in-plane figures: points are the measurement "
               f"'{comparison.measured.name}'; lines are the simulations ({sims}), normalised "
               f"per {bands.noun} by k, broken where a curve has no point, {gap}; the dotted "
               "line marks the retro-direction, the dashed one the mirror direction. Shaded "
               "around each line: +-1 standard uncertainty of that simulation (its Monte Carlo "
               "standard error times k; for Y[beta] summed linearly over the wavelengths, since "
               "one set of photons serves every wavelength and their errors are correlated). "
               "Panels share one value axis except those titled 'own scale' (grazing "
               f"incidences, >= {GRAZING_DEG:g} deg), which would flatten the others."
               if not measured.empty else "")

    def bars_note(hidden: bool, what: str) -> str:
        if hidden:
            return (f" The error bars ({what}) are smaller than the markers at this scale.")
        return f" Error bars: {what}."

    def inplane(fname, meas_rows, sim_rows, title, ylabel, caption):
        fig, hidden = inplane_figure(meas_rows, sim_rows, title, ylabel,
                                     comparison.measured.name, blocked=blocked)
        data = save_figure(fig, fig_dir / fname, svg, files)
        figures[fname] = (data, caption + bars_note(hidden, "+-1 standard uncertainty of the "
                                                    "measurement") + " Lines and shading: see "
                          "the note above the figures.")

    if not measured.empty:
        inplane("inplane_luminance.png", luminance_curve(measured, grid, weights),
                {n: luminance_curve(r, grid, weights, correlated=True)
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
            inplane(fname, single_wavelength(measured, wl),
                    {n: single_wavelength(r, wl) for n, r in simulated.items()},
                    f"radiance coefficient, {at}", "beta / pi  (1/sr)",
                    f"In-plane BRDF beta/pi, {at}, against the signed observation angle "
                    "s, one panel per incidence angle. Points: the measurement "
                    f"'{comparison.measured.name}'." + interpolated_at(comparison, wl))
    else:
        log.warning("the measured dataset has no in-plane points: no in-plane figures")
    if comparison.colour is not None:
        colour_figures(comparison, figures, fig_dir, svg, files)
    figures["factor.png"] = (save_figure(factor_figure(comparison), fig_dir / "factor.png", svg, files),
        "Normalisation factor k(lambda) = beta_meas(0,0) / C(0,0) of each simulation"
        + (" (per channel)" if bands.is_rgb else "") + ". Error bars: "
        "its standard uncertainty u_k = k sqrt((u_meas/beta_meas)^2 + (u_C/C)^2), from the "
        "estimate of the measured normal value (data and quadratic-vs-linear model term) and "
        "the simulation's normal value; not folded into the curve errors (see the "
        "normalisation table).")
    files[Path("metrics.json")] = (json.dumps({**metrics, "software": software()}, indent=2, allow_nan=False) + "\n").encode("utf-8")
    for section in sections:
        for name, data in section.figures.items():
            files[fig_dir / name] = data
    report = out / "report.html"
    extra = list(sections)
    if any("per_incidence" in r for r in metrics["shape"]["measured"].values()):
        extra.append(shape_section(comparison, metrics))
    files[Path("report.html")] = page_html(comparison, metrics, figures, extra, preface).encode("utf-8")
    write_together(out, files, "report")
    written = {out / name for name in files}
    for old in previous:
        for stale in (old, old.with_suffix(".svg")):
            if stale not in written and stale.suffix in (".png", ".svg") and stale.is_file():
                stale.unlink()
    return report


def interpolated_at(comparison: Comparison, wavelength: float) -> str:
    """A sentence naming the simulations that do not hold ``wavelength``, or ``""``.

    Their curve there is linearly interpolated in wavelength.

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    wavelength : float
        The wavelength (nm).

    Returns
    -------
    str
        The sentence, with a leading space; ``""`` when every simulation holds ``wavelength`` or the
        comparison is on channels.
    """
    if comparison.bands.is_rgb:
        return ""
    names = [name for name, ds in comparison.simulated.items()
             if not np.any(np.abs(ds.wavelengths_nm - wavelength) < 1e-6)]
    if not names:
        return ""
    return (f" {', '.join(repr(n) for n in names)} "
            + ("has" if len(names) == 1 else "have")
            + f" no simulated value at {wavelength:g} nm: drawn from values linearly "
            "interpolated in wavelength (see the note on interpolation).")


def write_together(out: Path, files: dict, what: str) -> None:
    """:func:`gonio.data.write_files_together`, its failure one :class:`CompareError` line.

    Parameters
    ----------
    out : Path
        The folder written into.
    files : dict
        Path (relative to ``out``) -> bytes.
    what : str
        What the files are (e.g. "report"), for the message.

    Raises
    ------
    CompareError
        When the files cannot be written; none of them is then written.
    """
    try:
        write_files_together(out, {str(k): v for k, v in files.items()})
    except OSError as exc:
        raise CompareError(f"cannot write the {what} into {out}: {exc.strerror or exc} (writing {exc.filename}); "
                           f"nothing of this {what} was written and the folder is as it was: free space or choose "
                           "another --out") from exc


def colour_figures(comparison: Comparison, figures: dict, fig_dir: Path, svg: bool, files: dict | None = None) -> None:
    """Add the colour figures to ``figures``: spectra and swatches at the colour geometry, colour strips.

    Parameters
    ----------
    comparison : Comparison
        The comparison; its colour match must be known.
    figures : dict
        File name -> ``(PNG bytes, caption)``, added to in place.
    fig_dir : Path
        The report's ``figures/`` folder.
    svg : bool
        Also write each figure as SVG.
    files : dict, optional
        Collects path -> bytes instead of writing them (see :func:`save_figure`).
    """
    geo = comparison.colour_matched().geometry
    figures["spectrum.png"] = (save_figure(spectrum_figure(comparison), fig_dir / "spectrum.png",
                                           svg, files),
        ("Channels" if comparison.bands.is_rgb else "Spectra")
        + f" at the colour geometry (theta_i={geo['theta_i']:g}, theta_o={geo['theta_o']:g}"
        " deg). Points with +-1 standard uncertainty: the measurement; each simulation scaled "
        "by the single luminance factor k_Y used for the colour match"
        + (" (channels as points: R, G and B are not a continuum)" if comparison.bands.is_rgb
           else "")
        + f". Normalised per {comparison.bands.noun} instead, every simulation would equal the "
        "measurement here by construction, so that view is not drawn.")
    figures["swatches.png"] = (save_figure(swatch_figure(comparison), fig_dir / "swatches.png",
                                        svg, files),
        "Colour swatches at the colour geometry as shown on screen (gamma-encoded sRGB); the "
        "H, S, V printed under each are those of the displayed pixel. The table's H, S, V "
        "are of linear sRGB, hence different numbers for the same colour.")
    strips = colour_strips(comparison)
    if strips:
        figures["colour_strips.png"] = (
            save_figure(colour_strip_figure(strips), fig_dir / "colour_strips.png", svg, files),
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
            "red as the light moves from the camera's side to the far side." + hue_trend(strips))
