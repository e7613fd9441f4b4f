"""Report section "Fitted parameters": what ``simulate fit`` found, from its ``fit.json``.

``fits_section(fit_dirs, simulated)`` reads ``DIR/fit.json`` of each ``simulate fit`` output folder
(:mod:`fabric_optics.fitting.search`: method, start config, objective, the figures before and after, every free
parameter with its start, bounds, fitted value and standard uncertainty split into its data and
Monte Carlo parts, warnings, evaluations, walks, seconds) and writes one table per fit. A simulated
dataset of the report made from a fit's ``fitted.toml`` (``simulate fabric DIR/fitted.toml``: its
``provenance.config.source``) is named under that fit: it has no fit of its own, its parameters
are the fit's. ``compare report
--fit DIR`` adds the section (before the normalisation).
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..errors import CompareError
from .page import Section

__all__ = ["fits_section", "read_fit"]


def read_fit(fit_dir: str | Path) -> dict:
    """``fit_dir/fit.json`` as a dict; :class:`CompareError` (one line) when it is not a fit.

    Parameters
    ----------
    fit_dir : str or Path
        The ``--out`` folder of ``simulate fit``.

    Returns
    -------
    dict
        The fit's summary, with its ``parameters`` list.

    Raises
    ------
    CompareError
        When ``fit.json`` is missing, too large, unreadable, or not a fit's summary.
    """
    path = Path(fit_dir) / "fit.json"
    try:
        if path.stat().st_size > MAX_FIT_BYTES:
            raise CompareError(f"--fit {fit_dir}: fit.json holds {path.stat().st_size:,} bytes; a fit's summary "
                               f"holds a few kB (at most {MAX_FIT_BYTES:,}): not written by simulate fit")
        if not path.is_file():
            raise CompareError(f"--fit {fit_dir}: fit.json is not a regular file")
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CompareError(f"--fit {fit_dir}: no fit.json there (give the --out folder of "
                           "`simulate fit`)") from None
    except RecursionError:
        raise CompareError(f"--fit {fit_dir}: fit.json is nested too deeply to be read (not written by "
                           "simulate fit)") from None
    except (OSError, ValueError) as exc:
        raise CompareError(f"--fit {fit_dir}: fit.json unreadable ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("parameters"), list):
        raise CompareError(f"--fit {fit_dir}: fit.json has no parameters list (not written by "
                           "simulate fit)")
    _check_fields(doc, fit_dir)
    return doc


#: Largest fit.json read (a fit's summary is a few kB).
MAX_FIT_BYTES = 16 * 2**20


def _check_fields(doc: dict, fit_dir: str | Path) -> None:
    """Refuse a fit.json whose fields have the wrong types (a hand edit): one line naming the field."""
    def fail(field: str, what: str) -> None:
        raise CompareError(f"--fit {fit_dir}: fit.json field '{field}' must be {what}, got "
                           f"{type(value).__name__}")

    for key in ("start", "fitted", "info", "uncertainty"):
        value = doc.get(key)
        if value is not None and not isinstance(value, dict):
            fail(key, "an object")
    for key in ("start", "fitted"):
        for figure in ("nrmse", "dh", "ds"):
            value = (doc.get(key) or {}).get(figure)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                fail(f"{key}.{figure}", "a number")
    for k, value in enumerate(doc["parameters"]):
        if not isinstance(value, dict):
            fail(f"parameters[{k}]", "an object")
    for key, value in (("warnings", doc.get("warnings")), ("info.notes", (doc.get("info") or {}).get("notes"))):
        if value is not None and not isinstance(value, list):
            fail(key, "a list")


def _num(x, digits: int = 4) -> str:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return "-"
    return f"{v:.{digits}g}" if math.isfinite(v) else "-"


def _figures(c: Mapping) -> str:
    out = f"NRMSE {_num(c.get('nrmse'))}"
    if "dh" in c:
        out += f", dh {_signed(c.get('dh'))} turn, ds {_signed(c.get('ds'))}"
    return out


def _signed(x) -> str:
    v = float(x) if isinstance(x, (int, float)) else math.nan
    return f"{v:+.4f}" if math.isfinite(v) else "-"


def _made_from(fit_dir: Path, simulated: Mapping) -> list[str]:
    """Names of the simulated datasets whose config is ``fit_dir/fitted.toml``."""
    target = (fit_dir / "fitted.toml").resolve()
    names = []
    for name, ds in simulated.items():
        source = ((ds.meta.get("provenance") or {}).get("config") or {}).get("source")
        if isinstance(source, str) and source and Path(source).resolve() == target:
            names.append(name)
    return names


def fits_section(fit_dirs: Sequence[str | Path], simulated: Mapping = {}) -> Section:
    """The "Fitted parameters" section (module docstring).

    ``simulated``: the report's simulated datasets by name.

    Parameters
    ----------
    fit_dirs : sequence of str or Path
        The ``--out`` folders of ``simulate fit``, one table each.
    simulated : mapping, default {}
        The report's simulated datasets by name; those evaluated at a fit's parameters are named
        under its table.

    Returns
    -------
    Section
        The section, placed before the normalisation section.

    Raises
    ------
    CompareError
        When a folder holds no readable fit (:func:`read_fit`).
    """
    e = html.escape
    parts = ["<h2>Fitted parameters</h2><p>Each model below was fitted to the measurement by "
             "<code>simulate fit</code> (objective NRMSE^2 + w_c (dh^2 + ds^2), the figures "
             "compare reports; uncertainties: standard, the measurement's u_beta and the model's "
             "Monte Carlo error propagated through the whole objective, linearised at the "
             "solution; the manual's page \"Fit parameters\", docs/how-to/fit.md, says how to read them). 'config value' and 'before' are the start config's value and figures; the search itself may start elsewhere (a --dye knots fit starts from the knots inverted from the measured colour: the start note says so).</p>"]
    for fit_dir in map(Path, fit_dirs):
        doc = read_fit(fit_dir)
        info = doc.get("info") or {}
        method = str(doc.get("method", "?"))
        parts.append(
            f"<h3>{e(method)} model, fitted (<code>{e(str(fit_dir))}</code>)</h3><p>start config "
            f"{e(str(doc.get('config', '?')))}; before {e(_figures(doc.get('start') or {}))}; "
            f"fitted {e(_figures(doc.get('fitted') or {}))}; {e(str(info.get('evaluations', '?')))} "
            f"evaluations (budget {e(str(info.get('max_evaluations', '?')))}), "
            f"{e(str(info.get('walks', '?')))} Monte Carlo walks, {_num(info.get('seconds'), 3)} s."
            + (f" Start: {e(str(info['start_note']))}." if info.get("start_note") else "") + "</p>")
        rows = []
        for p in doc["parameters"]:
            rows.append(f"<tr><td class='l'><code>{e(str(p.get('name')))}</code></td>"
                        f"<td>{_num(p.get('start'))}</td><td><b>{_num(p.get('value'))}</b></td>"
                        + (f"<td colspan='3'>{e(str(p['u_status']))}: no uncertainty</td>" if p.get("u_status") else
                           f"<td>{_num(p.get('u'), 2)}</td><td>{_num(p.get('u_data'), 2)}</td>"
                           f"<td>{_num(p.get('u_mc'), 2)}</td>")
                        + f"<td>[{_num(p.get('low'))}, {_num(p.get('high'))}]</td></tr>")
        parts.append("<table><tr><th class='l'>parameter</th><th>config value</th><th>fitted</th>"
                     "<th>u</th><th>u (data)</th><th>u (Monte Carlo)</th><th>bounds</th></tr>"
                     + "".join(rows) + "</table>")
        rule = doc.get("uncertainty") or {}
        if rule.get("data") == "residual":
            parts.append(f"<p>{e(str(rule.get('rule', '')))}"
                         + (f"; s^2 = {_num(rule.get('s2'), 3)} ({e(str(rule.get('dof')))} degrees of freedom)."
                            if rule.get("s2") is not None else ": no degree of freedom left, no u.") + "</p>")
        notes = [str(w) for w in doc.get("warnings") or []] + [str(n) for n in info.get("notes") or []]
        if notes:
            parts.append("<p>Warnings of the fit:</p><ul>" + "".join(f"<li>{e(n)}</li>" for n in notes)
                         + "</ul>")
        for name in _made_from(fit_dir, simulated):
            parts.append(f"<p>'{e(name)}' is evaluated at these fitted parameters "
                         f"(<code>{e(str(fit_dir / 'fitted.toml'))}</code>): no fit of its own; "
                         "its parameters and their uncertainties are the ones above.</p>")
    return Section("fits", "\n".join(parts), before="normalisation")
