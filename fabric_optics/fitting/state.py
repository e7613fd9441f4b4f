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
``DIR/fit-state.json``: the last accepted point (see :mod:`fabric_optics.fitting.driver`).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

__all__ = ["WALKS_DIR", "WalkCheckpoint", "write_json_atomic"]

WALKS_DIR = "walks"


def write_json_atomic(path: Path, doc: dict) -> None:
    """``doc`` as JSON at ``path``, written to a temporary file, fsynced and renamed."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


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
        self.dir.mkdir(parents=True, exist_ok=True)
        path = self._path(key)
        tmp = path.with_name(f".{path.stem}.tmp.npz")
        np.savez(tmp, value=value, u=u, photons=np.int64(photons), scatterings=np.float64(scatterings))
        os.replace(tmp, path)

    def count(self) -> int:
        """Runs of any walk on disk."""
        return len(list(self.dir.glob("*.npz"))) if self.dir.is_dir() else 0
