"""The report's words: dataset summaries, number formatting, banners.

The summaries carry no link URLs or temporary ports; the banners flag incomplete data and a
dataset compared with itself.
"""

from __future__ import annotations

import html
import math

from ..comparison import Comparison

__all__ = ["banners", "fmt", "sample_summary", "source_summary"]


def source_summary(ds) -> str:
    """A readable one-line summary of what produced ``ds`` (no link URLs or temporary ports).

    Parameters
    ----------
    ds : Dataset
        The dataset.

    Returns
    -------
    str
        Its instrument or model, plan, seed, completeness and software, ``"; "``-joined; ``"-"``
        when its meta says none of them.
    """
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


def sample_summary(ds) -> str:
    """The sample of a dataset in words: its name and its meta's simple fields.

    Parameters
    ----------
    ds : Dataset
        The dataset.

    Returns
    -------
    str
        The sample's name (the dataset's without one), then its fields in parentheses.
    """
    sample = ds.meta.get("sample") if isinstance(ds.meta.get("sample"), dict) else {}
    fields = [f"{k}: {v}" for k, v in sample.items()
              if k != "name" and isinstance(v, (str, int, float))]
    return str(sample.get("name", ds.name)) + (f" ({'; '.join(fields)})" if fields else "")


def fmt(x, digits: int = 4) -> str:
    """A figure for the page: ``digits`` significant digits, ``-`` for None or a non-finite value.

    Parameters
    ----------
    x : float, None or object
        The figure; anything else is shown as its escaped text.
    digits : int, default 4
        Significant digits of a float.

    Returns
    -------
    str
        The text, HTML-escaped.
    """
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}g}" if math.isfinite(x) else "-"
    return html.escape(str(x))


def banners(comparison: Comparison) -> list[str]:
    """The page's warnings: incomplete data, and a simulation that is the measurement itself.

    Parameters
    ----------
    comparison : Comparison
        The comparison.

    Returns
    -------
    list of str
        One plain-text warning each; empty when there is none.
    """
    from ..comparison import incomplete_datasets, same_dataset

    out = [f"Incomplete data: {line}. Curves and colours cover only what was measured."
           for line in incomplete_datasets(comparison.measured, comparison.simulated.values())]
    for name, ds in comparison.simulated.items():
        same = same_dataset(comparison.measured, ds)
        if same:
            out.append(f"'{name}' is the measured dataset itself ({same}): every figure agrees "
                       "trivially.")
    return out
