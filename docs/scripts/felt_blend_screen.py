r"""Screen the felt opposition scan's variants for the felt's red-larger opposition peak and its colour.

Does a blend of differently dyed fibres, or a dye placed in a ring or a core, give the felt's
red-larger opposition peak and its peaks' colour against the body's? A screen of
``felt_opposition_scan.py``'s runs.

    python docs/scripts/felt_opposition_scan.py --only preset,red-clear,red-x10,blend-red,blend-red-x4,blend-red-x2,ring-1.5,core-4.1 \
        --seeds 4 --out DIR/scan.json
    python docs/scripts/felt_blend_screen.py DIR/scan.json --json DIR/felt-blend-screen.json

For each variant of the scan (the preset, two single populations whose red differs from the preset's, their blends
traced as ``simulate fabric`` traces a blend, the dye in a ring or a core) and each order (``single``: one fibre
event, ``all``), at the file's incidences 27.76 and 40.03 deg:

* ``ratio``: the opposition ratio ``beta(ring 6 deg) / beta(ring 30 deg)`` at 550 and 650 nm, the rings pooled over
  the seeds (:func:`compare.ratios.opposition_ratios`' rings);
* ``red_excess``: ``ratio(650) - ratio(550)`` of each seed's own run (the two bands share the run's rays, so most of
  the noise cancels), its mean over the seeds and the standard error of that mean from their spread: the file's
  red-larger peak is a positive value;
* ``peak_rg``: the peak's colour, ``(ring_6 - ring_30)`` at 650 over 550 nm; ``body_rg``: ``ring_30`` at 650 over 550
  nm; ``untie``: ``peak_rg / body_rg`` (the file's peaks are less green than its body: above 1).

``mix-<a>-<b>`` is the single scattering of a 50/50 blend of two single-population variants, formed exactly by mixing
their runs by share seed by seed (the same felts and seeds; a blend's single scattering is the share-weighted mix of
its populations'); its all-orders row is the same mix of the all-orders runs, a patchwork of two felts rather than a
blend of fibres (a blend's higher orders meet both populations on one path: the traced ``blend-*`` rows).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

INCIDENCES = ("27.76", "40.03")
#: the scan's bands: 450, 550, 650 nm
GREEN, RED = 1, 2
#: the single-population variants mixed 50/50 (the scan's names)
MIXES = (("red-clear", "red-x10"),)


def _rings(run: dict, order: str, ti: str) -> tuple[np.ndarray, np.ndarray]:
    """One run's rings ``(ring_6, ring_30)`` of an order at an incidence, as arrays over the bands."""
    x = run["orders"][order]["incidences"][ti]
    return np.asarray(x["ring_6"], float), np.asarray(x["ring_30"], float)


def metrics(seeds: list[dict[str, tuple[np.ndarray, np.ndarray]]]) -> dict[str, Any]:
    """The screen's figures of one variant and order from each seed's rings ``{ti: (ring_6, ring_30)}``.

    Parameters
    ----------
    seeds : list of dict
        One entry per seed: for each incidence of :data:`INCIDENCES`, the rings at 6 and 30 deg as
        arrays over the scan's bands (450, 550, 650 nm).

    Returns
    -------
    dict
        Per incidence: the pooled ratios at 550 and 650 nm, the mean red excess and its standard error
        (None from one seed), the peak's and the body's red over green, and their quotient (``untie``).
    """
    out: dict[str, Any] = {}
    for ti in INCIDENCES:
        r6 = np.mean([s[ti][0] for s in seeds], axis=0)
        r30 = np.mean([s[ti][1] for s in seeds], axis=0)
        excess = np.array([s[ti][0][RED] / s[ti][1][RED] - s[ti][0][GREEN] / s[ti][1][GREEN] for s in seeds])
        peak = r6 - r30
        out[ti] = {"ratio_550": float(r6[GREEN] / r30[GREEN]), "ratio_650": float(r6[RED] / r30[RED]),
                   "red_excess": float(excess.mean()),
                   "u_red_excess": float(excess.std(ddof=1) / math.sqrt(excess.size)) if excess.size > 1 else None,
                   "peak_rg": float(peak[RED] / peak[GREEN]), "body_rg": float(r30[RED] / r30[GREEN]),
                   "untie": float(peak[RED] / peak[GREEN] / (r30[RED] / r30[GREEN]))}
    return out


def screen(scan: dict) -> dict[str, Any]:
    """The screen's table from a ``felt_opposition_scan.py`` result (its ``data`` part).

    Parameters
    ----------
    scan : dict
        The scan's JSON document, or its ``data`` part.

    Returns
    -------
    dict
        The scan's settings and the rows: the file's, one per variant (both orders) and one per mix of
        :data:`MIXES` whose two variants the scan holds (over the seeds they share).
    """
    data = scan.get("data", scan)
    file = {ti: (np.asarray(x["ring_6"], float), np.asarray(x["ring_30"], float))
            for ti, x in data["file"]["incidences"].items()}
    rows: dict[str, Any] = {"the file": {"all": metrics([file]), "seeds": 0}}
    by_name = {v["name"]: v for v in data["variants"]}
    for name, v in by_name.items():
        row: dict[str, Any] = {"seeds": len(v["runs"]), "label": v["label"]}
        for order in ("single", "all"):
            row[order] = metrics([{ti: _rings(run, order, ti) for ti in INCIDENCES} for run in v["runs"]])
        rows[name] = row
    for a, b in MIXES:
        if a not in by_name or b not in by_name:
            continue
        runs_a = {run["seed"]: run for run in by_name[a]["runs"]}
        runs_b = {run["seed"]: run for run in by_name[b]["runs"]}
        common = sorted(set(runs_a) & set(runs_b))
        row = {"seeds": len(common), "label": f"50/50 of {a} and {b}, mixed from their runs"}
        for order in ("single", "all"):
            row[order] = metrics([{ti: tuple(0.5 * x + 0.5 * y for x, y in zip(_rings(runs_a[s], order, ti),
                                                                                 _rings(runs_b[s], order, ti),
                                                                                 strict=True))
                                   for ti in INCIDENCES} for s in common])
        rows[f"mix-{a}-{b}"] = row
    return {"settings": data.get("settings"), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    """Read a scan's result, print the screen's rows and write them as JSON.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (the scan's JSON, ``--json``); ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0, or 2 when the file is not a scan's result (one line says so).
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scan", type=Path, help="a felt_opposition_scan.py result")
    ap.add_argument("--json", type=Path, help="write the table here")
    args = ap.parse_args(argv)
    try:
        scan = json.loads(args.scan.read_text())
        result = screen(scan)
    except (OSError, ValueError, KeyError) as exc:
        print(f"felt_blend_screen: {args.scan}: not a felt_opposition_scan.py result ({exc})", file=sys.stderr)
        return 2
    for name, row in result["rows"].items():
        for order in ("single", "all"):
            if order not in row:
                continue
            cells = []
            for ti in INCIDENCES:
                m = row[order][ti]
                u = "" if m["u_red_excess"] is None else f" ± {m['u_red_excess']:.3f}"
                cells.append(f"{ti}: {m['ratio_550']:.3f}/{m['ratio_650']:.3f} red {m['red_excess']:+.3f}{u} "
                             f"peak {m['peak_rg']:.2f} body {m['body_rg']:.2f}")
            print(f"{name:28s} {order:6s} " + " | ".join(cells))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
