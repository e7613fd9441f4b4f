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
``DIR/fit-state.json``: the last accepted point (see :mod:`fabric_optics.fitting.search`); ``DIR/mc-state.json``: the
Monte Carlo fit's finished runs (:mod:`fabric_optics.fitting.spacemapping`).

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
import logging
import math
import os
import re
import stat
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from fabric_optics.fitting.errors import FitError
from gonio.data.dataset import atomic_write
from simulate.montecarlo.accuracy import BATCH

__all__ = ["WALKS_DIR", "STATE_NAME", "MC_STATE", "MC_RUNS_DIR", "MCRun", "MCState", "load_state", "save_state",
           "left_behind", "refuse", "MAX_STATE_BYTES", "MAX_DEPTH", "MAX_RUN_PHOTONS", "WalkCheckpoint", "write_json_atomic",
           "read_state_json", "check_point", "check_number", "check_photons", "write_failed", "remove_quietly"]

log = logging.getLogger(__name__)

WALKS_DIR = "walks"
#: the state file of a classic or summation fit: its last accepted point
STATE_NAME = "fit-state.json"
STATE_SCHEMA = "simulate-fit-state/1"
#: the Monte Carlo fit's state file and the folder of its runs
MC_STATE = "mc-state.json"
MC_RUNS_DIR = "mc-runs"
MC_SCHEMA = "simulate-fit-mc-state/1"
#: the largest state file ``--resume`` reads (a fit's state is a few kB; a Monte Carlo fit's tens of kB)
MAX_STATE_BYTES = 1_000_000
#: the deepest nesting of lists and objects a state file may have (a fit's state has 4 levels)
MAX_DEPTH = 16
#: the most photons one recorded run may ask for on resume: the default budget ``100 / target^2`` of a
#: target of 0.0003, far tighter than any fit's (a fit's runs are capped by that budget of their target)
MAX_RUN_PHOTONS = 10**9
#: the largest integer any field of a state may hold (counts and photons are far below it)
MAX_INTEGER = 10**18


#: the largest checkpoint file read back (a walk's run or a Monte Carlo run: tens of kB to a few MB on a real plan)
MAX_RUN_BYTES = 64_000_000
#: a member of a checkpoint's zip may expand to at most this many times its stored size (np.savez stores them
#: uncompressed: ratio 1; a deflate bomb expands a thousandfold)
MAX_EXPANSION = 4


def refuse_file(path: Path, what: str) -> NoReturn:
    """One line for a checkpoint file ``--resume`` (or a re-run in the same folder) cannot trust.

    Parameters
    ----------
    path : Path
        The checkpoint file.
    what : str
        What is wrong with it.

    Raises
    ------
    FitError
        Always: the refusal.
    """
    raise FitError(f"{path}: {what}; it is not a checkpoint of this fit: delete it (or run without --resume in "
                   "another --out) to start afresh")


def read_npz(path: Path, arrays: dict[str, tuple[str, int | None]], *,
             max_bytes: int = MAX_RUN_BYTES) -> dict[str, np.ndarray] | None:
    """The arrays of the checkpoint ``path`` (``np.savez``), checked before anything is decompressed or loaded.

    None when there is no such file.

    ``arrays``: name -> ``(dtype kind, ndim)`` (kind ``"f"`` float64, ``"i"`` int64; ndim None: any). Refused with
    one line naming the file (:func:`refuse_file`): not a regular file (a FIFO is not opened for a blocking read),
    more than ``max_bytes``, not a zip of exactly these ``.npy`` members, a member that would expand beyond
    :data:`MAX_EXPANSION` times its stored size or ``max_bytes`` (a deflate bomb), a member of another dtype or
    number of dimensions (read from its header, before its data), a truncated or corrupt file, a value not finite.
    Pickled objects are never loaded (``allow_pickle=False``).

    Parameters
    ----------
    path : Path
        The checkpoint file.
    arrays : dict of str to (str, int or None)
        The arrays it must hold: name -> ``(dtype kind, ndim)``.
    max_bytes : int, default MAX_RUN_BYTES
        Largest size of the file and of each member once expanded (bytes).

    Returns
    -------
    dict of str to numpy.ndarray or None
        The arrays by name, or None when there is no file.

    Raises
    ------
    FitError
        For a file that is not such a checkpoint (:func:`refuse_file`).
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        return None
    except OSError as exc:
        refuse_file(path, f"cannot be opened ({exc.strerror})")
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        refuse_file(path, "is not a regular file (a FIFO, device or folder)")
    with os.fdopen(fd, "rb") as fh:
        if st.st_size > max_bytes:
            refuse_file(path, f"is {st.st_size:,} bytes, more than a checkpoint's limit of {max_bytes:,}")
        try:
            with zipfile.ZipFile(fh) as z:
                members = {i.filename: i for i in z.infolist()}
                want = {f"{name}.npy" for name in arrays}
                if set(members) != want:
                    refuse_file(path, f"holds {sorted(members)[:6]}, not the arrays {sorted(want)}")
                for info in members.values():
                    if info.file_size > max_bytes or info.file_size > MAX_EXPANSION * max(info.compress_size, 1) + 4096:
                        refuse_file(path, f"member {info.filename} would expand to {info.file_size:,} bytes from "
                                          f"{info.compress_size:,} (more than a checkpoint's)")
                out = {}
                for name, (kind, ndim) in arrays.items():
                    with z.open(f"{name}.npy") as member:
                        version = np.lib.format.read_magic(member)
                        if version == (1, 0):
                            shape, _, dtype = np.lib.format.read_array_header_1_0(member)
                        elif version == (2, 0):
                            shape, _, dtype = np.lib.format.read_array_header_2_0(member)
                        else:
                            refuse_file(path, f"array {name!r} has the .npy format {version}, not a checkpoint's")
                        if dtype != np.dtype(f"<{kind}8") or (ndim is not None and len(shape) != ndim):
                            refuse_file(path, f"array {name!r} is {dtype} of shape {shape}, not the checkpoint's "
                                              f"{np.dtype(f'<{kind}8')}" + (f" of {ndim} dimensions" if ndim else ""))
                    with z.open(f"{name}.npy") as member:
                        a = np.lib.format.read_array(member, allow_pickle=False)
                    if not np.all(np.isfinite(a)):
                        refuse_file(path, f"array {name!r} holds values that are not finite")
                    out[name] = a
        except FitError:
            raise
        except (zipfile.BadZipFile, EOFError, ValueError, OSError, KeyError) as exc:
            refuse_file(path, f"is truncated or corrupt ({type(exc).__name__}: {str(exc)[:60]})")
    return out


def remove_quietly(path: Path) -> None:
    """Remove ``path`` if it is there (a temporary file after a failed write).

    Parameters
    ----------
    path : Path
        The file to remove; an error removing it is ignored.
    """
    try:
        os.unlink(path)
    except OSError:
        pass


def write_failed(path: Path, exc: OSError) -> str:
    """One line for a state or checkpoint file that could not be written.

    Parameters
    ----------
    path : Path
        The file.
    exc : OSError
        The error the write raised.

    Returns
    -------
    str
        The line, naming the file and what to do.
    """
    return (f"{path}: cannot write ({exc.strerror or exc}); what the fit saved before is kept: free space (or "
            "choose another --out) and continue with --resume")


def write_json_atomic(path: Path, doc: dict) -> None:
    """Write ``doc`` as JSON at ``path`` with the toolkit's one atomic writer.

    :func:`gonio.data.dataset.atomic_write`: a temporary file, fsynced, the output's claim checked, renamed. A
    failed write (a full disk) leaves no temporary file and raises :class:`~fabric_optics.fitting.errors.FitError`.

    Parameters
    ----------
    path : Path
        The file written.
    doc : dict
        The JSON object.

    Raises
    ------
    FitError
        When the file cannot be written.
    """
    try:
        atomic_write(path, json.dumps(doc, indent=1).encode("utf-8"))
    except OSError as exc:
        raise FitError(write_failed(path, exc)) from None


def refuse(path: Path, what: str) -> None:
    """Raise the ``--resume`` refusal naming ``path`` and what is wrong with it.

    Parameters
    ----------
    path : Path
        The state file.
    what : str
        What is wrong with it.

    Raises
    ------
    FitError
        Always: the refusal.
    """
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
    """The JSON object in the state file ``path`` (module docstring), None if there is none.

    Refuses anything else with :class:`~fabric_optics.fitting.problem.FitError` naming the file.

    Parameters
    ----------
    path : Path
        The state file.

    Returns
    -------
    dict or None
        The object, or None when there is no file.

    Raises
    ------
    FitError
        For a file that is not a regular file, too large, not JSON, not an object or nested too deeply.
    """
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
    """``value`` as a number in ``[low, high]``, or refuse it naming ``path`` and ``field``.

    The number is finite unless ``allow_nan`` lets NaN through.

    Parameters
    ----------
    path : Path
        The state file, named in a refusal.
    field : str
        The field, named in a refusal.
    value : Any
        The field's value as read.
    low, high : float, default -inf, inf
        The bounds, included.
    integer : bool, default False
        Require an integer.
    allow_nan : bool, default False
        Let NaN through.

    Returns
    -------
    float
        The number.

    Raises
    ------
    FitError
        For a value that is not such a number.
    """
    kind = "an integer" if integer else "a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        refuse(path, f"field {field!r} is {json.dumps(value)[:40]}, not {kind}")
    if isinstance(value, int) and abs(value) > MAX_INTEGER:   # a float of it would overflow, or lose digits
        refuse(path, f"field {field!r} is a {len(str(abs(value)))}-digit integer, outside [{low:g}, {high:g}]")
    v = float(value) if not integer else value
    if isinstance(v, float) and math.isnan(v) and allow_nan:
        return v
    if isinstance(v, float) and not math.isfinite(v):
        refuse(path, f"field {field!r} is {v}, not a finite number")
    if not low <= v <= high:
        refuse(path, f"field {field!r} is {v:g}, outside [{low:g}, {high:g}]")
    return float(v)


def check_point(path: Path, field: str, value: Any, names: list[str], low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``value`` as a point of the free parameters ``names``.

    One finite number each, inside its bounds (not clamped: a point outside is refused naming ``path``, ``field``
    and the parameter).

    Parameters
    ----------
    path : Path
        The state file, named in a refusal.
    field : str
        The field, named in a refusal.
    value : Any
        The field's value as read.
    names : list of str
        The free parameters' names.
    low, high : numpy.ndarray
        The free parameters' bounds.

    Returns
    -------
    numpy.ndarray
        The point, one value per free parameter.

    Raises
    ------
    FitError
        For a value that is not a list of one number per parameter inside its bounds.
    """
    if not isinstance(value, list):
        refuse(path, f"field {field!r} is {json.dumps(value)[:40]}, not a list of {len(names)} number(s)")
    if len(value) != len(names):
        refuse(path, f"field {field!r} has {len(value)} entries; this fit has {len(names)} free parameter(s) "
                      f"({', '.join(names)})")
    x = np.empty(len(names))
    for j, (v, name, lo, hi) in enumerate(zip(value, names, low, high, strict=True)):
        x[j] = check_number(path, f"{field}[{j}] ({name})", v, low=float(lo), high=float(hi))
    return x


def check_photons(path: Path, field: str, value: Any) -> dict | None:
    """The recorded photons of a state: None, or an object of run keys to photon counts.

    A run's (key ``d:g``) is whole batches (:data:`simulate.montecarlo.accuracy.BATCH`: every round of the accuracy
    control is) below :data:`MAX_RUN_PHOTONS`; the structured walk's photons per row (``per_row``) at least 1 and
    below it, its ``exit_tables`` total at most 10^15.

    Parameters
    ----------
    path : Path
        The state file, named in a refusal.
    field : str
        The field, named in a refusal.
    value : Any
        The field's value as read.

    Returns
    -------
    dict or None
        Run key -> photons (a copy), or None.

    Raises
    ------
    FitError
        For a value that is not such an object.
    """
    if value is None:
        return None
    if not isinstance(value, dict):
        refuse(path, f"field {field!r} is {json.dumps(value)[:40]}, not an object of photon counts")
    if len(value) > 100_000:
        refuse(path, f"field {field!r} lists {len(value)} runs, more than a fit walks")
    for key, n in value.items():
        where = f"{field}.{key}"[:60]
        if key == "exit_tables":
            check_number(path, where, n, low=0, high=10**15, integer=True)
        elif key == "per_row":
            check_number(path, where, n, low=1, high=MAX_RUN_PHOTONS - 1, integer=True)
        else:
            check_number(path, where, n, low=BATCH, high=MAX_RUN_PHOTONS - 1, integer=True)
            if n % BATCH:
                refuse(path, f"field {where!r} is {n}, not whole batches of {BATCH} photons (a run's)")
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
        """Run ``key`` from the checkpoint (:func:`read_npz`: a file that is there but not a run is refused).

        Parameters
        ----------
        key : str
            The run's key (module docstring).

        Returns
        -------
        tuple or None
            ``(value, u, photons, scatterings)`` of the run, or None when the checkpoint does not hold it.

        Raises
        ------
        FitError
            For a file that is not a run.
        """
        path = self._path(key)
        z = read_npz(path, {"value": ("f", None), "u": ("f", None), "photons": ("i", 0), "scatterings": ("f", 0)})
        if z is None:
            return None
        if z["value"].shape != z["u"].shape:
            refuse_file(path, f"holds a value of shape {z['value'].shape} and its u of {z['u'].shape}")
        photons = int(z["photons"])
        if not BATCH <= photons < MAX_RUN_PHOTONS:
            refuse_file(path, f"records {photons} photons, not a run's ({BATCH} to {MAX_RUN_PHOTONS - 1})")
        self.found += 1
        return z["value"], z["u"], photons, float(z["scatterings"])

    def put(self, key: str, value: np.ndarray, u: np.ndarray, photons: int, scatterings: float) -> None:
        """Store a walk's values under ``key`` (atomically: an interrupt leaves the old file or the new one).

        Parameters
        ----------
        key : str
            The run's key (module docstring).
        value, u : numpy.ndarray
            The run's values and their standard uncertainties.
        photons : int
            The photons walked.
        scatterings : float
            The scattering events counted.

        Raises
        ------
        FitError
            When the file cannot be written.
        """
        path = self._path(key)
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            atomic_write(path, lambda fh: np.savez(fh, value=value, u=u, photons=np.int64(photons),
                                                   scatterings=np.float64(scatterings)))
        except OSError as exc:
            raise FitError(write_failed(path, exc)) from None

    def count(self) -> int:
        """Runs of any walk on disk."""
        return len(list(self.dir.glob("*.npz"))) if self.dir.is_dir() else 0


# ------------------------------------------------------------------------------------------
# the state of a classic or summation fit


def load_state(out: Path, problem: Any) -> dict | None:
    """The saved state of an interrupted fit of the same problem, checked field by field.

    The checks are this module's (:mod:`fabric_optics.fitting.state`); a state that fails one raises
    FitError naming the file and the field.

    Parameters
    ----------
    out : Path
        The fit's ``--out`` folder.
    problem : FitProblem
        The fit being resumed.

    Returns
    -------
    dict or None
        The state, its ``x``, ``objective``, ``photons`` and ``evaluations`` checked; None when there is
        no state file.

    Raises
    ------
    FitError
        For a state of another fit, or one that fails a check.
    """
    path = out / STATE_NAME
    state = read_state_json(path)
    if state is None:
        return None
    if state.get("schema") != STATE_SCHEMA or state.get("identity") != problem.identity():
        raise FitError(f"--resume: {path} belongs to a different fit (config, measurement, method, seed or "
                       "free parameters differ); use a new --out or drop --resume")
    names = [p.name for p in problem.free]
    if "names" in state and state["names"] != names:
        raise FitError(f"--resume: {path}: field 'names' does not list this fit's free parameters ({', '.join(names)}); "
                       "delete the file or run without --resume to start afresh")
    for name in ("x", "objective"):
        if name not in state:
            raise FitError(f"--resume: {path}: field {name!r} is missing; delete the file or run without --resume "
                           "to start afresh")
    return {**state,
            "x": check_point(path, "x", state["x"], names, problem.low, problem.high),
            "objective": check_number(path, "objective", state["objective"], low=0.0, high=1e12),
            "photons": check_photons(path, "photons", state.get("photons")),
            "evaluations": int(check_number(path, "evaluations", state.get("evaluations", 0), low=0, high=10**9,
                                            integer=True))}


def save_state(out: Path, problem: Any, x: np.ndarray, objective: float, *, done: bool = False) -> None:
    """``DIR/fit-state.json``: the last accepted point ``x`` of ``problem``'s fit (module docstring).

    Parameters
    ----------
    out : Path
        The fit's ``--out`` folder.
    problem : FitProblem
        The fit.
    x : numpy.ndarray
        The point, one value per free parameter.
    objective : float
        The objective at ``x``.
    done : bool, default False
        Mark the fit as finished.

    Raises
    ------
    FitError
        When the file cannot be written.
    """
    doc = {"schema": STATE_SCHEMA, "identity": problem.identity(), "x": np.asarray(x, float).tolist(),
           "names": [p.name for p in problem.free], "objective": float(objective), "photons": problem.photons,
           "evaluations": problem.counters.evaluations}
    if done:
        doc["done"] = True
    write_json_atomic(out / STATE_NAME, doc)


# ------------------------------------------------------------------------------------------
# the Monte Carlo fit's state and runs


@dataclass
class MCRun:
    """One Monte Carlo run of the fit at parameters ``x`` and its figures against the measurement."""

    x: np.ndarray
    beta: np.ndarray
    u_beta: np.ndarray
    seconds: float
    rays: int
    rel_err: float
    objective: float
    nrmse: float
    dh: float
    ds: float

    def record(self) -> dict:
        """The run as the state file records it."""
        return {"x": self.x.tolist(), "seconds": self.seconds, "rays": self.rays, "rel_err": self.rel_err,
                "objective": self.objective, "nrmse": self.nrmse, "dh": self.dh, "ds": self.ds}


#: the most Monte Carlo runs a state may list (the budget's runs and their trend runs)
MAX_STATE_RUNS = 1000
_RUN_FILE = re.compile(r"run-[0-9]{1,4}(-d[0-9]{1,3})?\.npz")


def _check_record(path: Path, field: str, rec: Any, problem: Any, reach: float = 0.0) -> None:
    """One run record of the state (its point within the bounds widened by ``reach`` spans, figures, file)."""
    if not isinstance(rec, dict):
        refuse(path, f"field {field!r} is not an object")
    for name in ("x", "file", "seconds", "rays", "rel_err", "objective", "nrmse", "dh", "ds"):
        if name not in rec:
            refuse(path, f"field '{field}.{name}' is missing")
    span = problem.high - problem.low
    check_point(path, f"{field}.x", rec["x"], [p.name for p in problem.free], problem.low - reach * span,
                problem.high + reach * span)
    if not isinstance(rec["file"], str) or not _RUN_FILE.fullmatch(rec["file"]):
        refuse(path, f"field '{field}.file' is {json.dumps(rec['file'])[:40]}, not a run file name (run-K.npz)")
    check_number(path, f"{field}.seconds", rec["seconds"], low=0.0, high=1e9)
    check_number(path, f"{field}.rays", rec["rays"], low=0, high=MAX_INTEGER, integer=True)
    check_number(path, f"{field}.objective", rec["objective"], low=0.0, high=1e12)
    for name in ("rel_err", "nrmse", "dh", "ds"):
        check_number(path, f"{field}.{name}", rec[name], allow_nan=True)


def _check_iterations(path: Path, its: Any, problem: Any) -> None:
    """``mc-state.json``'s ``iterations``, checked against this fit.

    Refused, naming the field, unless every run and proposal is one of this fit's
    (:mod:`fabric_optics.fitting.state`).
    """
    if not isinstance(its, list):
        refuse(path, f"field 'iterations' is {json.dumps(its)[:40]}, not a list of runs")
    if len(its) > MAX_STATE_RUNS:
        refuse(path, f"field 'iterations' lists {len(its)} runs, more than {MAX_STATE_RUNS}")
    names = [p.name for p in problem.free]
    for k, rec in enumerate(its):
        _check_record(path, f"iterations[{k}]", rec, problem)
        fine = rec.get("fine_runs")
        if fine is not None:
            if not isinstance(fine, dict) or len(fine) > len(names):
                refuse(path, f"field 'iterations[{k}].fine_runs' is not an object of at most {len(names)} runs")
            for j, fr in fine.items():
                if not (j.isdigit() and int(j) < len(names)):
                    refuse(path, f"field 'iterations[{k}].fine_runs' names parameter {j!r}, not one of 0..{len(names) - 1}")
                _check_record(path, f"iterations[{k}].fine_runs.{j}", fr, problem, reach=1.0)
        prop = rec.get("proposal")
        if prop is not None:
            where = f"iterations[{k}].proposal"
            if not isinstance(prop, dict) or prop.get("kind") not in ("surrogate fit", "backtrack"):
                refuse(path, f"field {where!r} is not a proposal (kind 'surrogate fit' or 'backtrack')")
            for name in ("x", "u", "surrogate_evaluations"):
                if name not in prop:
                    refuse(path, f"field '{where}.{name}' is missing")
            check_point(path, f"{where}.x", prop["x"], names, problem.low, problem.high)
            u = prop["u"]
            if not isinstance(u, list) or len(u) != len(names):
                refuse(path, f"field '{where}.u' is not a list of {len(names)} uncertainties")
            for j, v in enumerate(u):
                check_number(path, f"{where}.u[{j}]", v, low=0.0, allow_nan=True)
            check_number(path, f"{where}.surrogate_evaluations", prop["surrogate_evaluations"], low=0,
                         high=10**9, integer=True)
            notes = prop.get("notes", [])
            if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
                refuse(path, f"field '{where}.notes' is not a list of texts")


class MCState:
    """``DIR/mc-state.json`` and ``DIR/mc-runs/`` (module docstring)."""

    def __init__(self, out: Path | None, identity: str, shape: tuple | None = None):
        self.out = out
        self.identity = identity
        #: ``(geometries, wavelengths)`` of a run's table (None: not checked)
        self.shape = shape
        self.iterations: list[dict] = []

    def load(self, problem: Any | None = None) -> None:
        """The finished runs of ``DIR/mc-state.json``, checked field by field against ``problem``'s free parameters.

        A malformed or out-of-bounds state is refused, not repaired (:mod:`fabric_optics.fitting.state`).

        Parameters
        ----------
        problem : FitProblem, optional
            The fit being resumed; without it the runs' points are not checked.

        Raises
        ------
        FitError
            When there is no state, it belongs to another fit, or it fails a check.
        """
        assert self.out is not None
        path = self.out / MC_STATE
        doc = read_state_json(path)
        if doc is None:
            raise FitError(f"--resume: nothing to resume in {self.out}: no {MC_STATE} (no Monte Carlo run of "
                           "this fit had finished); run without --resume")
        if doc.get("schema") != MC_SCHEMA or doc.get("identity") != self.identity:
            raise FitError(f"--resume: {path} belongs to a different fit (config, measurement, free parameters, "
                           "seed or --target-rel-err differ); use a new --out or drop --resume")
        its = doc.get("iterations")
        if problem is not None:
            _check_iterations(path, its, problem)
        self.iterations = list(its or [])

    def save(self) -> None:
        """Write ``mc-state.json`` (atomically) when the fit has an output folder."""
        if self.out is not None:
            write_json_atomic(self.out / MC_STATE, {"schema": MC_SCHEMA, "identity": self.identity,
                                                   "iterations": self.iterations})

    def run(self, k: int, x: np.ndarray) -> MCRun | None:
        """Run ``k`` from the checkpoint if it was made at ``x``.

        Parameters
        ----------
        k : int
            The iteration.
        x : numpy.ndarray
            The point the run must have been made at.

        Returns
        -------
        MCRun or None
            The run, or None when there is none at ``x``.
        """
        if self.out is None or k >= len(self.iterations):
            return None
        rec = self.iterations[k]
        if not np.allclose(rec["x"], x, rtol=0.0, atol=1e-12):
            return None
        return self._load(rec)

    def _load(self, rec: dict) -> MCRun | None:
        """The run ``rec`` names, or None (it is run again) when its file is missing.

        A file that is there but not a run of this fit (:func:`read_npz`; two finite tables of this fit's shape)
        is refused naming it.
        """
        path = self.out / MC_RUNS_DIR / rec["file"]  # type: ignore[operator]
        z = read_npz(path, {"x": ("f", 1), "beta": ("f", 2), "u_beta": ("f", 2)})
        if z is None:
            log.warning("%s is missing: its Monte Carlo run is run again", path)
            return None
        beta, u = z["beta"], z["u_beta"]
        want = self.shape if self.shape is not None else beta.shape
        if beta.shape != want or u.shape != want:
            refuse_file(path, f"holds tables of shape {beta.shape} and {u.shape}, not this fit's {want}")
        return MCRun(x=np.asarray(rec["x"], float), beta=beta, u_beta=u, seconds=rec["seconds"], rays=rec["rays"],
                     rel_err=rec["rel_err"], objective=rec["objective"], nrmse=rec["nrmse"], dh=rec["dh"],
                     ds=rec["ds"])

    def _store(self, name: str, run: MCRun) -> dict:
        rec = run.record()
        if self.out is not None:
            d = self.out / MC_RUNS_DIR
            rec["file"] = f"{name}.npz"
            try:
                d.mkdir(parents=True, exist_ok=True)
                atomic_write(d / rec["file"], lambda fh: np.savez(fh, x=run.x, beta=run.beta, u_beta=run.u_beta))
            except OSError as exc:
                raise FitError(write_failed(d / rec["file"], exc)) from None
        return rec

    def put_run(self, k: int, run: MCRun) -> None:
        """Record run ``k`` (dropping any later one) and save the state.

        Parameters
        ----------
        k : int
            The iteration.
        run : MCRun
            The run.
        """
        del self.iterations[k:]
        self.iterations.append(self._store(f"run-{k}", run))
        self.save()

    def fine_run(self, k: int, j: int, x: np.ndarray) -> MCRun | None:
        """Fine parameter ``j``'s finite-difference run about centre ``k`` from the checkpoint, if made at ``x``.

        Parameters
        ----------
        k : int
            The iteration (the centre).
        j : int
            The fine parameter's index.
        x : numpy.ndarray
            The point the run must have been made at.

        Returns
        -------
        MCRun or None
            The run, or None when there is none at ``x``.
        """
        if self.out is None or k >= len(self.iterations):
            return None
        rec = (self.iterations[k].get("fine_runs") or {}).get(str(j))
        if rec is None or not np.allclose(rec["x"], x, rtol=0.0, atol=1e-12):
            return None
        return self._load(rec)

    def put_fine_run(self, k: int, j: int, run: MCRun) -> None:
        """Record the trend run ``j`` of iteration ``k`` and save the state.

        Parameters
        ----------
        k : int
            The iteration (the centre).
        j : int
            The fine parameter's index.
        run : MCRun
            The run.
        """
        self.iterations[k].setdefault("fine_runs", {})[str(j)] = self._store(f"run-{k}-d{j}", run)
        self.save()

    def proposal(self, k: int) -> dict | None:
        """The proposal recorded for iteration ``k``, None when there is none.

        Parameters
        ----------
        k : int
            The iteration.

        Returns
        -------
        dict or None
            The proposal.
        """
        return self.iterations[k].get("proposal") if k < len(self.iterations) else None

    def put_proposal(self, k: int, proposal: dict) -> None:
        """Record the proposal of iteration ``k`` and save the state.

        Parameters
        ----------
        k : int
            The iteration.
        proposal : dict
            The proposal.
        """
        self.iterations[k]["proposal"] = proposal
        self.save()


def left_behind(out: Path) -> str:
    """What an interrupted Monte Carlo fit left in ``out`` (only what exists).

    Parameters
    ----------
    out : Path
        The fit's ``--out`` folder.

    Returns
    -------
    str
        One phrase: the finished runs and proposals kept, or that nothing was saved.
    """
    try:
        its = (read_state_json(out / MC_STATE) or {}).get("iterations") or []
    except FitError:
        its = []
    if not isinstance(its, list):
        its = []
    if its:
        props = sum(1 for it in its if isinstance(it, dict) and it.get("proposal"))
        return (f"{len(its)} finished Monte Carlo run(s) and {props} proposal(s) fitted from them are in "
                f"{out / MC_STATE} and {out / MC_RUNS_DIR} (continue with --resume)")
    return "no Monte Carlo run had finished: nothing was saved (run again without --resume)"


