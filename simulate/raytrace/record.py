"""What the fibre-assembly tracer records of a run when asked (``record``): its events, for a re-weighting.

:func:`simulate.raytrace.integrator.trace` with ``record`` appends one :class:`TraceLog` per trace; each
chunk of rays is recorded by an :class:`EventLog` into a :class:`ChunkLog`: per hit the ray, the table row
and the continuation's scalar and the path roulette's outcome, per next-event score the hit, the detector,
the row and the scalar over the shadow roulette's probability. :mod:`simulate.raytrace.reweight` replays
them with another dye's tables.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ChunkLog", "EventLog", "TraceLog"]


@dataclass(frozen=True)
class ChunkLog:
    """The events of one chunk of ``N = G n`` rays, in the tracer's order (bounce by bounce).

    Hits: ``hit_ray`` (the ray), ``hit_row`` (the table row of a volume exit, -1 otherwise), ``hit_scale``
    (the continuation's scalar; 0: the ray stopped), ``hit_rr`` (the path's roulette: 0 not played, 1 kept,
    2 stopped); bounce ``b``'s hits are ``hit_start[b]:hit_start[b + 1]``. Next-event scores (visible and
    kept by the shadow roulette): ``nee_hit`` (index into the hits), ``nee_det``, ``nee_row`` (-1: the
    surface term), ``nee_scale`` (the scalar over the roulette's probability); bounce ``b``'s are
    ``nee_start[b]:nee_start[b + 1]``.
    """

    N: int
    n: int
    G: int
    D: int
    hit_ray: np.ndarray
    hit_row: np.ndarray
    hit_scale: np.ndarray
    hit_rr: np.ndarray
    hit_start: np.ndarray
    nee_hit: np.ndarray
    nee_det: np.ndarray
    nee_row: np.ndarray
    nee_scale: np.ndarray
    nee_start: np.ndarray

    @property
    def nbytes(self) -> int:
        """Bytes held by the recorded arrays (what keeping the record costs in memory)."""
        return int(sum(getattr(self, f.name).nbytes for f in dataclasses.fields(self)
                       if isinstance(getattr(self, f.name), np.ndarray)))


class EventLog:
    """The recorder of one chunk (:func:`simulate.raytrace.integrator._chunk` with ``record``)."""

    def __init__(self, N: int, n: int, G: int, D: int) -> None:
        self.N, self.n, self.G, self.D = int(N), int(n), int(G), int(D)
        self._hits: list[tuple] = []
        self._scores: list[tuple] = []
        self._h = 0
        self._q = 0
        self._hit_start = [0]
        self._nee_start = [0]

    def scores(self, kept: np.ndarray, cidx: np.ndarray, p: np.ndarray, nee_row: np.ndarray,
               nee_scale: np.ndarray) -> None:
        """A bounce's scored candidates (``kept``: their indices into ``cidx``, in scoring order)."""
        i, e, d = cidx[kept, 0], cidx[kept, 1], cidx[kept, 2]
        self._scores.append(((self._h + i).astype(np.int32), d.astype(np.int16), nee_row[i, e, d].astype(np.int32),
                             nee_scale[i, e, d] / p[kept]))
        self._q += int(kept.size)

    def hits(self, ray: np.ndarray, out_row: np.ndarray, out_scale: np.ndarray, low: np.ndarray,
             draws: np.ndarray, survive: float) -> None:
        """A bounce's hits, their continuations and the path roulette's outcome (``draws`` over the ``low`` rows)."""
        rr = low.astype(np.int8)
        if draws.size:
            rr[low] = np.where(draws < survive, 1, 2).astype(np.int8)
        self._hits.append((ray.astype(np.int32), out_row.astype(np.int32), np.array(out_scale, float), rr))
        self._h += int(ray.size)
        self._hit_start.append(self._h)
        self._nee_start.append(self._q)

    def close(self) -> ChunkLog:
        """The chunk's events as one :class:`ChunkLog` (the bounces' parts joined in order)."""
        def cat(parts: list, k: int, dtype: Any) -> np.ndarray:
            return np.concatenate([p[k] for p in parts]) if parts else np.zeros(0, dtype)

        h, s = self._hits, self._scores
        return ChunkLog(self.N, self.n, self.G, self.D, cat(h, 0, np.int32), cat(h, 1, np.int32),
                        cat(h, 2, float), cat(h, 3, np.int8), np.array(self._hit_start, np.int64),
                        cat(s, 0, np.int32), cat(s, 1, np.int16), cat(s, 2, np.int32), cat(s, 3, float),
                        np.array(self._nee_start, np.int64))


@dataclass
class TraceLog:
    """One :func:`simulate.raytrace.integrator._trace`'s chunks (in order), its groups, detectors and table rows' shape."""

    chunks: list
    G: int
    D: int
    L: int
    detectors: np.ndarray
    rays: int
    rows_shape: tuple

    @property
    def nbytes(self) -> int:
        """Bytes held by all chunks' recorded arrays."""
        return int(sum(c.nbytes for c in self.chunks))
