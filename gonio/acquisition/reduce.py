"""Reduction of a journal to the measured dataset: the radiance factor of every journaled reading.

Each point uses the calibration it was measured with; a geometry journaled twice keeps its first
record; points of an invalid calibration are left out (:func:`usable_points`). The radiance
factor and its uncertainty come from the measurement equation
(:func:`gonio.acquisition.calibration.radiance_factor`), so a dataset can always be rebuilt from
its journal, and a resumed run and an uninterrupted run with the same mock seed write identical
``radiance.csv``.

Retry counts survive a killed session: every ``calibration`` and ``point`` record carries the
session's cumulative retry counter (``retries``) at its checkpoint. The meta's ``retries`` sum,
over the sessions (a ``start`` record or a ``resume`` event opens one), each session's last
snapshot - its ``session_end`` counts when it ended, else those of its last checkpoint (retries
spent on a point that was never journaled are lost with that point). ``sessions`` counts every
session, killed ones included. A journal whose records carry no snapshots sums its
``session_end`` events.
"""

from __future__ import annotations

import datetime as _dt
from importlib import metadata

import numpy as np
import pandas as pd

from gonio.acquisition.calibration import WhiteStandard, calibration_problem, radiance_factor
from gonio.acquisition.plan import Plan, Procedure
from gonio.data import Dataset, make_dataset, new_meta
from gonio.instrument.head_commands import GAIN_FACTORS

__all__ = ["dataset_from_journal", "usable_points", "retry_totals", "point_key", "point_beta"]


def _versions() -> dict:
    from gonio.version import commit

    out: dict = {"commit": commit()}
    for dist in ("fabric-optics", "pymodbus", "pyserial", "numpy"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def _iso(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.UTC).isoformat(timespec="seconds")


def point_key(point: dict) -> tuple[float, ...]:
    """The geometry key ``(theta_i, phi_i, theta_o, phi_o)`` of a journaled point, rounded."""
    return tuple(round(float(x), 6) for x in point["geometry"])


def usable_points(records: list[dict]) -> list[dict]:
    """The journal's point records whose calibration is valid.

    Validity is :func:`gonio.acquisition.calibration.calibration_problem`'s; the points of an
    invalid calibration are measured again on resume.
    """
    invalid = {r["id"] for r in records if r["type"] == "calibration"
               and calibration_problem(r["darks"], r["reference"]) is not None}
    return [r for r in records if r["type"] == "point" and r["calibration"] not in invalid]


def point_beta(point: dict, calibration: dict, standard: WhiteStandard,
               reference_deg=(0.0, 45.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(wavelength_nm, beta, u_beta)`` of one journaled point against the calibration it names.

    The measurement equation of :func:`dataset_from_journal`, for one point record as it arrives
    (the live view, :mod:`gonio.acquisition.live`): each reading against the dark at its own
    ranging step and the white standard at its wavelength. ``reference_deg`` is the plan's, used
    when the calibration record does not carry its own.
    """
    darks = {(d["itime_ms"], d["gain"]): d for d in calibration["darks"]}
    refs = {float(r["wavelength_nm"]): r for r in calibration["reference"]}
    to_ref = abs(float(calibration.get("reference_deg", reference_deg)[1]))
    theta_o = float(point["geometry"][2])
    rows = []
    for r in point["readings"]:
        wl = float(r["wavelength_nm"])
        ref = refs[wl]
        d, dr = darks[(r["itime_ms"], r["gain"])], darks[(ref["itime_ms"], ref["gain"])]
        rows.append((wl, r["mean"], r["sem"], d["mean"], d["sem"], r["itime_ms"], GAIN_FACTORS[r["gain"]],
                     ref["mean"], ref["sem"], dr["mean"], dr["sem"], ref["itime_ms"], GAIN_FACTORS[ref["gain"]]))
    c = np.asarray(rows, dtype=float).reshape(-1, 13).T
    beta_ref, u_beta_ref = standard.at(c[0])
    beta, u_beta = radiance_factor(c[1], c[2], c[3], c[4], c[5], c[6], theta_o, c[7], c[8], c[9], c[10],
                                   c[11], c[12], to_ref, beta_ref, u_beta_ref)
    return c[0], np.asarray(beta, dtype=float), np.asarray(u_beta, dtype=float)


def dataset_from_journal(records: list[dict], plan: Plan, standard: WhiteStandard, *,
                         seed: int | None = None, links: dict | None = None,
                         firmware: str = "", complete: bool = False,
                         created: str | None = None) -> Dataset:
    """Build the measured dataset from journal records (see the module docstring).

    Each point uses the calibration it was measured with; a geometry journaled twice keeps its
    first record; points of an invalid calibration are left out (:func:`usable_points`).
    Returns a :class:`gonio.data.Dataset`.
    """
    cals = {r["id"]: r for r in records if r["type"] == "calibration"}
    start = next(r for r in records if r["type"] == "start")
    seen: set[tuple[float, ...]] = set()
    cols: dict[str, list] = {k: [] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm",
                                         "S", "uS", "D", "uD", "t", "G", "Sr", "uSr", "Dr",
                                         "uDr", "tr", "Gr", "n", "to_ref")}
    saturated = []
    for rec in usable_points(records):
        key = point_key(rec)
        if key in seen:
            continue
        seen.add(key)
        cal = cals[rec["calibration"]]
        darks = {(d["itime_ms"], d["gain"]): d for d in cal["darks"]}
        refs = {float(r["wavelength_nm"]): r for r in cal["reference"]}
        to_ref = abs(float(cal.get("reference_deg", plan.reference_deg)[1]))
        for sat in rec.get("saturated_nm", []):
            saturated.append(list(key) + [sat])
        for r in rec["readings"]:
            wl = float(r["wavelength_nm"])
            ref = refs[wl]
            d = darks[(r["itime_ms"], r["gain"])]
            dr = darks[(ref["itime_ms"], ref["gain"])]
            for name, v in zip(("theta_i", "phi_i", "theta_o", "phi_o"), key, strict=True):
                cols[name].append(v)
            cols["wavelength_nm"].append(wl)
            cols["S"].append(r["mean"]); cols["uS"].append(r["sem"])
            cols["D"].append(d["mean"]); cols["uD"].append(d["sem"])
            cols["t"].append(r["itime_ms"]); cols["G"].append(GAIN_FACTORS[r["gain"]])
            cols["Sr"].append(ref["mean"]); cols["uSr"].append(ref["sem"])
            cols["Dr"].append(dr["mean"]); cols["uDr"].append(dr["sem"])
            cols["tr"].append(ref["itime_ms"]); cols["Gr"].append(GAIN_FACTORS[ref["gain"]])
            cols["n"].append(r["n"])
            cols["to_ref"].append(to_ref)
    c = {k: np.asarray(v, dtype=float) for k, v in cols.items()}
    beta_ref, u_beta_ref = standard.at(c["wavelength_nm"])
    beta, u_beta = radiance_factor(c["S"], c["uS"], c["D"], c["uD"], c["t"], c["G"], c["theta_o"],
                                   c["Sr"], c["uSr"], c["Dr"], c["uDr"], c["tr"], c["Gr"],
                                   c["to_ref"], beta_ref, u_beta_ref)
    table = pd.DataFrame({"theta_i": c["theta_i"], "phi_i": c["phi_i"], "theta_o": c["theta_o"],
                          "phi_o": c["phi_o"], "wavelength_nm": c["wavelength_nm"], "beta": beta,
                          "u_beta": u_beta, "n": c["n"].astype(int)})
    retries, sessions = retry_totals(records)
    check = plan.check()
    links = links or {}
    meta = new_meta(
        "measured", sample=plan.sample,
        source={"idn": cals[max(cals)]["idn"] if cals else "", "firmware": firmware,
                "modbus": links.get("modbus"), "serial": links.get("serial")},
        provenance={
            "plan": {"name": plan.name, "sha256": plan.sha256, "description": plan.description},
            "seed": seed,
            "white_standard": {"name": standard.name, "sha256": standard.sha256},
            "reference_deg": list(plan.reference_deg),
            "acquisition": {k: getattr(plan.acquisition, k) for k in plan.acquisition.__dataclass_fields__},
            "points_planned": len(check.ordered), "points_measured": len(seen),
            "complete": bool(complete),
            "unmeasurable": [list(p.key) for p in check.blocked]
                            + [list(p.key) for p, _ in check.out_of_limits],
            "saturated": saturated,
            "retries": dict(sorted(retries.items())),
            "sessions": sessions,
            "calibrations": sorted(cals),
            "versions": _versions(),
            # only a procedure other than the default is recorded (older datasets stay as they are)
            **({"procedure": {"steps": list(plan.procedure.steps),
                              "recalibrate_every": plan.procedure.recalibrate_every}}
               if plan.procedure != Procedure() else {}),
        },
        created=created or _iso(float(start["time"])))
    return make_dataset(table, meta)


def retry_totals(records: list[dict]) -> tuple[dict[str, int], int]:
    """``(retries summed over the sessions, number of sessions)`` of a journal.

    A ``start`` record or a ``resume`` event opens a session; a session's counts are its last
    snapshot (``retries`` of its ``session_end`` event, or of its last ``calibration`` or
    ``point`` record when it was killed). See the module docstring.
    """
    snapshots: list[dict] = []
    for r in records:
        kind, what = r["type"], r.get("what")
        if kind == "start" or (kind == "event" and what == "resume"):
            snapshots.append({})
            continue
        if not snapshots or not isinstance(r.get("retries"), dict):
            continue
        if kind in ("calibration", "point") or (kind == "event" and what == "session_end"):
            snapshots[-1] = r["retries"]
    totals: dict[str, int] = {}
    for snap in snapshots:
        for k, v in snap.items():
            totals[k] = totals.get(k, 0) + int(v)
    return dict(sorted(totals.items())), len(snapshots)
