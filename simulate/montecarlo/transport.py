"""The Monte Carlo's run machinery: validated inputs, the kernel's input record, the batches.

What every estimator of the package shares (the slab and cylinder runs of :mod:`.slab` and
:mod:`.cylinder`, the fiber tables, the yarn tables, the accuracy-controlled runs): the checks of a
run's parameters (:class:`ParameterError`), :func:`make_control` (one event cap, one roulette rule),
:func:`make_inputs` (the flat arrays of the compiled kernel, :mod:`.kernel`, with the re-weighted
wavelengths of :class:`SpectralTargets`) and :func:`execute`, which runs the photon batches (in
parallel over batches, ``prange``) and sums the per-batch accumulators in batch order.

Units: ``mu_a``, ``mu_s`` (1/length) and ``thickness`` / ``radius`` (length) may use any
consistent length unit; only the optical depths ``mu_t d`` and ``mu_t R`` matter.

Estimates are means of per-photon scores ``X_j`` over ``N`` launched photons (every photon
exits at most once, so its score is its exit weight or 0)::

    X = (1/N) sum_j X_j        u(X) = sqrt( ((1/N) sum_j X_j^2 - X^2) / (N - 1) )

Determinism: batch ``b`` always holds the same photons and uses stream ``(seed, b)``; rows are
summed in batch order, so the numbers do not depend on ``threads``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.scatter import PHASE_TABLE, PhaseArrays, phase_arrays

__all__ = [
    "ParameterError",
    "make_inputs",
    "execute",
    "SpectralTargets",
    "phase_ratio_table",
    "DEFAULT_BATCH_SIZE",
    "DEFAULT_MAX_EVENTS",
    "DEFAULT_WEIGHT_THRESHOLD",
    "DEFAULT_SURVIVAL",
    "ROUND_SECONDS",
    "make_control",
    "finite_nonneg",
    "finite_pos",
    "positive_int",
    "medium_row",
    "log_cap",
]

log = logging.getLogger(__name__)


class ParameterError(ValueError):
    """An invalid run parameter (a user error; the message names the parameter)."""


DEFAULT_BATCH_SIZE = 10_000
DEFAULT_MAX_EVENTS = 1_000_000  # the one event cap (slab, cylinder, fiber, yarn tables); a guard, rarely reached
DEFAULT_WEIGHT_THRESHOLD = 1e-4
DEFAULT_SURVIVAL = 0.1
_ROUND_ELEMENTS = 1 << 22  # cap on per-round bin buffer elements (32 MB)
#: Target wall time of one compiled round of :func:`execute` (the interrupt latency); the first
#: round of a call is ``_FIRST_ROUND_BATCHES`` batches (at least one per thread), later ones are
#: sized from the last's time (at least one batch per thread).
ROUND_SECONDS = 0.25
_FIRST_ROUND_BATCHES = 2


def finite_nonneg(name: str, value: float) -> float:
    """``value`` as a float, or :class:`ParameterError` naming ``name`` unless finite and >= 0."""
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        raise ParameterError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def finite_pos(name: str, value: float) -> float:
    """``value`` as a float, or :class:`ParameterError` naming ``name`` unless finite and > 0."""
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def positive_int(name: str, value: int, upper: int = 2**62) -> int:
    """``value`` as an int, or :class:`ParameterError` naming ``name`` unless a whole number in [1, upper]."""
    if isinstance(value, bool) or int(value) != value or not 1 <= int(value) <= upper:
        raise ParameterError(f"{name} must be an integer in [1, {upper}], got {value!r}")
    return int(value)


def medium_row(mu_a: float, mu_s: float, g: float | None, phase_table: Any, n: float) -> tuple[np.ndarray, PhaseArrays]:
    """The kernel's medium row and the walk's phase function, from validated coefficients, index and phase."""
    mu_a = finite_nonneg("mu_a", mu_a)
    mu_s = finite_nonneg("mu_s", mu_s)
    n = finite_pos("n", n)
    if phase_table is not None and g is not None:
        raise ParameterError("give either g (Henyey-Greenstein) or phase_table, not both")
    if phase_table is None:
        g = 0.0 if g is None else float(g)
        if not math.isfinite(g) or not -1.0 < g < 1.0:
            raise ParameterError(f"g must be in (-1, 1), got {g!r}")
        arrays = phase_arrays(g=g)
    else:
        table = np.array(getattr(phase_table, "cos_table", phase_table), dtype=np.float64, order="C", copy=True)
        if table.ndim != 1 or table.size < 2:
            raise ParameterError("phase_table.cos_table must be a 1-D array of at least 2 values")
        if not np.all(np.isfinite(table)) or table[0] < -1.0 or table[-1] > 1.0 or np.any(np.diff(table) < 0):
            raise ParameterError("phase_table.cos_table must be finite, non-decreasing and within [-1, 1]")
        arrays = phase_arrays(cos_table=table)
    medium = np.zeros(K.N_MEDIUM)
    medium[K.M_MU_A] = mu_a
    medium[K.M_MU_S] = mu_s
    medium[K.M_G] = arrays.g
    medium[K.M_N] = n
    medium[K.M_PHASE] = arrays.kind
    return medium, arrays


@dataclass(frozen=True)
class SpectralTargets:
    """Target media of a re-weighted ("white") run: one row per wavelength.

    Attributes
    ----------
    mu_a, mu_s : numpy.ndarray
        ``[L]`` coefficients of each target wavelength.
    phases : list of PhaseArrays
        Phase function of each target (all of one kind and table size).
    same_phase : numpy.ndarray
        ``bool[L]``: the target's phase function is the walk's (no phase ratio needed).
    mu_a_dye : numpy.ndarray or None
        ``[L]`` the part of ``mu_a`` that the walk medium's dye profile places (``medium[M_DYE_PROFILE]``,
        :mod:`.kernel`, "Dye profile"); None: no profile (the whole ``mu_a`` is uniform).
    """

    mu_a: np.ndarray
    mu_s: np.ndarray
    phases: list[PhaseArrays]
    same_phase: np.ndarray
    mu_a_dye: np.ndarray | None = None


RATIO_GRID = 1025


def _cell_probabilities(pa: PhaseArrays, mu_edges: np.ndarray) -> np.ndarray:
    """Probability of each ``mu`` cell under a phase function (exact CDF of the table or of HG)."""
    if pa.kind == PHASE_TABLE:
        K_int = pa.table.size - 1
        cdf = np.interp(mu_edges, pa.table, np.arange(K_int + 1) / K_int)
    elif pa.g == 0.0:
        cdf = 0.5 * (mu_edges + 1.0)
    else:
        g = pa.g
        cdf = (1 - g * g) / (2 * g) * (1 / np.sqrt(1 + g * g - 2 * g * mu_edges) - 1 / (1 + g))
    return np.diff(cdf)


def phase_ratio_table(walk: PhaseArrays, targets: list[PhaseArrays], n_grid: int = RATIO_GRID) -> np.ndarray:
    """``p^l / p^w`` at the nodes ``t_j = j / (n - 1)``, ``mu = 1 - 2 t^2``, as ratios of cell probabilities.

    Cell ``j`` spans the half-way points between neighbouring nodes; ``[n_grid, L]``. The grid is uniform
    in ``t = sqrt((1 - mu) / 2)``, dense in the forward peak, and holds every wavelength's value of a node
    on one cache line, so a collision costs the kernel one look-up (linear interpolation) for all
    wavelengths instead of one table search per wavelength. It re-weights towards the cell-averaged target
    density, which differs from the target's own sampling table only by that table's discretisation.
    """
    t = np.linspace(0.0, 1.0, n_grid)
    t_edges = np.concatenate(([0.0], 0.5 * (t[1:] + t[:-1]), [1.0]))
    mu_edges = np.sort(1.0 - 2.0 * t_edges ** 2)  # increasing mu
    p_w = _cell_probabilities(walk, mu_edges)[::-1]  # back to increasing t
    out = np.ones((n_grid, len(targets)))
    for l, pa in enumerate(targets):
        p_l = _cell_probabilities(pa, mu_edges)[::-1]
        with np.errstate(divide="ignore", invalid="ignore"):
            out[:, l] = np.where(p_w > 0, p_l / np.where(p_w > 0, p_w, 1.0), 0.0)
    return np.ascontiguousarray(out)


def _spectral_arrays(targets: SpectralTargets | None, medium: np.ndarray, walk_phase: PhaseArrays):
    if targets is None:
        return False, np.array([[medium[K.M_MU_A], medium[K.M_MU_S]]]), False, np.ones((2, 1))
    columns = [targets.mu_a, targets.mu_s] + ([] if targets.mu_a_dye is None else [targets.mu_a_dye])
    mu = np.ascontiguousarray(np.stack(columns, axis=1), dtype=np.float64)
    same = np.asarray(targets.same_phase, dtype=np.bool_)
    if np.all(same):
        return True, mu, False, np.ones((2, mu.shape[0]))
    return True, mu, True, phase_ratio_table(walk_phase, list(targets.phases))


def make_inputs(
    geometry: int,
    geom: np.ndarray,
    source: np.ndarray,
    medium: np.ndarray,
    walk_phase: PhaseArrays,
    control: np.ndarray,
    tally_mode: int = T.NONE,
    tally_params: np.ndarray | None = None,
    vertex_mode: int = T.V_NONE,
    outputs: np.ndarray | None = None,
    targets: SpectralTargets | None = None,
) -> K.KernelInputs:
    """Pack a run's inputs into the kernel's :class:`~.kernel.KernelInputs` record (validated upstream)."""
    tally_params = np.zeros(1) if tally_params is None else np.ascontiguousarray(tally_params, dtype=np.float64)
    outputs = np.zeros((0, 8)) if outputs is None else np.ascontiguousarray(outputs, dtype=np.float64)
    reweight, mu, phase_ratio, ratio = _spectral_arrays(targets, medium, walk_phase)
    src = np.zeros(5)
    src[: len(source)] = source
    if vertex_mode != T.V_NONE and medium.shape[0] > K.M_ROUGH_B and max(medium[K.M_ROUGH], medium[K.M_ROUGH_B]) > 0.0:
        raise ParameterError("a rough boundary for transmitted light (transmission_rms_slope > 0) is walked with "
                             "exit tallies only: the next-event vertex estimators assume the smooth boundary; "
                             "use the exit-tally route (the woven/felt yarn tables) or transmission_rms_slope = 0")
    if medium.shape[0] > K.M_DYE_PROFILE and medium[K.M_DYE_PROFILE] != K.DYE_UNIFORM:
        if vertex_mode != T.V_NONE:
            raise ParameterError("a dye profile (ring or core) is walked with exit tallies only: the next-event "
                                 "vertex estimators assume a uniform dye; use the exit-tally route (the woven/felt "
                                 "yarn tables) or the uniform profile")
        if targets is None or targets.mu_a_dye is None or geometry == G.SLAB:
            raise ParameterError("a dye profile (ring or core) needs a cylinder and spectral targets that name the "
                                 "dye's absorption (SpectralTargets.mu_a_dye)")
    if medium.shape[0] > K.M_SCAT_PROFILE and medium[K.M_SCAT_PROFILE] != K.SCAT_UNIFORM:
        if vertex_mode != T.V_NONE:
            raise ParameterError("a scatterer profile (skin or core) is walked with exit tallies only: the next-event "
                                 "vertex estimators assume scatterers through the fiber; use the beam route "
                                 "([fiber] route = \"beam\") or the uniform profile")
        if geometry == G.SLAB:
            raise ParameterError("a scatterer profile (skin or core) needs a cylinder")
    consts = np.zeros((outputs.shape[0], T.N_NEE))
    if vertex_mode != T.V_NONE:
        for o in range(outputs.shape[0]):
            if outputs[o, 4] == outputs[o, 3] and outputs[o, 6] == outputs[o, 5]:  # point direction
                T.nee_constants(outputs[o, 3], outputs[o, 5], float(medium[K.M_N]), float(geom[0]), consts[o])
    return K.KernelInputs(
        int(geometry), np.ascontiguousarray(geom, dtype=np.float64), src, np.ascontiguousarray(medium),
        walk_phase.table, walk_phase.pdf, walk_phase.lookup, control, int(tally_mode), tally_params,
        int(vertex_mode), outputs, int(T.bin_count(tally_mode, tally_params)), bool(reweight),
        mu, bool(phase_ratio), ratio, consts,
    )


def make_control(max_events: int = DEFAULT_MAX_EVENTS, weight_threshold: float = DEFAULT_WEIGHT_THRESHOLD,
                 survival: float = DEFAULT_SURVIVAL) -> np.ndarray:
    """The kernel's control row (``K.N_CONTROL``): event cap, roulette threshold and survival.

    Every Monte Carlo estimator of the package builds its control here (one event cap, one
    roulette rule); the defaults are those of all fiber, yarn-table and fabric runs.
    """
    control = np.zeros(K.N_CONTROL)
    control[K.C_WEIGHT_THRESHOLD] = finite_nonneg("weight_threshold", weight_threshold)
    s = float(survival)
    if not 0.0 < s <= 1.0:
        raise ParameterError(f"survival must be in (0, 1], got {survival!r}")
    control[K.C_SURVIVAL] = s
    control[K.C_MAX_EVENTS] = positive_int("max_events", max_events, 2**52)
    return control


def execute(
    inp: K.KernelInputs,
    photons: int,
    seed: int,
    threads: int | None,
    batch_size: int,
    first_batch: int = 0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Run ``photons`` photons (batches from ``first_batch`` on); return (scalar sums, bin sums, seconds).

    ``bins`` has ``n_spec x (exit bins + vertex outputs)`` rows of ``(sum, sum of squares)``.
    Batches are numbered globally, so a run continued with ``first_batch`` = the batches done
    so far draws fresh, reproducible streams (accuracy-controlled runs add batches this way).
    """
    n_spec = inp.spec_mu.shape[0]
    n_vertex = inp.outputs.shape[0] if inp.vertex_mode != T.V_NONE else 0
    n_bins = max((inp.n_exit_bins + n_vertex) * n_spec, 1)
    total = first_batch * batch_size + photons
    n_batches = -(-photons // batch_size)
    per_batch = n_bins * 2 + T.N_SCALARS
    round_size = int(min(256, max(8, _ROUND_ELEMENTS // per_batch)))
    scal_buf = np.zeros((min(round_size, n_batches), T.N_SCALARS))
    bins_buf = np.zeros((min(round_size, n_batches), n_bins, 2))
    scal = np.zeros(T.N_SCALARS)
    bins = np.zeros((n_bins, 2))
    previous = numba.get_num_threads()
    if threads is not None:
        limit = numba.config.NUMBA_NUM_THREADS
        if isinstance(threads, bool) or int(threads) != threads or not 1 <= int(threads) <= limit:
            raise ParameterError(f"threads must be an integer in [1, {limit}] (this machine), got {threads!r}")
        numba.set_num_threads(int(threads))
    # dynamic scheduling, one batch per chunk: a thread slowed by other load takes fewer
    # batches (results do not depend on which thread ran a batch)
    previous_chunk = numba.set_parallel_chunksize(1)
    scoring = inp.tally_mode != T.NONE or inp.vertex_mode != T.V_NONE
    kernel = K.run_batches_for(inp)
    try:
        t0 = time.perf_counter()
        threads_now = numba.get_num_threads()
        first, count = 0, min(round_size, max(_FIRST_ROUND_BATCHES, threads_now))
        while first < n_batches:
            count = min(count, n_batches - first)
            t_round = time.perf_counter()
            kernel(inp, total, batch_size, first_batch + first, count, seed, scal_buf, bins_buf)
            for r in range(count):  # batch order: thread-count independent sums
                scal += scal_buf[r]
                if scoring:
                    bins += bins_buf[r]
            first += count
            # rounds of ~ROUND_SECONDS: a compiled round holds the interpreter, so Ctrl-C (and any
            # progress display) waits for it; the sums do not depend on how batches are cut in rounds
            dt = max(time.perf_counter() - t_round, 1e-6)
            count = int(min(round_size, max(threads_now, count * ROUND_SECONDS / dt)))
        seconds = time.perf_counter() - t0
    finally:
        numba.set_parallel_chunksize(previous_chunk)
        numba.set_num_threads(previous)
    return scal, bins, seconds


def log_cap(scal: np.ndarray, max_events: int) -> int:
    """The number of photons stopped by the event cap, logged as a warning when there are any."""
    capped = int(scal[T.S_CAPPED])
    if capped:
        log.warning(
            "%d of %d photons reached the event cap (max_events=%d) and were stopped; "
            "their weight %.3g is reported as energy.capped_weight",
            capped, int(scal[T.S_LAUNCHED]), max_events, scal[T.S_CAPPED_WEIGHT] / scal[T.S_LAUNCHED],
        )
    return capped
