"""A finished ``simulate fit`` kept in the table cache, so that the same command run again restores it.

A fit is a pure function of its inputs: the config (as loaded, every field and table it holds), the
measured values, the options that change its result (method, free parameters, budgets, target,
seed, colour and level settings, wavelengths) and the code (the source of the four packages and
their data files, numpy, numba and miepython's versions). Its outputs do not depend on the number
of threads. When a command finishes, its output folder, the lines it printed and its exit status are
stored in the table cache (:mod:`simulate.fiber.tablecache`) under the SHA-256 of all of these and
of the output folder's path (the outputs name it); the same command run again, with nothing
changed, restores the folder and prints the same lines instead of fitting again, and says so. The
measurement counts by its values and what its meta says it measured, not by when, through which
port or by which build of the software it was recorded: a repeated
acquisition of the same values (the mock instrument at its seed) restores the fit, whose own report
then names the acquisition it was computed from. Any
change -- an edited source file, another measurement, another option -- is another key: the fit
runs. ``--no-cache`` (or ``FABRIC_OPTICS_NO_CACHE=1``) fits every time, ``--resume`` continues
its own fit and never restores, and the Python API's :func:`fabric_optics.fit` always fits.

This is what a build tool does for a step whose inputs did not change (``make``, ``ccache``): a
second ``make demo`` repeats its acquisition and restores its three fits.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import io
import json
import logging
import tarfile
from pathlib import Path
from typing import Any

import numpy as np

from simulate.fiber import tablecache

__all__ = ["KIND", "MAX_FOLDER_BYTES", "RESULT_OPTIONS", "code_identity", "fit_key", "lookup", "restore", "keep"]

log = logging.getLogger(__name__)

#: the cache entries' kind (the first word of their key)
KIND = "fit"
#: a fit's folder above this size is not stored (a fit's outputs are a few MB)
MAX_FOLDER_BYTES = 64 * 2**20
#: the ``simulate fit`` options that change its result (every other option changes how it runs, not what)
RESULT_OPTIONS = ("method", "free", "colour_weight", "colour_hold", "absolute", "max_evaluations", "max_runs",
                  "mc_trend", "mc_retrace", "starts", "wavelengths", "dye", "target_rel_err", "seed")
#: the packages whose source and data files make the code's identity
PACKAGES = ("gonio", "simulate", "compare", "fabric_optics")
#: the files of a package that can change a result (its code and the data it reads)
SUFFIXES = (".py", ".toml", ".json", ".csv", ".txt", ".bsdf", ".npz")

_IDENTITY: list[str] = []


def code_identity() -> str:
    """SHA-256 of the code: every source and data file of the four packages and the numerical libraries' versions.

    The files' paths and bytes are hashed; computed once per process.
    """
    if not _IDENTITY:
        h = hashlib.sha256()
        root = Path(__file__).resolve().parents[2]
        for package in PACKAGES:
            for path in sorted((root / package).rglob("*")):
                if path.suffix in SUFFIXES and "__pycache__" not in path.parts and path.is_file():
                    h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
        for dist in ("numpy", "scipy", "numba", "llvmlite", "miepython", "colour-science", "pandas"):
            try:
                version = importlib.metadata.version(dist)
            except importlib.metadata.PackageNotFoundError:
                version = "absent"
            h.update(f"{dist}={version}\0".encode())
        _IDENTITY.append(h.hexdigest())
    return _IDENTITY[0]


#: the measurement's meta fields that name its run rather than what it measured (its time, the instrument's
#: connection endpoints, the software that recorded it: the fit's own code is in the key apart), left out of the key
RUN_FIELDS = ("created", "instrument", "software")


def _measurement(measured: Any) -> dict[str, Any]:
    """What a fit reads of a measurement: its values and what its meta says it measured.

    The values by the canonical ``radiance.csv`` bytes' hash; the meta without the fields that name the run
    (:data:`RUN_FIELDS`, and the provenance's software ``versions``).
    """
    meta = {k: v for k, v in measured.meta.items() if k not in RUN_FIELDS}
    if isinstance(meta.get("provenance"), dict):   # the acquisition's software versions name the run too
        meta["provenance"] = {k: v for k, v in meta["provenance"].items() if k != "versions"}
    return {"values": measured.content_sha256(), "meta": json.dumps(meta, sort_keys=True, default=str)}


def fit_key(options: dict[str, Any], config: Any, measured: Any, out: Path) -> str:
    """The cache key of one ``simulate fit``.

    Parameters
    ----------
    options : dict
        The parsed command line; :data:`RESULT_OPTIONS` are read.
    config : SimulationConfig
        The loaded config.
    measured : Dataset
        The measured dataset.
    out : Path
        The output folder.

    Returns
    -------
    str
        ``fit-`` and 40 hex digits of the inputs' and the code's hash.
    """
    chosen = {name: options.get(name) for name in RESULT_OPTIONS}
    inputs = {"options": repr(sorted(chosen.items())), "config": tablecache.content_hash(config),
              "measured": _measurement(measured), "out": str(Path(out).resolve()),
              "code": code_identity()}
    return f"{KIND}-{tablecache.content_hash(inputs)[:40]}"


def lookup(key: str) -> dict[str, np.ndarray] | None:
    """The fit stored under ``key``, or None (no such fit, or the cache is off).

    Parameters
    ----------
    key : str
        The fit's key (:func:`fit_key`).

    Returns
    -------
    dict of str to numpy.ndarray or None
        The stored arrays (the folder, the printed lines and the exit status).
    """
    return tablecache.load(key) if tablecache.enabled() else None


def restore(found: dict[str, np.ndarray], out: Path) -> tuple[list[tuple[str, str]], int]:
    """Restore a fit :func:`lookup` found into ``out``: the lines it printed ``(stream, text)`` and its exit status.

    Parameters
    ----------
    found : dict of str to numpy.ndarray
        What :func:`lookup` returned.
    out : Path
        The ``--out`` folder the fit's files are restored into.

    Returns
    -------
    lines : list of (str, str)
        The lines the fit printed: the stream's name and the text.
    exit_status : int
        The fit's exit status.
    """
    with tarfile.open(fileobj=io.BytesIO(found["folder"].tobytes()), mode="r") as tar:
        tar.extractall(out, filter="data")
    lines = [(str(s), str(t)) for s, t in zip(found["streams"].tolist(), found["lines"].tolist(), strict=True)]
    return lines, int(found["exit"])


def keep(key: str, out: Path, lines: list[tuple[str, str]], exit_status: int) -> bool:
    """Store the finished fit's folder ``out``, its printed ``lines`` and ``exit_status`` under ``key``.

    Returns False when not stored: the cache is off, the folder is too large, or the cache cannot be written.

    Parameters
    ----------
    key : str
        The fit's key (:func:`fit_key`).
    out : Path
        The finished fit's ``--out`` folder (its hidden files are left out).
    lines : list of (str, str)
        The lines the fit printed: the stream's name and the text.
    exit_status : int
        The fit's exit status.

    Returns
    -------
    bool
        Whether the fit was stored.
    """
    if not tablecache.enabled():
        return False
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    if size > MAX_FOLDER_BYTES:
        log.info("fit cache: %s holds %d MB, above %d MB: not stored", out, size >> 20, MAX_FOLDER_BYTES >> 20)
        return False
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for path in sorted(out.rglob("*")):
            if path.is_file() and not path.name.startswith("."):
                tar.add(path, arcname=str(path.relative_to(out)), recursive=False)
    arrays = {"folder": np.frombuffer(buf.getvalue(), dtype=np.uint8),
              "streams": np.array([s for s, _ in lines], dtype=str),
              "lines": np.array([t for _, t in lines], dtype=str),
              "exit": np.array(exit_status)}
    return tablecache.store(key, arrays) is not None

