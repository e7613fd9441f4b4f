"""``report.html``: the page assembled from its sections.

Every user-supplied string (sample names, paths, meta fields) is escaped with
:func:`html.escape` before it enters the HTML.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field

import numpy as np

from ..comparison import Comparison
from .outdir import GENERATOR
from .prose import banners, fmt, sample_summary, source_summary

__all__ = ["SECTION_KEYS", "STYLE", "Section", "assemble", "colour_html", "head_html",
           "order_sections", "page_html", "result_html", "result_sentences"]


STYLE = ("<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;}"
         "table{border-collapse:collapse;margin:0.5em 0 1.5em;}"
         "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right;}"
         "th{background:#eee;} td.l,th.l{text-align:left;} img{max-width:100%;}"
         "code{background:#f4f4f4;} figure{margin:1.5em 0;}"
         "figcaption{max-width:60em;font-size:0.95em;}"
         ".note{background:#e8f1fb;border:1px solid #4a7ab5;padding:0.5em 1em;}"
         ".banner{background:#fff3cd;border:2px solid #c77c00;padding:0.6em 1em;"
         "font-weight:bold;}"
         ".result{font-size:1.1em;border-left:4px solid #2a6f97;padding:0.2em 1em;}"
         ".howto{background:#f3f8ee;border:1px solid #6a9a4a;padding:0.2em 1em 0.6em;"
         "margin:1em 0;}</style>")

#: The standard sections of a comparison report, in order (:attr:`Section.before` names one).
SECTION_KEYS = ("howto", "datasets", "normalisation", "curves", "colour", "figures")


@dataclass(frozen=True)
class Section:
    """One section of ``report.html``.

    Attributes
    ----------
    key : str
        Its name (the standard ones: :data:`SECTION_KEYS`).
    html : str
        Its HTML, normally starting with an ``<h2>``; every user string in it escaped by its
        author.
    figures : dict
        ``{file name: bytes}`` written into ``figures/`` with the report and listed among the
        report's own files (replaced or removed with it by the next report in that folder).
    before : str or None
        The standard section it goes before (``"datasets"``: under the "how to read this" box;
        ``"howto"``: right under the title and banners); None: at the end.
    """

    key: str
    html: str
    figures: dict[str, bytes] = field(default_factory=dict)
    before: str | None = "datasets"


def head_html(title: str, heading: str, files: list[str], style: str = STYLE) -> list[str]:
    """The page's head (generator and file list: :mod:`compare.report.outdir`) and title.

    Parameters
    ----------
    title : str
        The page's title (the browser's tab).
    heading : str
        The page's ``<h1>``.
    files : list of str
        The report's own files (relative paths), named in the head so that the next report in
        the folder may replace them.
    style : str, default STYLE
        The ``<style>`` element.

    Returns
    -------
    list of str
        The page's first lines of HTML, up to and including the ``<h1>``.
    """
    from gonio.version import describe

    e = html.escape
    return ["<!DOCTYPE html>", "<html lang='en'><head><meta charset='utf-8'>",
            f"<meta name='generator' content='{GENERATOR}'>",
            f"<meta name='software' content='{e(describe())}'>",
            f"<meta name='report-files' content='{e(' '.join(files))}'>",
            f"<title>{e(title)}</title>", style + "</head><body>", f"<h1>{e(heading)}</h1>"]


def assemble(head: list[str], sections: list[Section]) -> str:
    """The page: ``head``, the sections in order, and a footer naming the version (and commit) that wrote it.

    Parameters
    ----------
    head : list of str
        The page's first lines (:func:`head_html`, then banners and the result).
    sections : list of Section
        The sections, in page order.

    Returns
    -------
    str
        The whole page.
    """
    from gonio.version import describe

    footer = f"<footer><p class='software'>Written by {html.escape(describe())}.</p></footer>"
    return "\n".join(head + [s.html for s in sections] + [footer, "</body></html>"]) + "\n"


def order_sections(standard: list[Section], extra: list[Section]) -> list[Section]:
    """``extra`` placed before the standard section each names (in the order given).

    Parameters
    ----------
    standard : list of Section
        The standard sections, in page order.
    extra : list of Section
        The added sections; one naming no standard section goes at the end.

    Returns
    -------
    list of Section
        All the sections, in page order.
    """
    out: list[Section] = []
    for s in standard:
        out += [x for x in extra if x.before == s.key]
        out.append(s)
    known = {s.key for s in standard}
    return out + [x for x in extra if x.before not in known]


def page_html(comparison: Comparison, metrics: dict, figures: dict[str, tuple[bytes, str]],
              extra: list[Section] | tuple = (), preface: str = "") -> str:
    """The comparison report's page: banners, the standard sections and ``extra``.

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`, as ``metrics.json`` holds them).
    figures : dict of str to (bytes, str)
        Figure file name -> ``(PNG bytes, caption)``.
    extra : list of Section or tuple, default ()
        Sections added to the standard ones (:func:`order_sections`).
    preface : str, default ""
        Plain text said once above the figures.

    Returns
    -------
    str
        The page's HTML.
    """
    e = html.escape
    files = [f"figures/{name}" for name in figures]
    files += [f"figures/{name}" for s in extra for name in s.figures]
    head = head_html(f"Comparison report: {comparison.measured.name}",
                     f"Measurement vs simulation: {comparison.measured.name}", files)
    head += [f"<p class='banner'>{e(text)}</p>" for text in banners(comparison)]
    head.append(result_html(comparison, metrics))
    standard = [howto_section(comparison, metrics), datasets_section(comparison),
                normalisation_section(comparison, metrics), curves_section(comparison, metrics),
                colour_section(comparison, metrics), figures_section(figures, preface)]
    return assemble(head, order_sections(standard, list(extra)))


#: How a simulation's C(0,0) was obtained (NormalValue.how), in words that do not call a model
#: value "measured".
HOW_SIMULATED = {"measured": "its own s = 0 point", "estimated": "quadratic estimate",
                 "mixed": "s = 0 point at some wavelengths, estimate at others"}


def describe_dataset(ds) -> str:
    """What a dataset is, read from its meta.json (kind, sample, instrument or model).

    Parameters
    ----------
    ds : Dataset
        The dataset.

    Returns
    -------
    str
        A phrase, e.g. "a measurement of red cotton, by ...".
    """
    meta = ds.meta
    sample = meta.get("sample") if isinstance(meta.get("sample"), dict) else {}
    what = str(sample.get("name") or ds.name)
    details = [str(sample[k]) for k in ("description", "material", "colour", "model")
               if isinstance(sample.get(k), (str, int, float)) and str(sample[k])]
    if details:
        what += f" ({'; '.join(details)})"
    model = meta.get("model") if isinstance(meta.get("model"), dict) else {}
    instrument = meta.get("instrument") if isinstance(meta.get("instrument"), dict) else {}
    if ds.kind == "measured":
        by = instrument.get("name") or instrument.get("idn") or instrument.get("format")
        text = f"a measurement of {what}" + (f", by {by}" if by else "")
    else:
        text = f"a {ds.kind} dataset (not a measurement) of {what}"
    name = model.get("name") or model.get("method") or model.get("generator")
    if name:
        extra = [f"{k} {model[k]}" for k in ("method", "config") if model.get(k) and model[k] != name]
        text += f", made by the model {name}" + (f" ({', '.join(extra)})" if extra else "")
    if ds.relative:
        text += ", in relative (raw detector) units"
    return text


#: The model name :mod:`gonio.mock.truth` writes: such a dataset is the mock sample's true value (a check
#: of the instrument chain), not a model of the fabric, and is not ranked among the models.
TRUTH_MODEL = "mock virtual sample"


def _meets(metrics: dict, name: str, with_colour: bool) -> bool:
    """Within the thresholds of ``compare check`` (its defaults)."""
    from ..metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF

    nrmse = metrics["overall"][name]["nrmse"]
    ok = nrmse is not None and nrmse <= DEFAULT_MAX_NRMSE
    if with_colour:
        c = metrics["colour"][name]
        ok = ok and c["dh"] is not None and abs(c["dh"]) <= DEFAULT_MAX_HUE_DIFF
        ok = ok and c["ds"] is not None and abs(c["ds"]) <= DEFAULT_MAX_SAT_DIFF
    return ok


def _signed(x: float) -> str:
    """``x`` to 3 decimals with its sign; 0.000 unsigned (no "-0.000")."""
    return "0.000" if round(x, 3) == 0 else f"{x:+.3f}"


def result_sentences(comparison: Comparison, metrics: dict) -> list[str]:
    """The report's result in words, before any table.

    Which model is closest to the measurement and by how much on curve and colour, whether any
    meets the threshold, and what the threshold means.

    Closest is the smallest ``NRMSE^2 + dh^2 + ds^2`` (the fit's objective at its default colour
    weight; NRMSE alone when there is no colour statement). Datasets of the mock's true values
    (:data:`TRUTH_MODEL`) are checks of the instrument chain and are not ranked. Returns ``[]`` when
    there is no model to rank (a report of a measurement alone).

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`).

    Returns
    -------
    list of str
        Three sentences (the closest model, whether any model matches, what the threshold means),
        or ``[]``.
    """
    from ..metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF

    with_colour = comparison.colour is not None

    def is_truth(ds) -> bool:
        model = ds.meta.get("model") if isinstance(ds.meta.get("model"), dict) else {}
        return model.get("name") == TRUTH_MODEL

    names = [n for n, ds in comparison.simulated.items() if not is_truth(ds)]
    names = [n for n in names if metrics["overall"][n]["nrmse"] is not None]
    if not names:
        return []

    def colour_of(name: str) -> tuple[float | None, float | None]:
        c = metrics["colour"][name] if with_colour else {}
        return c.get("dh"), c.get("ds")

    def score(name: str) -> float:
        dh, ds = colour_of(name)
        extra = (dh or 0.0) ** 2 + (ds or 0.0) ** 2 if with_colour else 0.0
        return metrics["overall"][name]["nrmse"] ** 2 + extra

    ranked = sorted(names, key=score)
    best = ranked[0]
    nrmse = metrics["overall"][best]["nrmse"]
    how = f"its curves are off by an overall NRMSE of {fmt(nrmse, 3)}"
    dh, ds = colour_of(best)
    if with_colour and dh is not None and ds is not None:
        how += f" and its colour by {_signed(dh)} turn in hue and {_signed(ds)} in saturation"
    lead = (f"The only model, '{best}'" if len(ranked) == 1 else f"Closest to the measurement is '{best}'")
    first = f"{lead}: {how}"
    if len(ranked) > 1:
        second = ranked[1]
        first += f" (next: '{second}', NRMSE {fmt(metrics['overall'][second]['nrmse'], 3)})"
    first += "."
    meeting = [n for n in ranked if _meets(metrics, n, with_colour)]
    if not meeting:
        verdict = ("No model meets the threshold." if len(ranked) > 1 else "It does not meet the threshold.")
    elif len(meeting) == len(ranked):
        verdict = "Every model meets the threshold." if len(ranked) > 1 else "It meets the threshold."
    else:
        verdict = f"{', '.join(repr(n) for n in meeting)} {'meets' if len(meeting) == 1 else 'meet'} the threshold."
    colour_part = (f", its hue within {DEFAULT_MAX_HUE_DIFF:g} turn and its saturation within "
                   f"{DEFAULT_MAX_SAT_DIFF:g} near the normal direction" if with_colour else "")
    meaning = (f"The threshold (the defaults of compare check): after scaling to the measurement at the "
               f"normal direction, the model's curves are within an RMS of {DEFAULT_MAX_NRMSE:g} of the "
               f"mean measured value{colour_part}.")
    return [first, verdict, meaning]


def result_html(comparison: Comparison, metrics: dict) -> str:
    """:func:`result_sentences` as the page's first paragraph (empty without a model).

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`).

    Returns
    -------
    str
        A ``<section>`` of HTML, or ``""``.
    """
    sentences = result_sentences(comparison, metrics)
    if not sentences:
        return ""
    e = html.escape
    return (f"<section class='result' id='result'><p><b>{e(sentences[0])} {e(sentences[1])}</b></p>"
            f"<p>{e(sentences[2])}</p></section>")


def howto_section(comparison: Comparison, metrics: dict) -> Section:
    """The "how to read this" box: what the reference is, what the models are, what success is.

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`).

    Returns
    -------
    Section
        The section, with a verdict per model at the defaults of ``compare check``.
    """
    from ..metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_LEVEL_RATIO, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF

    e = html.escape
    meas = comparison.measured
    parts = ["<div class='howto'><h2>How to read this report</h2>",
             f"<p><b>The reference</b> '{e(meas.name)}' is {e(describe_dataset(meas))}.</p>",
             "<p><b>The models</b> compared with it:</p><ul>"]
    for name, ds in comparison.simulated.items():
        parts.append(f"<li>'{e(name)}': {e(describe_dataset(ds))}.</li>")
    parts.append("</ul>")
    per = comparison.bands.noun
    colour_rule = (f", and its colour near the normal direction within |dh| &le; "
                   f"{DEFAULT_MAX_HUE_DIFF:g} turn of the hue circle and |ds| &le; "
                   f"{DEFAULT_MAX_SAT_DIFF:g}" if comparison.colour is not None else "")
    parts.append(
        f"<p><b>Success.</b> Every model is scaled per {per} so that it equals the reference at "
        "the normal direction (so agreement there means nothing); what is judged is the SHAPE "
        "of the curves away from the normal and the colour. A model matches (the defaults of "
        f"<code>compare check</code>) when its overall NRMSE (curve RMSE over the mean "
        f"reference value) is &le; {DEFAULT_MAX_NRMSE:g}{colour_rule}"
        + ("" if comparison.relative else
           f", and its absolute level, which the normalisation hides, within a factor {DEFAULT_MAX_LEVEL_RATIO:g} "
           "of the measured one (level ratio max(k_Y, 1/k_Y) at the colour geometry)") + ".</p>")
    parts.append("<table><tr><th class='l'>model</th><th>overall NRMSE</th>"
                 + ("<th>dh (turns)</th><th>ds</th>" if comparison.colour is not None else "")
                 + "<th>level ratio</th><th class='l'>verdict</th></tr>")
    words = []
    for name in comparison.simulated:
        nrmse = metrics["overall"][name]["nrmse"]
        ok = nrmse is not None and nrmse <= DEFAULT_MAX_NRMSE
        cells = f"<td>{fmt(nrmse)}</td>"
        if comparison.colour is not None:
            c = metrics["colour"][name]
            ok = ok and c["dh"] is not None and abs(c["dh"]) <= DEFAULT_MAX_HUE_DIFF
            ok = ok and c["ds"] is not None and abs(c["ds"]) <= DEFAULT_MAX_SAT_DIFF
            cells += f"<td>{fmt(c['dh'])}</td><td>{fmt(c['ds'])}</td>"
        level = comparison.level(name)
        level_ok = not level.judged or level.ratio <= DEFAULT_MAX_LEVEL_RATIO
        cells += f"<td>{fmt(level.ratio) if level.judged else 'not judged'}</td>"
        verdict = ("matches" if ok and level_ok else "matches in shape, not in level" if ok
                   else "does not match")
        parts.append(f"<tr><td class='l'>{e(name)}</td>{cells}<td class='l'>{verdict}</td></tr>")
        if level.judged and not level_ok:
            words.append(level.words(name, nrmse if nrmse is not None else float("nan"), DEFAULT_MAX_LEVEL_RATIO,
                                     DEFAULT_MAX_NRMSE))
    parts.append("</table>")
    parts += [f"<p class='note'><b>Level:</b> {e(w)}.</p>" for w in words]
    parts.append("</div>")
    return Section("howto", "\n".join(parts))


def datasets_section(comparison: Comparison) -> Section:
    """The "Datasets" section: every dataset compared, what the comparison is made on, and its notes.

    Parameters
    ----------
    comparison : Comparison
        The comparison.

    Returns
    -------
    Section
        The section.
    """
    e = html.escape
    parts: list[str] = []
    meas = comparison.measured
    parts.append("<h2>Datasets</h2><table><tr><th class='l'>role</th><th class='l'>name</th>"
                 "<th class='l'>path</th><th class='l'>sample</th><th class='l'>source</th>"
                 "<th>rows</th><th class='l'>created</th></tr>")
    rows = [("measured", meas.name, meas)] + [("simulated", n, ds) for n, ds in
                                             comparison.simulated.items()]
    for role, name, ds in rows:
        parts.append(
            f"<tr><td class='l'>{e(role)}</td><td class='l'>{e(name)}</td>"
            f"<td class='l'><code>{e(str(ds.path) if ds.path else '-')}</code></td>"
            f"<td class='l'>{e(sample_summary(ds))}</td>"
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
        own = {name: comparison.simulated_wavelengths_used(name) for name in comparison.simulated}
        partial = [f"'{name}' holds {k} of them" for name, k in own.items() if k < grid.size]
        parts.append(f"<p>Compared on the {grid.size} measured wavelengths "
                     f"{grid[0]:g}..{grid[-1]:g} nm"
                     + (f" ({e('; '.join(partial))}, the others linearly interpolated in "
                        "wavelength: see the note)" if partial else "") + "; "
                     f"colour under illuminant {e(comparison.illuminant)} "
                     "(CIE 1931 2-degree observer, linear sRGB).</p>")
    for text in comparison.notes():
        parts.append(f"<p class='note'><b>Note:</b> {e(text[0].upper() + text[1:])}.</p>")
    return Section("datasets", "\n".join(parts))


def normalisation_section(comparison: Comparison, metrics: dict) -> Section:
    """The "Normalisation at the normal direction" section: the measured normal value and each factor ``k``.

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`).

    Returns
    -------
    Section
        The section.
    """
    e = html.escape
    parts: list[str] = []
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
    parts.append("<table><tr><th class='l'>simulation</th><th class='l'>C(0,0) from</th>"
                 "<th>median k</th><th>k range</th><th>median u_k / k</th>"
                 "<th>luminance k_Y</th><th>k spread (max/min)</th><th>k CV</th>"
                 "<th>overall NRMSE at k - u_k .. k + u_k</th></tr>")
    for name, n in comparison.normalisations.items():
        lo, hi = comparison.nrmse_with_factor_shifted(name)
        lv = comparison.level(name)
        parts.append(f"<tr><td class='l'>{e(name)}</td><td class='l'>{e(HOW_SIMULATED[n.simulated.how])}</td>"
                     f"<td>{np.median(n.factor):.4g}</td>"
                     f"<td>{n.factor.min():.4g} .. {n.factor.max():.4g}</td>"
                     f"<td>{np.median(n.u_factor / n.factor):.2g}</td>"
                     f"<td>{fmt(metrics['normalisation']['factor'][name]['luminance'])}</td>"
                     f"<td>{fmt(lv.spread)}</td><td>{fmt(lv.cv)}</td>"
                     f"<td>{fmt(lo)} .. {fmt(hi)}</td></tr>")
    parts.append("</table>")
    parts.append("<p>The factor k makes every model equal the reference at the normal, so the curve errors judge "
                 "shape only. The level is judged apart: k_Y (the luminance-weighted k at the colour geometry) is "
                 "how many times the measurement exceeds the model there; a k spread above 1 is a colour "
                 "difference the normalisation took out at the normal.</p>")
    return Section("normalisation", "\n".join(parts))


def curves_section(comparison: Comparison, metrics: dict) -> Section:
    """The "Curve errors" section: RMSE, NRMSE and the largest difference per simulation and incidence.

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`).

    Returns
    -------
    Section
        The section.
    """
    e = html.escape
    parts: list[str] = []
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
                     f"s={fmt(at['s'])}; "
                     + (f"channel {at['channel']}" if 'channel' in at
                        else f"{at['wavelength_nm']:g} nm"))
            parts.append(f"<tr><td class='l'>{e(name)}</td><td>{e(angle)}</td>"
                         f"<td>{fmt(m['rmse'])}</td><td>{fmt(m['nrmse'])}</td>"
                         f"<td>{fmt(m['max_abs'])}</td><td class='l'>{e(where)}</td></tr>")
        o = metrics["overall"][name]
        parts.append(f"<tr><th class='l'>{e(name)}</th><th>all</th><th>{fmt(o['rmse'])}</th>"
                     f"<th>{fmt(o['nrmse'])}</th><th></th><th></th></tr>")
    parts.append("</table>")
    return Section("curves", "\n".join(parts))


def colour_section(comparison: Comparison, metrics: dict) -> Section:
    """The "Colour match" section: the H, S, V table, or why there is no colour statement.

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`).

    Returns
    -------
    Section
        The section.
    """
    parts: list[str] = []
    colour = metrics["colour"]
    if not colour and comparison.colour_note:
        parts.append("<h2>Colour match</h2><p class='note'>No colour statement (no H, S, V): "
                     f"{html.escape(comparison.colour_note)}. The curves and their errors are compared "
                     "above.</p>")
    elif not colour:
        parts.append("<h2>Colour match</h2><p class='note'>No colour statement: the measurement "
                     "is photometric (Y only).</p>")
    else:
        colour_html(parts, comparison, colour)
    return Section("colour", "\n".join(parts))


def figures_section(figures: dict[str, tuple[bytes, str]], preface: str = "") -> Section:
    """The figures with numbered captions.

    ``preface`` (plain text) is said once above them (what every in-plane figure shares).

    Parameters
    ----------
    figures : dict of str to (bytes, str)
        Figure file name -> ``(PNG bytes, caption)``, in page order.
    preface : str, default ""
        Plain text said once above the figures.

    Returns
    -------
    Section
        The section, each figure embedded as a data URL.
    """
    e = html.escape
    parts: list[str] = []
    parts.append("<h2>Figures</h2>")
    if preface:
        parts.append(f"<p class='note'>{e(preface)}</p>")
    for j, (fname, (data, caption)) in enumerate(figures.items(), start=1):
        b64 = base64.b64encode(data).decode("ascii")
        parts.append(f"<figure><img alt='{e(caption.split('.')[0])}' "
                     f"src='data:image/png;base64,{b64}'>"
                     f"<figcaption><b>Figure {j}.</b> {e(caption)} "
                     f"<span style='color:#777'>(figures/{e(fname)})</span></figcaption>"
                     "</figure>")
    return Section("figures", "\n".join(parts))


def colour_html(parts: list[str], comparison: Comparison, colour: dict) -> None:
    """Append the colour-match table of ``metrics.json``'s ``colour`` to ``parts`` (HTML).

    Parameters
    ----------
    parts : list of str
        The section's HTML so far, appended to in place.
    comparison : Comparison
        The comparison.
    colour : dict
        ``metrics.json``'s ``colour``: the ``geometry`` and each dataset's figures by name.
    """
    e = html.escape
    meas = comparison.measured
    geo = colour["geometry"]
    scaled = ("Simulations scaled by k_Y (luminance ratio of the normal/normal "
              + ("channels" if comparison.bands.is_rgb else "spectra") + ")")
    parts.append(
        "<h2>Colour match</h2>"
        f"<p>At theta_i={geo['theta_i']:g}, phi_i={geo['phi_i']:g}, theta_o={geo['theta_o']:g}, "
        f"phi_o={geo['phi_o']:g} deg (s = {fmt(geo['s'])}), the shared geometry closest to "
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
        parts.append(f"<tr><td class='l'>{e(shown)}</td><td>{fmt(c.get('h'))}</td>"
                     f"<td>{fmt(h_deg, 3)}</td>" + "".join(
                         f"<td>{fmt(c.get(k))}</td>" for k in ("s", "v", "blue_red",
                                                               "green_red", "dh", "ds", "dv"))
                     + "</tr>")
    parts.append("</table>")
    if comparison.relative:
        parts.append("<p class='note'><b>V and dv refused:</b> the measurement is relative (raw "
                     "detector units), so no absolute colour statement is made; H, S and the "
                     "ratios do not depend on the scale.</p>")
