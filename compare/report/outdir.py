"""Where a report may be written: the output-folder policy.

``write_report`` writes only into a new or empty folder or over a previous report (recognised by
the ``<meta name="generator">`` of its ``report.html``; only that report's files are replaced, its
figures that the new one does not draw removed); any other non-empty folder needs ``force``.
"""

from __future__ import annotations

import html
import logging
import re
from pathlib import Path

from ..errors import CompareError

__all__ = ["GENERATOR", "prepare_out_dir"]

log = logging.getLogger("compare.report")

#: ``<meta name="generator">`` of every report: how a folder holding a previous report is known.
GENERATOR = "fabric-optics compare report"


_PREVIOUS_FILES = re.compile(r"<meta name='report-files' content='([^']*)'>")
_LEGACY_FIGURES = re.compile(r"<img alt='([A-Za-z0-9_.-]+\.png)' src='data:image/png")


def prepare_out_dir(out: Path, force: bool) -> list[Path]:
    """Check that ``out`` may receive a report; return the previous report's figure files.

    ``out`` may be missing, empty, or hold a previous report (its ``report.html`` names this
    generator): then only the previous report's own files are replaced or removed. Any other
    non-empty folder is refused unless ``force`` (then same-named files are replaced).

    Parameters
    ----------
    out : Path
        The report's folder.
    force : bool
        Write into a non-empty folder that holds no previous report.

    Returns
    -------
    list of Path
        The figure files of the previous report in ``out`` (empty when there is none).

    Raises
    ------
    CompareError
        When ``out`` is not a folder, or is a non-empty folder without a previous report and
        ``force`` is not given.
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
        # a report without the generator tag (an older layout): its figures are named by img alt
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
