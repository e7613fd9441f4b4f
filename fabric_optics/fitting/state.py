"""What an interrupted ``simulate fit`` leaves behind: the walk checkpoint and the state file.

Walk checkpoint
---------------
Every (incident direction, wavelength group) run of every Monte Carlo walk of the fit is written,
as soon as it is finished, to ``DIR/walks/RUNKEY.npz`` (atomically: a temporary file renamed), with
``RUNKEY`` a hash of everything the run depends on: the fit's identity (config, measurement,
method, free parameters, seed, wavelengths), the walked parameters' values, the absorption nodes,
the run's index and its photon rule (accuracy-controlled, or the fixed photons of the first walk).
A walk asks the checkpoint first, so ``--resume`` after Ctrl-C in the middle of the first walk
(the expensive one: minutes on a real plan) continues at the next run instead of walking again,
and gives the same table as an uninterrupted fit (same seeds, same accuracy control). A run
costs 10-100 kB; the checkpoint is kept after the fit (a re-run with ``--resume`` reads it) and can
be deleted at any time.

State file
----------
``DIR/fit-state.json``: the last accepted point (see :mod:`fabric_optics.fitting.driver`); ``DIR/mc-state.json``: the
Monte Carlo fit's finished runs (:mod:`fabric_optics.fitting.mc`).

``--resume`` trusts neither blindly (:func:`read_state_json`, :func:`check_point`): the file must be a
regular file (a symbolic link to one is followed; a FIFO, device or directory is refused without being
opened for a blocking read) of at most :data:`MAX_STATE_BYTES`, hold a JSON object of nesting at most
:data:`MAX_DEPTH` levels and a finite number of the right kind in every field that needs one (NaN is
accepted only where a run records a figure it could not compute), and its point must have one finite
value per free parameter, inside the parameter's bounds. A state that breaks any of these
is refused with one line naming the file and the field (exit 2): a value out of bounds is not clamped
and a malformed one is not replaced by the start, since either would resume a fit the file does not
describe. Deleting the file (or running without ``--resume``) starts afresh.

Writes
------
Every file is written to a temporary file beside it and renamed. A write that fails (a full disk)
removes its temporary file and is one :class:`~fabric_optics.fitting.problem.FitError` line naming the file; what
was written before stays (``--resume`` continues from it).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import stat
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["WALKS_DIR", "refuse", "MAX_STATE_BYTES", "MAX_DEPTH", "MAX_RUN_PHOTONS", "WalkCheckpoint", "write_json_atomic",
           "read_state_json", "check_point", "check_number", "check_photons", "write_failed", "remove_quietly"]

WALKS_DIR = "walks"
#: the largest state file ``--resume`` reads (a fit's state is a few kB; a Monte Carlo fit's tens of kB)
MAX_STATE_BYTES = 1_000_000
#: the deepest nesting of lists and objects a state file may have (a fit's state has 4 levels)
MAX_DEPTH = 16
#: the most photons one recorded run may ask for on resume: the default budget ``100 / target^2`` of a
#: target of 0.0003, far tighter than any fit's (a fit's runs are capped by that budget of their target)
MAX_RUN_PHOTONS = 10**9


def remove_quietly(path: Path) -> None:
    """Remove ``path`` if it is there (a temporary file after a failed write)."""
    try:
        os.unlink(path)
    except OSError:
        pass


def write_failed(path: Path, exc: OSError) -> str:
    """One line for a state or checkpoint file that could not be written."""
    return (f"{path}: cannot write ({exc.strerror or exc}); what the fit saved before is kept: free space (or "
            "choose another --out) and continue with --resume")


def write_json_atomic(path: Path, doc: dict) -> None:
    """``doc`` as JSON at ``path``, written to a temporary file, fsynced and renamed. A failed write
    (a full disk) leaves no temporary file and raises :class:`~fabric_optics.fitting.problem.FitError`."""
    from fabric_optics.fitting.errors import FitError

    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        remove_quietly(tmp)
        raise FitError(write_failed(path, exc)) from None
    except BaseException:
        remove_quietly(tmp)
        raise


def refuse(path: Path, what: str) -> None:
    from fabric_optics.fitting.errors import FitError

    raise FitError(f"--resume: {path}: {what}; delete the file or run without --resume to start afresh")


def _depth(doc: Any, limit: int) -> int:
    """The nesting depth of ``doc`` (iterative: a deep document cannot exhaust the stack), at most ``limit + 1``."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        item, d = stack.pop()
        if isinstance(item, (list, dict)):
            deepest = max(deepest, d)
            if deepest > limit:
                return deepest
            stack.extend((v, d + 1) for v in (item.values() if isinstance(item, dict) else item))
    return deepest


def read_state_json(path: Path) -> dict | None:
    """The JSON object in the state file ``path`` (module docstring), None if there is none; refuses
    anything else with :class:`~fabric_optics.fitting.problem.FitError` naming the file."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        if os.path.islink(path):
            refuse(path, f"is a symbolic link to a missing target ({os.readlink(path)})")
        return None
    except OSError as exc:
        refuse(path, f"cannot be opened ({exc.strerror})")
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a directory" if stat.S_ISDIR(st.st_mode)
                    else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file")
            refuse(path, f"is {kind}{' (through a symbolic link)' if os.path.islink(path) else ''}, not a state file")
        if st.st_size > MAX_STATE_BYTES:
            refuse(path, f"is {st.st_size:,} bytes, more than a state file's limit of {MAX_STATE_BYTES:,}")
        with os.fdopen(fd, "rb") as fh:
            fd = -1
            raw = fh.read(MAX_STATE_BYTES + 1)
    except OSError as exc:
        refuse(path, f"cannot be read ({exc.strerror})")
    finally:
        if fd >= 0:
            os.close(fd)
    if len(raw) > MAX_STATE_BYTES:
        refuse(path, f"holds more than a state file's limit of {MAX_STATE_BYTES:,} bytes")
    try:
        doc = json.loads(raw.decode("utf-8"))
    except RecursionError:
        refuse(path, f"is nested deeper than a state file's {MAX_DEPTH} levels")
    except (UnicodeDecodeError, ValueError) as exc:
        refuse(path, f"is not valid JSON ({exc})")
    if not isinstance(doc, dict):
        refuse(path, f"holds a JSON {type(doc).__name__ if doc is not None else 'null'}, not the state's object")
    if _depth(doc, MAX_DEPTH) > MAX_DEPTH:
        refuse(path, f"is nested deeper than a state file's {MAX_DEPTH} levels")
    return doc


def check_number(path: Path, field: str, value: Any, *, low: float = -math.inf, high: float = math.inf,
                 integer: bool = False, allow_nan: bool = False) -> float:
    """``value`` as a number in ``[low, high]`` (finite unless ``allow_nan`` lets NaN through), or refuse it
    naming ``path`` and ``field``."""
    kind = "an integer" if integer else "a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        refuse(path, f"field {field!r} is {json.dumps(value)[:40]}, not {kind}")
    v = float(value) if not integer else value
    if isinstance(v, float) and math.isnan(v) and allow_nan:
        return v
    if isinstance(v, float) and not math.isfinite(v):
        refuse(path, f"field {field!r} is {v}, not a finite number")
    if not low <= v <= high:
        refuse(path, f"field {field!r} is {v:g}, outside [{low:g}, {high:g}]")
    return float(v)


def check_point(path: Path, field: str, value: Any, names: list[str], low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``value`` as a point of the free parameters ``names``: one finite number each, inside its bounds
    (not clamped: a point outside is refused naming ``path``, ``field`` and the parameter)."""
    if not isinstance(value, list):
        refuse(path, f"field {field!r} is {json.dumps(value)[:40]}, not a list of {len(names)} number(s)")
    if len(value) != len(names):
        refuse(path, f"field {field!r} has {len(value)} entries; this fit has {len(names)} free parameter(s) "
                      f"({', '.join(names)})")
    x = np.empty(len(names))
    for j, (v, name, lo, hi) in enumerate(zip(value, names, low, high)):
        x[j] = check_number(path, f"{field}[{j}] ({name})", v, low=float(lo), high=float(hi))
    return x


def check_photons(path: Path, field: str, value: Any) -> dict | None:
    """The recorded photons of a state: None, or an object of run keys to photon counts (at most
    :data:`MAX_RUN_PHOTONS` a run)."""
    if value is None:
        return None
    if not isinstance(value, dict):
        refuse(path, f"field {field!r} is {json.dumps(value)[:40]}, not an object of photon counts")
    for key, n in value.items():
        check_number(path, f"{field}.{key}"[:60], n, low=0 if key in ("exit_tables", "per_row") else 1,
                     high=MAX_RUN_PHOTONS if ":" in key else 10**15, integer=True)
    return dict(value)


class WalkCheckpoint:
    """The runs of one walk on disk (:class:`simulate.fiber.absorption.RunCache`; module docstring)."""

    def __init__(self, out: Path, identity: str, walk: tuple, nodes: np.ndarray, photons: dict | None):
        self.dir = Path(out) / WALKS_DIR
        self._base = json.dumps([identity, list(walk), np.asarray(nodes, float).round(12).tolist()])
        self._photons = photons
        self.found = 0

    def _path(self, key: str) -> Path:
        rule = "controlled" if self._photons is None else self._photons.get(key)
        digest = hashlib.sha256(json.dumps([self._base, key, rule]).encode()).hexdigest()[:24]
        return self.dir / f"{digest}.npz"

    def get(self, key: str) -> tuple[np.ndarray, np.ndarray, int, float] | None:
        path = self._path(key)
        try:
            with np.load(path) as z:
                found = (z["value"].copy(), z["u"].copy(), int(z["photons"]), float(z["scatterings"]))
        except (OSError, ValueError, KeyError):
            return None
        self.found += 1
        return found

    def put(self, key: str, value: np.ndarray, u: np.ndarray, photons: int, scatterings: float) -> None:
        from fabric_optics.fitting.errors import FitError

        path = self._path(key)
        tmp = path.with_name(f".{path.stem}.tmp.npz")
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            np.savez(tmp, value=value, u=u, photons=np.int64(photons), scatterings=np.float64(scatterings))
            os.replace(tmp, path)
        except OSError as exc:
            remove_quietly(tmp)
            raise FitError(write_failed(path, exc)) from None
        except BaseException:
            remove_quietly(tmp)
            raise

    def count(self) -> int:
        """Runs of any walk on disk."""
        return len(list(self.dir.glob("*.npz"))) if self.dir.is_dir() else 0
