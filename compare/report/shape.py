"""The report's shape-ratio section: opposition and mirror-to-neighbours ratios (:mod:`compare.ratios`)."""

from __future__ import annotations

import html

from ..comparison import Comparison
from ..ratios import INNER_DEG, NEIGHBOUR_DEG, OUTER_DEG
from .page import Section
from .prose import fmt

__all__ = ["SHOWN_NM", "shape_section"]

#: the wavelengths a spectral comparison shows (the nearest compared ones); an RGB one shows G and R
SHOWN_NM = (550.0, 650.0)


def _shown_keys(comparison: Comparison) -> list[str]:
    bands = comparison.bands
    if bands.is_rgb:
        keys = [bands.key(b) for b in comparison.wavelength_nm]
        return [k for k in ("G", "R", "Y") if k in keys] or keys[:2]
    grid = comparison.wavelength_nm
    if len(grid) == 0:
        return []
    return list(dict.fromkeys(bands.key(min(grid, key=lambda w: abs(w - x))) for x in SHOWN_NM))


def shape_section(comparison: Comparison, metrics: dict) -> Section:
    """A table per ratio.

    Rows are the measurement and each simulation, columns the incidences where the measurement
    has the ratio, at :data:`SHOWN_NM` (or the G and R channels); a dataset that lacks the points
    is named with its reason.

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    metrics : dict
        Its figures (:meth:`Comparison.metrics`), with their ``shape`` ratios.

    Returns
    -------
    Section
        The section, placed before the colour section.
    """
    e = html.escape
    shape = metrics.get("shape", {})
    keys = _shown_keys(comparison)
    unit = "" if comparison.bands.is_rgb else " nm"
    parts = ["<h2>Shape ratios</h2><p>Each dataset's own ratios at one wavelength (the "
             "normalisation cancels). <b>Opposition</b>: beta averaged on the ring "
             f"{INNER_DEG:g} deg from the retro direction over the ring {OUTER_DEG:g} deg from it "
             "(shadow-hiding raises it above 1). <b>Mirror</b>: beta at the in-plane mirror "
             f"direction over its in-plane neighbours {NEIGHBOUR_DEG[0]:g}-{NEIGHBOUR_DEG[1]:g} deg "
             "either side (a mirror lobe raises it above 1). +- one standard uncertainty.</p>"]
    rows = ["measured"] + list(comparison.simulated)
    for ratio, title in (("opposition", "Opposition ratio"), ("mirror", "Mirror-to-neighbours ratio")):
        measured = shape.get("measured", {}).get(ratio, {})
        angles = list(measured.get("per_incidence", {}))
        if not angles:
            parts.append(f"<p><b>{title}</b>: the measurement lacks the points "
                         f"({e(measured.get('reason', 'no data'))}).</p>")
            continue
        head = "".join(f"<th>theta_i {e(a)}, {e(k)}{unit}</th>" for a in angles for k in keys)
        parts.append(f"<p><b>{title}</b></p><table><tr><th class='l'>dataset</th>{head}</tr>")
        reasons = []
        for name in rows:
            doc = shape.get(name, {}).get(ratio, {})
            per = doc.get("per_incidence", {})
            cells = []
            for a in angles:
                for k in keys:
                    v = per.get(a, {}).get("value", {}).get(k)
                    u = per.get(a, {}).get("u", {}).get(k)
                    cells.append(f"<td>{fmt(v)}" + (f" +- {fmt(u, 2)}" if v is not None and u else "")
                                 + "</td>")
            if "reason" in doc:
                reasons.append(f"'{name}': {doc['reason']}")
            parts.append(f"<tr><td class='l'>{e(name)}</td>{''.join(cells)}</tr>")
        parts.append("</table>")
        if reasons:
            parts.append("<p>Without the points: " + e("; ".join(reasons)) + ".</p>")
    return Section("shape", "\n".join(parts), before="colour")
