"""A dye's woven/felt Monte Carlo without tracing again: the traced rays re-weighted (correlated sampling).

A dye (the fiber host's absorption) enters the tracer only through the fiber's exit table ``T`` (the
white walk applies it per wavelength: :mod:`simulate.raytrace.yarn`). The rays' geometry -- where they
hit, the row read, the exit cell and direction sampled, reflect or enter, the roulettes -- was drawn
from probabilities computed with the traced table; under another table the same draws are an
importance sample of the other dye's estimate when each event's weight factor is the new table's
value over the probability that was USED (perturbation / correlated-sampling Monte Carlo: Hayakawa
et al., Opt. Lett. 26(17), 2001; Alerstam, Andersson-Engels and Svensson, J. Biomed. Opt. 13(4),
2008). Per event that factor is a table row times a scalar that holds every sampling probability
and geometric factor of the traced run:

* a volume exit continues with ``w T[row] s`` (``s = entry corr f_out / (c_bar p_cell (1 - p_refl))``,
  ``p_cell`` and ``p_refl`` the traced table's), a reflection with ``w s`` (``s = f / p_refl``);
* a next-event score adds ``w T[row] s / p_shadow`` (a volume exit) or ``w s / p_shadow`` (the
  surface term), ``p_shadow`` the shadow roulette's probability, played on the traced weights;
* the path's roulette multiplies a survivor by ``1 / 0.1`` and stops a loser, as traced.

:func:`simulate.raytrace.integrator.trace` with ``record`` keeps those per event (:class:`EventLog`:
per hit the ray, the row and the scalar (:mod:`simulate.raytrace.record`), and the roulette's outcome; per next-event score the hit, the
detector, the row and the scalar over ``p_shadow``), and :func:`replay` recomputes every ray's
per-detector totals with another table, in the tracer's order: at the traced table the result equals
the traced one to rounding. ``u_beta`` is computed from the re-weighted per-ray totals as the tracer
computes its own, so the variance the weights add is in it. The findings, the memory per event and
the validation against re-traced runs: docs/notes/reweighted-mc.md.

What it needs of the new table: wherever the new table's exit density is above zero the traced one's
must be too (a cell never sampled cannot be re-weighted). Tables walked with the same photons
(white Monte Carlo at the same seeds: :func:`simulate.raytrace.yarn.table_halves`) reach the same cells.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Sequence
from typing import Any, overload

import numba
import numpy as np

from simulate.montecarlo.accuracy import relative_error
from simulate.raytrace.record import TraceLog

__all__ = ["replay", "record_bytes", "new_tables", "WalkedHalves", "MixedHalves", "reweighted_beta",
           "same_but_dye"]


@numba.njit(cache=True, nogil=True)
def _replay_chunk(N, hit_ray, hit_row, hit_scale, hit_rr, hit_start, nee_hit, nee_det, nee_row, nee_scale,
                  nee_start, t_rows, survive, acc):
    """Every ray's per-detector totals ``acc [N, D, L]`` with the table rows ``t_rows`` (compiled)."""
    L = t_rows.shape[1]
    W = np.ones((N, L))
    for b in range(hit_start.shape[0] - 1):
        for q in range(nee_start[b], nee_start[b + 1]):
            r = hit_ray[nee_hit[q]]
            d = nee_det[q]
            row = nee_row[q]
            sc = nee_scale[q]
            if row < 0:
                for k in range(L):
                    acc[r, d, k] += W[r, k] * sc
            else:
                for k in range(L):
                    acc[r, d, k] += W[r, k] * t_rows[row, k] * sc
        for i in range(hit_start[b], hit_start[b + 1]):
            r = hit_ray[i]
            row = hit_row[i]
            sc = hit_scale[i]
            rr = hit_rr[i]
            for k in range(L):
                x = W[r, k] * t_rows[row, k] * sc if row >= 0 else W[r, k] * sc
                if rr == 1:
                    x = x / survive
                elif rr == 2:
                    x = 0.0
                W[r, k] = x


def replay(log: TraceLog, t_rows: np.ndarray) -> list[Any]:
    """The :class:`~simulate.raytrace.integrator.MCResult` of each group of a recorded trace, re-weighted.

    The trace's rays are re-weighted to the table rows ``t_rows``; the traced table's rows give the traced
    result to rounding. Only ``beta``, ``u_beta``, ``rays`` and ``rel_err`` are filled in.

    Parameters
    ----------
    log : TraceLog
        The recorded trace.
    t_rows : numpy.ndarray
        ``T.reshape(-1, L)`` of the new table (the traced table's row shape).

    Returns
    -------
    list of MCResult
        One result per group of the trace.

    Raises
    ------
    ValueError
        When the new table's rows differ in shape from the traced one's.
    """
    from simulate.raytrace.integrator import ROULETTE_SURVIVE, MCResult, mean_se

    t_rows = np.ascontiguousarray(t_rows, float)
    if t_rows.shape != tuple(log.rows_shape):
        raise ValueError(f"reweight: the new table's rows {t_rows.shape} differ from the traced {log.rows_shape} "
                         "(another grid, exit bins or wavelengths: trace again)")
    G, D, L = log.G, log.D, log.L
    nee = np.zeros((G, D, L))
    nee2 = np.zeros((G, D, L))
    rays = 0
    for c in log.chunks:
        acc = np.zeros((c.N, D, L))
        _replay_chunk(c.N, c.hit_ray, c.hit_row, c.hit_scale, c.hit_rr, c.hit_start, c.nee_hit, c.nee_det,
                      c.nee_row, c.nee_scale, c.nee_start, t_rows, ROULETTE_SURVIVE, acc)
        tot = acc.reshape(G, c.n, D, L)
        nee += tot.sum(axis=1)
        nee2 += np.einsum("gndl,gndl->gdl", tot, tot)
        rays += c.n
    cos_o = log.detectors[..., 2][..., None]
    out = []
    empty = np.zeros(0)
    for g in range(G):
        mean, u = mean_se(nee[g], nee2[g], rays)
        beta, u_beta = np.pi * mean / cos_o[g], np.pi * u / cos_o[g]
        out.append(MCResult(beta, u_beta, empty, empty, empty, empty, empty, empty, rays, 0.0,
                            relative_error(beta, u_beta) if float(np.abs(beta).max(initial=0.0)) > 0 else 0.0,
                            "target"))
    return out


def record_bytes(record: dict) -> int:
    """The memory of a :func:`simulate.raytrace.fabric_beta` record's events (bytes).

    Parameters
    ----------
    record : dict
        The record.

    Returns
    -------
    int
        Bytes held by its traces' arrays.
    """
    return int(sum(t.nbytes for inc in record.get("incidences", []) for t in inc["realisations"]))


def _half_results(record: dict, tables: Sequence[Any]) -> list[list[Any]]:
    """Per incidence, the realisations' results re-weighted to ``tables``, in the realisations' order.

    Each realisation's rotations are averaged; realisation ``j`` is read on table half ``j mod 2``.

    Half by half: every incidence's rays of a half are replayed with that half's table, which is then let go
    before the other is asked for (:func:`new_tables` walks or reads each only then), so a re-weighting holds
    one table at a time beside the record. The replays are independent: the order changes no result.
    """
    from simulate.raytrace.estimate import mean_of

    incidences = record["incidences"]
    out: list[list[Any]] = [[None] * len(inc["realisations"]) for inc in incidences]
    for h in range(len(tables)):
        T = tables[h].T
        rows = T.reshape(-1, T.shape[-1])
        for i, inc in enumerate(incidences):
            for j in range(h, len(inc["realisations"]), len(tables)):
                out[i][j] = mean_of(replay(inc["realisations"][j], rows))
        del T, rows
    return out


def reweighted_beta(record: dict, tables: Sequence[Any]) -> tuple[np.ndarray, np.ndarray, dict]:
    """A recorded :func:`simulate.raytrace.fabric_beta` run re-weighted to the table halves ``tables``.

    The realisations are combined as :func:`~simulate.raytrace.fabric_beta` combines its traces
    (:func:`simulate.raytrace.estimate.combine_realisations`: the realisations' mean and its error).

    Parameters
    ----------
    record : dict
        The run's record (its incidences, realisations, traced tables and grid).
    tables : sequence of YarnTable
        The new table halves (:func:`new_tables`).

    Returns
    -------
    beta, u_beta : numpy.ndarray
        ``[P, L]`` estimate and standard error.
    info : dict
        ``rel_err`` and ``ray_rel_err`` (the re-weighted run's, :func:`relative_error`), per incidence the
        same and ``spread``, the re-weighted ray error over the traced run's at the same rays (1 at the traced
        dye; a fresh trace at the new dye would give about the traced run's, so the ratio is how much the
        weights cost: its square is the inverse of the effective sample size's share), ``rays``,
        ``event_bytes`` and ``u_rays`` (``[P, L]``: the rays' part of ``u_beta``, without the table's).
    """
    from simulate.raytrace.estimate import combine_realisations

    shape = tuple(record["shape"])
    beta = np.zeros(shape)
    u_beta = np.zeros(shape)
    u_rays = np.zeros(shape)
    runs = []
    for inc, res in zip(record["incidences"], _half_results(record, tables), strict=True):
        rows, det_inv = inc["rows"], inc["det_inv"]
        c = combine_realisations([r.beta for r in res], [r.u_beta for r in res])
        b, u = c["beta"], c["u_beta"]
        beta[rows] = b[det_inv]
        u_beta[rows] = u[det_inv]
        u_rays[rows] = c["u_rays"][det_inv]
        ray_rel = relative_error(b, c["u_rays"])
        traced = inc.get("ray_rel_err")
        runs.append({"rel_err": relative_error(b, u), "ray_rel_err": ray_rel,
                     "spread": ray_rel / traced if traced else float("nan"), "rays": int(sum(r.rays for r in res))})
    info = {"rel_err": relative_error(beta, u_beta),
            "ray_rel_err": max((r["ray_rel_err"] for r in runs), default=0.0),
            "spread": max((r["spread"] for r in runs), default=float("nan")),
            "incidences": runs, "rays": int(sum(r["rays"] for r in runs)), "event_bytes": record_bytes(record),
            "u_rays": u_rays}
    return beta, u_beta, info


def same_but_dye(old: Any, new: Any) -> bool:
    """Whether fiber ``new`` is ``old`` but for its host absorption (the dye).

    Every field of the fiber must be the same, and the medium's canonical form (the yarn table's cache key,
    :func:`simulate.raytrace.yarn.table_key`) the same once the dye is put back.

    Parameters
    ----------
    old : Fiber
        The traced fiber.
    new : Fiber
        The fiber to re-weight to.

    Returns
    -------
    bool
        True when a re-weighting of ``old``'s record can stand for a trace of ``new``.
    """
    from simulate.media.medium import HGMedium
    from simulate.raytrace.yarn import table_key

    try:
        if isinstance(new.medium, HGMedium):
            medium = dataclasses.replace(new.medium, mu_a=old.medium.mu_a)
        else:
            medium = dataclasses.replace(new.medium, mu_a_host_per_um=old.medium.mu_a_host_per_um)
        back = dataclasses.replace(new, medium=medium)
        rest = all(getattr(back, f.name) == getattr(old, f.name) for f in dataclasses.fields(old)
                   if f.name != "medium")
        return bool(rest and table_key(back, [550.0]) == table_key(old, [550.0]))
    except (TypeError, AttributeError, ValueError):
        return False


class _RecordHalves(Sequence):
    """The table halves of a recorded run, each made by :meth:`_half` when it is read and not kept."""

    _record: dict

    def __len__(self) -> int:
        return len(self._record["tables"])

    @overload
    def __getitem__(self, h: int) -> Any: ...

    @overload
    def __getitem__(self, h: slice) -> Sequence[Any]: ...

    def __getitem__(self, h: int | slice) -> Any:
        if isinstance(h, slice):
            return [self[i] for i in range(len(self))[h]]
        if not -len(self) <= h < len(self):
            raise IndexError(f"table half {h} of {len(self)}")
        h %= len(self)
        table = self._half(h)
        _check_half(self._record["tables"][h], table)
        return table

    @abc.abstractmethod
    def _half(self, h: int) -> Any:
        """Half ``h`` (``0 <= h < len(self)``), made afresh."""


class WalkedHalves(_RecordHalves):
    """The two table halves a recorded run would have traced with ``fiber``, each made when it is asked for.

    Each half is walked (or read from the table cache) and not kept: :func:`reweighted_beta` reads them one
    after the other, so the two are never held together (a felt's half at its [10, 20] exit bins takes
    hundreds of MB). Each half is bit for bit the one :func:`simulate.raytrace.yarn.table_halves` gives (the
    same photons, seeds and grid; the same cache key), checked against the traced half's grid, ``c_bar`` and
    ``tau`` as it is made.

    Parameters
    ----------
    record : dict
        The recorded run (its traced tables, grid, photons and seed).
    fiber : Fiber
        The fiber to walk the halves with.
    """

    def __init__(self, record: dict, fiber: Any) -> None:
        from simulate.raytrace.pile import HELD_LOG_MU_S, pile_fiber

        self._record = record
        self._grid: dict[str, Any] = dict(record["grid"])
        self._walked = fiber
        if record["volume"] == "pile":
            self._walked = pile_fiber(fiber, record["yarn_radius"], record["packing"])
            self._grid["held_log_mu_s"] = HELD_LOG_MU_S

    def _half(self, h: int) -> Any:
        from simulate.raytrace.yarn import HALF_SEED_STEP, yarn_table

        r = self._record
        threads = r["threads"]
        return yarn_table(self._walked, r["wavelengths_nm"], photons_per_row=r["photons_per_row"],
                          seed=int(r["seed"]) + HALF_SEED_STEP * h, threads=threads if threads else None,
                          **self._grid)


def _check_half(traced: dict, table: Any) -> None:
    if (tuple(traced["shape"]) != table.T.shape
            or not np.allclose(traced["c_bar"], table.c_bar, rtol=1e-12, atol=0.0)
            or not np.allclose(traced["tau"], table.tau, rtol=1e-12, atol=0.0)):
        raise ValueError("reweight: the new tables differ from the traced ones in more than the dye (grid, "
                         "radius or index): trace again")


class MixedHalves(_RecordHalves):
    """A blend's table halves a recorded run would have traced with ``populations``.

    Each half is the populations' :class:`WalkedHalves` half mixed by share
    (:func:`simulate.raytrace.yarn.mix_tables`), as :func:`simulate.raytrace.fabric_beta` mixes them, made
    when it is read and checked against the traced half.

    Parameters
    ----------
    record : dict
        The recorded run.
    populations : sequence of (float, Fiber)
        The blend's ``(share, fiber)`` pairs.
    """

    def __init__(self, record: dict, populations: Sequence[tuple[float, Any]]) -> None:
        self._record = record
        self._shares = [float(share) for share, _ in populations]
        self._walked = [WalkedHalves(record, fiber) for _, fiber in populations]

    def _half(self, h: int) -> Any:
        from simulate.raytrace.yarn import mix_tables

        return mix_tables([w[h] for w in self._walked], self._shares)


def new_tables(record: dict, fiber: Any, tables: tuple | None = None,
               populations: Sequence[tuple[float, Any]] | None = None) -> Sequence[Any]:
    """The table halves a recorded run would have traced with ``fiber``.

    The same walk (photons, seeds, grid; from the table cache when there), each half made when it is read.

    Parameters
    ----------
    record : dict
        The recorded run.
    fiber : Fiber
        The fiber to re-weight to.
    tables : tuple of YarnTable, optional
        Halves already made (mixed halves): they are checked and returned.
    populations : sequence of (float, Fiber), optional
        A blend's ``(share, fiber)`` pairs, mixed half by half.

    Returns
    -------
    sequence of YarnTable
        ``tables``; else a :class:`MixedHalves` for ``populations``; else a :class:`WalkedHalves`.

    Raises
    ------
    ValueError
        When given tables differ from the traced ones in number or in more than the dye.
    """
    if tables is None:
        return WalkedHalves(record, fiber) if populations is None else MixedHalves(record, populations)
    if len(tables) != len(record["tables"]):
        raise ValueError(f"reweight: {len(tables)} table halves given for the {len(record['tables'])} traced")
    for traced, table in zip(record["tables"], tables, strict=True):
        _check_half(traced, table)
    return tuple(tables)
