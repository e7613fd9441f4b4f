"""Many runs in one parallel kernel call: runs that differ only in their source row and seed.

The BSSRDF tables (:func:`simulate.fiber.bssrdf.bssrdf_rows`, the woven fabric's yarn and pile
tables :mod:`simulate.raytrace.yarn`) are made of many short runs -- one per lit row, per axial
node, per table half -- of a few thousand photons each, i.e. one or two batches of
:data:`simulate.montecarlo.accuracy.BATCH`. Run one at a time (:func:`.transport.execute`), each
kernel call had fewer batches than threads: on 2 cores one thread idled in most of them, and every
call paid its thread start and barrier (red cotton's cold woven Monte Carlo made 700
such calls). :func:`execute_rows` hands all batches of all runs to ONE ``prange``
(:func:`.kernel.run_rows` or its dye profile's flavour, dynamic scheduling, one batch per chunk) and reduces each run's
batches in batch order, exactly as :func:`.transport.execute` does for that run alone: every
run's sums are bit-identical to its own call (``tests/simulate/mc/test_rows.py``).

Rounds: like :func:`.transport.execute`, the jobs are cut into compiled rounds of about
:data:`.transport.ROUND_SECONDS` (Ctrl-C latency) and of at most ``_ROUND_ELEMENTS`` buffer
elements; how they are cut does not change any sum.
"""

from __future__ import annotations

import threading
import time
from typing import overload

import numba
import numpy as np

from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.transport import ROUND_SECONDS, ParameterError

__all__ = ["execute_rows"]

_ROUND_ELEMENTS = 1 << 22  # cap on per-round bin buffer elements (32 MB), as transport.execute

_scratch = threading.local()


def _buffers(jobs: int, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """The round buffers ``scal[jobs, N_SCALARS]`` and ``bins[jobs, n_bins, 2]``, kept per thread.

    They are reused while the shape holds (the kernel zeroes a job's rows before it runs: no stale
    values); fresh buffers of this size would cost their page faults at every call
    (docs/notes/implementation.md).
    """
    got = getattr(_scratch, "buffers", None)
    if got is None or got[1].shape != (jobs, n_bins, 2):
        got = (np.zeros((jobs, T.N_SCALARS)), np.zeros((jobs, n_bins, 2)))
        _scratch.buffers = got
    return got


@overload
def execute_rows(inp: K.KernelInputs, sources: np.ndarray, seeds: np.ndarray, photons: int, threads: int | None,
                 batch_size: int, means: None = None) -> tuple[np.ndarray, np.ndarray, float]: ...


@overload
def execute_rows(inp: K.KernelInputs, sources: np.ndarray, seeds: np.ndarray, photons: int, threads: int | None,
                 batch_size: int, means: np.ndarray) -> tuple[np.ndarray, None, float]: ...


def execute_rows(inp: K.KernelInputs, sources: np.ndarray, seeds: np.ndarray, photons: int, threads: int | None,
                 batch_size: int, means: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Run ``photons`` photons for each source row ``sources[r]`` (``float64[R, 5]``) with seed ``seeds[r]``.

    Returns ``scal[R, N_SCALARS]``, ``bins[R, n_bins, 2]`` -- run ``r``'s sums, bit-identical to
    ``transport.execute(inp with source sources[r], photons, seeds[r], threads, batch_size)`` -- and
    the seconds of the whole call. ``inp.source`` is not read. Scoring runs only (a tally or a
    vertex estimator: the plain flavour has no rows driver).

    ``means`` (optional, ``float64[R, ...]`` with ``n_bins`` values a row, e.g. a view of a larger table):
    each run's bin means ``bins[r, :, 0] / photons`` are written there (row-major order of its trailing
    axes) and ``None`` is returned for ``bins``: no ``[R, n_bins, 2]`` array (~10^8 bytes a call on the
    felt) and no sums of squares. The sums are accumulated in ``means`` itself by :func:`_reduce_means`,
    the same additions in the same order as into ``bins`` (``0.0 + b_0 + b_1 ...``, then the division),
    so the means are bit-identical to ``bins[r, :, 0] / photons``.
    """
    sources = np.ascontiguousarray(sources, dtype=np.float64).reshape(-1, 5)
    seeds = np.ascontiguousarray(seeds, dtype=np.int64).reshape(-1)
    if sources.shape[0] != seeds.shape[0]:
        raise ValueError("execute_rows: one seed per source row")
    if inp.tally_mode == T.NONE and inp.vertex_mode == T.V_NONE:
        raise ValueError("execute_rows: runs with a tally or a vertex estimator only")
    n_rows = sources.shape[0]
    n_spec = inp.spec_mu.shape[0]
    n_vertex = inp.outputs.shape[0] if inp.vertex_mode != T.V_NONE else 0
    n_bins = max((inp.n_exit_bins + n_vertex) * n_spec, 1)
    n_batches = -(-photons // batch_size)
    # jobs in (row, batch) order: a run's batches are consecutive, reduced in batch order below
    job_row = np.repeat(np.arange(n_rows, dtype=np.int64), n_batches)
    job_batch = np.tile(np.arange(n_batches, dtype=np.int64), n_rows)
    n_jobs = job_row.size
    per_job = n_bins * 2 + T.N_SCALARS
    round_size = int(min(256, max(8, _ROUND_ELEMENTS // per_job)))
    scal_buf, bins_buf = _buffers(min(round_size, n_jobs), n_bins)
    scal = np.zeros((n_rows, T.N_SCALARS))
    bins = np.zeros((n_rows, n_bins, 2)) if means is None else None
    if means is not None:
        if means.shape[0] != n_rows or means.size != n_rows * n_bins or means.dtype != np.float64:
            raise ValueError(f"execute_rows: means must be float64 [{n_rows}, ...] with {n_bins} values a row")
        means6 = means.reshape(means.shape[:1] + (1,) * (6 - means.ndim) + means.shape[1:]) if means.ndim < 6 \
            else means
    previous = numba.get_num_threads()
    if threads is not None:
        limit = numba.config.NUMBA_NUM_THREADS
        if isinstance(threads, bool) or int(threads) != threads or not 1 <= int(threads) <= limit:
            raise ParameterError(f"threads must be an integer in [1, {limit}] (this machine), got {threads!r}")
        numba.set_num_threads(int(threads))
    runner = K.run_rows_for(inp)      # the dye profile's flavour when the run places its dye
    previous_chunk = numba.set_parallel_chunksize(1)
    try:
        t0 = time.perf_counter()
        threads_now = numba.get_num_threads()
        first, count = 0, min(round_size, max(2, threads_now))
        while first < n_jobs:
            count = min(count, n_jobs - first)
            t_round = time.perf_counter()
            runner(inp, sources, seeds, job_row[first:first + count], job_batch[first:first + count], photons,
                   batch_size, scal_buf, bins_buf)
            if bins is None:
                _reduce_means(job_row[first:first + count], job_batch[first:first + count], n_batches, photons,
                              scal_buf, bins_buf, scal, means6)
            else:
                for i in range(count):  # per run, batch order: the sums of transport.execute
                    r = job_row[first + i]
                    scal[r] += scal_buf[i]
                    bins[r] += bins_buf[i]
            first += count
            dt = max(time.perf_counter() - t_round, 1e-6)
            count = int(min(round_size, max(threads_now, count * ROUND_SECONDS / dt)))
        seconds = time.perf_counter() - t0
    finally:
        numba.set_parallel_chunksize(previous_chunk)
        numba.set_num_threads(previous)
    return scal, bins, seconds


@numba.njit(cache=True, nogil=True, parallel=True)
def _reduce_means(job_row, job_batch, n_batches, photons, scal_buf, bins_buf, scal, means):
    """:func:`execute_rows`'s reduction into ``means`` (``[R, a, b, c, d, e]``, any strides).

    Job ``i``'s scalars are added to its run's, its bin sums to the run's sums held in ``means`` (``0.0 +``
    the first batch, as ``bins`` starts at zero), divided by ``photons`` after the run's last batch.
    Compiled, parallel over the first bin axis (each value still sees its jobs in order) and without the
    GIL, so other threads run meanwhile.
    """
    R, A, B, C, D, E = means.shape
    for i in range(job_row.shape[0]):
        for s in range(scal.shape[1]):
            scal[job_row[i], s] += scal_buf[i, s]
    for a in numba.prange(A):
        for i in range(job_row.shape[0]):
            r = job_row[i]
            first = job_batch[i] == 0
            last = job_batch[i] == n_batches - 1
            j = a * B * C * D * E
            for b in range(B):
                for c in range(C):
                    for d in range(D):
                        row = means[r, a, b, c, d]
                        if first and last:
                            for e in range(E):
                                row[e] = (0.0 + bins_buf[i, j + e, 0]) / photons
                        elif first:
                            for e in range(E):
                                row[e] = 0.0 + bins_buf[i, j + e, 0]
                        elif last:
                            for e in range(E):
                                row[e] = (row[e] + bins_buf[i, j + e, 0]) / photons
                        else:
                            for e in range(E):
                                row[e] = row[e] + bins_buf[i, j + e, 0]
                        j += E
