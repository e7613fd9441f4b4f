"""Python API of the Monte Carlo photon transport: slab and cylinder runs.

:func:`run_slab` and :func:`run_cylinder` validate their inputs, pack them into the flat
arrays of the compiled kernel (:mod:`.kernel`), run the photon batches (in parallel over
batches, ``prange``), reduce the per-batch accumulators in batch order and return result
objects with values, standard errors, timing and the energy balance.

Units: ``mu_a``, ``mu_s`` (1/length) and ``thickness`` / ``radius`` (length) may use any
consistent length unit; only the optical depths ``mu_t d`` and ``mu_t R`` matter.

Estimates are means of per-photon scores ``X_j`` over ``N`` launched photons (every photon
exits at most once, so its score is its exit weight or 0)::

    X = (1/N) sum_j X_j        u(X) = sqrt( ((1/N) sum_j X_j^2 - X^2) / (N - 1) )

The slab results follow MCML: ``Rd`` is the diffuse reflectance WITHOUT the specular surface
reflection ``Rsp = F(theta_i)`` (that is the surface term, docs/physics.md section 5), ``Tt`` the
total transmittance (unscattered + diffuse). Determinism: batch ``b`` always holds the same
photons and uses stream ``(seed, b)``; rows are summed in batch order, so the numbers do not
depend on ``threads``.

Over 500 lines for a reason: the two public runs (slab, cylinder) share their validation, the
KernelInputs assembly and the energy bookkeeping line for line; the compiled kernel is being
changed beside it (numba cache) and this file is kept in one piece until that lands.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from simulate.montecarlo import geometry as G
from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.scatter import PHASE_TABLE, PhaseArrays, phase_arrays

__all__ = [
    "ParameterError",
    "EnergyBalance",
    "SlabAngular",
    "SlabResult",
    "CylinderAngular",
    "CylinderResult",
    "run_slab",
    "run_cylinder",
    "make_inputs",
    "execute",
    "SpectralTargets",
    "DEFAULT_BATCH_SIZE",
    "DEFAULT_MAX_EVENTS",
    "DEFAULT_WEIGHT_THRESHOLD",
    "DEFAULT_SURVIVAL",
    "make_control",
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


@dataclass(frozen=True)
class EnergyBalance:
    """Energy bookkeeping of a run, as fractions of the launched photons (weight 1 each).

    ``entered + roulette_gain = exited + absorbed + roulette_killed + capped_weight`` holds
    exactly (``residual`` is its rounding error); ``roulette_gain - roulette_killed`` is zero
    in expectation. ``specular + entered = 1``.
    """

    launched: int
    specular: float
    entered: float
    exited: float
    exited_by_face: tuple[float, ...]
    absorbed: float
    roulette_gain: float
    roulette_killed: float
    capped_weight: float
    u_roulette_balance: float = math.nan

    @property
    def roulette_balance(self) -> float:
        """Net weight added by Russian roulette (``gain - killed``, zero in expectation)."""
        return self.roulette_gain - self.roulette_killed

    @property
    def residual(self) -> float:
        """``entered + gain - exited - absorbed - killed - capped`` (rounding only)."""
        return (
            self.entered + self.roulette_gain - self.exited - self.absorbed
            - self.roulette_killed - self.capped_weight
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return {
            "launched": self.launched,
            "specular": self.specular,
            "entered": self.entered,
            "exited": self.exited,
            "exited_by_face": list(self.exited_by_face),
            "absorbed": self.absorbed,
            "roulette_gain": self.roulette_gain,
            "roulette_killed": self.roulette_killed,
            "roulette_balance": self.roulette_balance,
            "u_roulette_balance": self.u_roulette_balance,
            "capped_weight": self.capped_weight,
            "residual": self.residual,
        }


@dataclass(frozen=True)
class SlabAngular:
    """Exit weight of a slab run per direction bin (fractions of the launched photons).

    ``reflected[i, j]`` / ``transmitted[i, j]``: weight leaving the top / bottom face with
    ``mu = cos(theta_out)`` in ``[mu_edges[i], mu_edges[i+1])`` (relative to that face's
    outward normal) and azimuth ``atan2(w_y, w_x)`` in ``[phi_edges[j], phi_edges[j+1])``;
    ``u_*`` their standard errors. Each bin spans the solid angle
    ``d_omega = (mu_edges[i+1] - mu_edges[i]) * (phi_edges[j+1] - phi_edges[j])``.
    """

    mu_edges: np.ndarray
    phi_edges: np.ndarray
    reflected: np.ndarray
    u_reflected: np.ndarray
    transmitted: np.ndarray
    u_transmitted: np.ndarray


@dataclass(frozen=True)
class SlabResult:
    """Result of :func:`run_slab` (all fractions of the launched photons)."""

    Rd: float
    Tt: float
    u_Rd: float
    u_Tt: float
    Tu: float
    Rsp: float
    absorbed: float
    photons: int
    seconds: float
    events_per_photon: float
    scatterings_per_photon: float
    capped: int
    energy: EnergyBalance
    theta_i_deg: float
    seed: int
    angular: SlabAngular | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (the ``simulate slab --json`` object)."""
        return {
            "Rd": self.Rd,
            "Tt": self.Tt,
            "u_Rd": self.u_Rd,
            "u_Tt": self.u_Tt,
            "Tu": self.Tu,
            "Rsp": self.Rsp,
            "absorbed": self.absorbed,
            "photons": self.photons,
            "seconds": self.seconds,
            "events_per_photon": self.events_per_photon,
            "scatterings_per_photon": self.scatterings_per_photon,
            "capped": self.capped,
            "theta_i_deg": self.theta_i_deg,
            "seed": self.seed,
            "energy": self.energy.as_dict(),
        }


@dataclass(frozen=True)
class CylinderAngular:
    """Exit weight of a cylinder run per (psi, local direction) bin, fractions of launched photons.

    ``exits[k, i, j]``: weight leaving through the surface cell ``k`` (azimuth ``psi`` within
    half a cell width ``2 pi / n_psi`` of ``psi_centers[k] = 2 pi k / n_psi``; cell 0 is the
    top) with ``mu = w . n(psi)`` in ``[mu_edges[i], mu_edges[i+1])`` and local azimuth
    ``phi = atan2(w . b, w . t)`` in ``[phi_edges[j], phi_edges[j+1])`` (frame
    ``(n(psi), t = x, b = n x t)``, see :mod:`.geometry`); ``u_exits`` its standard error.
    """

    psi_centers: np.ndarray
    mu_edges: np.ndarray
    phi_edges: np.ndarray
    exits: np.ndarray
    u_exits: np.ndarray


@dataclass(frozen=True)
class CylinderResult:
    """Result of :func:`run_cylinder` (fractions of the launched photons).

    In ``"beam"`` mode the launched photons are the power of a parallel beam intercepted by
    the projected width of the cylinder; in ``"point"`` mode the power arriving at the cell
    A (``psi = 0``). ``exited`` excludes the specular surface reflection ``specular``.
    """

    exited: float
    u_exited: float
    unscattered: float
    specular: float
    absorbed: float
    photons: int
    seconds: float
    events_per_photon: float
    scatterings_per_photon: float
    capped: int
    energy: EnergyBalance
    direction: tuple[float, float, float]
    source: str
    seed: int
    angular: CylinderAngular | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary of the scalar results."""
        return {
            "exited": self.exited,
            "u_exited": self.u_exited,
            "unscattered": self.unscattered,
            "specular": self.specular,
            "absorbed": self.absorbed,
            "photons": self.photons,
            "seconds": self.seconds,
            "events_per_photon": self.events_per_photon,
            "scatterings_per_photon": self.scatterings_per_photon,
            "capped": self.capped,
            "direction": list(self.direction),
            "source": self.source,
            "seed": self.seed,
            "energy": self.energy.as_dict(),
        }


# ----------------------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------------------


def _finite_nonneg(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        raise ParameterError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def _finite_pos(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def _positive_int(name: str, value: int, upper: int = 2**62) -> int:
    if isinstance(value, bool) or int(value) != value or not 1 <= int(value) <= upper:
        raise ParameterError(f"{name} must be an integer in [1, {upper}], got {value!r}")
    return int(value)


def _medium(mu_a: float, mu_s: float, g: float | None, phase_table: Any, n: float) -> tuple[np.ndarray, PhaseArrays]:
    mu_a = _finite_nonneg("mu_a", mu_a)
    mu_s = _finite_nonneg("mu_s", mu_s)
    n = _finite_pos("n", n)
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

    Cell ``j`` spans the half-way points between neighbouring nodes; ``[n_grid, L]``.
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
    control[K.C_WEIGHT_THRESHOLD] = _finite_nonneg("weight_threshold", weight_threshold)
    s = float(survival)
    if not 0.0 < s <= 1.0:
        raise ParameterError(f"survival must be in (0, 1], got {survival!r}")
    control[K.C_SURVIVAL] = s
    control[K.C_MAX_EVENTS] = _positive_int("max_events", max_events, 2**52)
    return control


def _stderr(total: float, total_sq: float, n: int) -> float:
    if n < 2:
        return math.nan
    mean = total / n
    return math.sqrt(max(total_sq / n - mean * mean, 0.0) / (n - 1))


def _bins_stderr(sums: np.ndarray, sums_sq: np.ndarray, n: int) -> np.ndarray:
    if n < 2:
        return np.full_like(sums, np.nan)
    mean = sums / n
    return np.sqrt(np.maximum(sums_sq / n - mean * mean, 0.0) / (n - 1))


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


def _energy(scal: np.ndarray, faces: int) -> EnergyBalance:
    n = scal[T.S_LAUNCHED]
    by_face = (scal[T.S_EXIT0] / n, scal[T.S_EXIT1] / n)[:faces]
    return EnergyBalance(
        launched=int(n),
        specular=scal[T.S_SPECULAR] / n,
        entered=scal[T.S_ENTERED] / n,
        exited=(scal[T.S_EXIT0] + scal[T.S_EXIT1]) / n,
        exited_by_face=tuple(float(v) for v in by_face),
        absorbed=scal[T.S_ABSORBED] / n,
        roulette_gain=scal[T.S_ROULETTE_GAIN] / n,
        roulette_killed=scal[T.S_ROULETTE_KILLED] / n,
        capped_weight=scal[T.S_CAPPED_WEIGHT] / n,
        u_roulette_balance=_stderr(scal[T.S_ROULETTE_GAIN] - scal[T.S_ROULETTE_KILLED], scal[T.S_ROULETTE_NET_SQ], int(n)),
    )


def _log_cap(scal: np.ndarray, max_events: int) -> int:
    capped = int(scal[T.S_CAPPED])
    if capped:
        log.warning(
            "%d of %d photons reached the event cap (max_events=%d) and were stopped; "
            "their weight %.3g is reported as energy.capped_weight",
            capped, int(scal[T.S_LAUNCHED]), max_events, scal[T.S_CAPPED_WEIGHT] / scal[T.S_LAUNCHED],
        )
    return capped


def run_slab(
    mu_a: float,
    mu_s: float,
    g: float | None = None,
    phase_table: Any = None,
    n: float = 1.0,
    thickness: float = 1.0,
    photons: int = 100_000,
    seed: int = 0,
    theta_i_deg: float = 0.0,
    threads: int | None = None,
    angular_bins: tuple[int, int] | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
    max_events: int = DEFAULT_MAX_EVENTS,
    weight_threshold: float = DEFAULT_WEIGHT_THRESHOLD,
    survival: float = DEFAULT_SURVIVAL,
) -> SlabResult:
    r"""Diffuse reflectance and total transmittance of a slab in air (docs/physics.md section 3).

    The slab ``-d <= z <= 0`` (index ``n``, outside index 1) is lit at its top face by a
    collimated beam at polar angle ``theta_i`` in the x-z plane. Each photon refracts in with
    weight ``1 - F(theta_i)``, walks with exponential free paths (mean ``1 / mu_t``), implicit
    capture ``w *= mu_s / mu_t`` and Russian roulette, and leaves with Fresnel/Snell at the faces.

    Parameters
    ----------
    mu_a, mu_s : float
        Absorption and scattering coefficients (1/length, >= 0).
    g : float, optional
        Henyey-Greenstein asymmetry in (-1, 1); isotropic when neither ``g`` nor
        ``phase_table`` is given.
    phase_table : PhaseTable or array_like, optional
        Inverse-CDF table ``cos_table`` (``simulate.optics.phase.PhaseTable`` or the array itself).
    n : float
        Refractive index of the slab (outside: 1).
    thickness : float
        Slab thickness ``d`` (length, same unit as ``1/mu``).
    photons : int
        Photons launched.
    seed : int
        Seed of the random streams (>= 0).
    theta_i_deg : float
        Incidence angle in degrees, in [0, 90); 90 (grazing) is an error: no light enters.
    threads : int, optional
        Threads for this run (default: numba's current setting). Results do not depend on it.
    angular_bins : (int, int), optional
        ``(n_mu, n_phi)``: also tally exits per direction bin (:class:`SlabAngular`).
    batch_size : int
        Photons per batch (part of the definition of the random streams).
    max_events : int
        Cap on free-path steps per photon (a guard; capped photons are counted).
    weight_threshold, survival : float
        Russian roulette below ``weight_threshold``: survive with probability ``survival``.

    Returns
    -------
    SlabResult
        ``Rd`` (without the specular ``Rsp``), ``Tt`` (= unscattered ``Tu`` + diffuse),
        standard errors ``u_Rd``, ``u_Tt``, timing, events per photon, capped count and the
        energy balance.

    Raises
    ------
    ParameterError
        (a ``ValueError``) on invalid parameters; the message names the parameter.

    Examples
    --------
    >>> r = run_slab(10.0, 90.0, g=0.75, n=1.0, thickness=0.02, photons=20_000, seed=1)
    >>> abs(r.Rd - 0.09739) < 5 * r.u_Rd and abs(r.Tt - 0.66096) < 5 * r.u_Tt
    True
    """
    medium, walk_phase = _medium(mu_a, mu_s, g, phase_table, n)
    d = _finite_pos("thickness", thickness)
    photons = _positive_int("photons", photons)
    batch_size = _positive_int("batch_size", batch_size)
    if isinstance(seed, bool) or int(seed) != seed or not 0 <= int(seed) < 2**63:
        raise ParameterError(f"seed must be an integer in [0, 2^63), got {seed!r}")
    theta = float(theta_i_deg)
    if not math.isfinite(theta) or not 0.0 <= theta <= 90.0:
        raise ParameterError(f"theta_i_deg must be in [0, 90) degrees, got {theta_i_deg!r}")
    if theta == 90.0:
        raise ParameterError(
            "theta_i_deg = 90 is grazing incidence: no light crosses the surface; use an angle below 90"
        )
    control = make_control(max_events, weight_threshold, survival)
    t = math.radians(theta)
    source = np.array([0.0, math.sin(t), 0.0, math.cos(t)])
    if angular_bins is None:
        mode, params = T.NONE, np.zeros(1)
    else:
        n_mu, n_phi = (_positive_int("angular_bins", int(v), 100_000) for v in angular_bins)
        mode, params = T.SLAB_DIRECTIONS, np.array([float(n_mu), float(n_phi)])
    inp = make_inputs(G.SLAB, np.array([d]), source, medium, walk_phase, control, mode, params)
    scal, bins, seconds = execute(inp, photons, int(seed), threads, batch_size)
    capped = _log_cap(scal, int(control[K.C_MAX_EVENTS]))
    angular = None
    if mode == T.SLAB_DIRECTIONS:
        n_mu, n_phi = int(params[0]), int(params[1])
        s = bins[:, 0].reshape(2, n_mu, n_phi)
        s2 = bins[:, 1].reshape(2, n_mu, n_phi)
        u = _bins_stderr(s, s2, photons)
        angular = SlabAngular(
            mu_edges=np.linspace(0.0, 1.0, n_mu + 1),
            phi_edges=np.linspace(-math.pi, math.pi, n_phi + 1),
            reflected=s[0] / photons,
            u_reflected=u[0],
            transmitted=s[1] / photons,
            u_transmitted=u[1],
        )
    return SlabResult(
        Rd=scal[T.S_EXIT0] / photons,
        Tt=scal[T.S_EXIT1] / photons,
        u_Rd=_stderr(scal[T.S_EXIT0], scal[T.S_EXIT0_SQ], photons),
        u_Tt=_stderr(scal[T.S_EXIT1], scal[T.S_EXIT1_SQ], photons),
        Tu=scal[T.S_UNSCATTERED1] / photons,
        Rsp=scal[T.S_SPECULAR] / photons,
        absorbed=scal[T.S_ABSORBED] / photons,
        photons=photons,
        seconds=seconds,
        events_per_photon=scal[T.S_EVENTS] / photons,
        scatterings_per_photon=scal[T.S_SCATTERINGS] / photons,
        capped=capped,
        energy=_energy(scal, 2),
        theta_i_deg=theta,
        seed=int(seed),
        angular=angular,
    )


def run_cylinder(
    mu_a: float,
    mu_s: float,
    g: float | None = None,
    phase_table: Any = None,
    n: float = 1.0,
    radius: float = 1.0,
    photons: int = 100_000,
    seed: int = 0,
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0),
    source: str = "beam",
    threads: int | None = None,
    angular_bins: tuple[int, int, int] | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
    max_events: int = DEFAULT_MAX_EVENTS,
    weight_threshold: float = DEFAULT_WEIGHT_THRESHOLD,
    survival: float = DEFAULT_SURVIVAL,
    dye_profile: tuple[str, float] | None = None,
) -> CylinderResult:
    r"""Photon transport in an infinite circular cylinder (a fiber) with axis ``t = +x``.

    Parameters
    ----------
    mu_a, mu_s, g, phase_table, n
        As in :func:`run_slab`.
    radius : float
        Cylinder radius ``R`` (length).
    photons, seed, threads, batch_size, max_events, weight_threshold, survival
        As in :func:`run_slab`.
    direction : (float, float, float)
        Unit vector ``w_i`` towards the light, in the fiber frame (x = axis, z = normal at
        ``psi = 0``); photons travel along ``-w_i``. Normalised here.
    source : {"beam", "point"}
        ``"beam"``: parallel beam, impact parameter uniform over the projected width
        ``[-R, R]`` (direct beam estimator); ``w_i`` must not be parallel to the axis.
        ``"point"``: all photons enter at ``psi = 0, v = 0``; requires ``w_i . z > 0``.
    angular_bins : (int, int, int), optional
        ``(n_psi, n_mu, n_phi)``: tally exits per ``psi`` x local direction bin
        (:class:`CylinderAngular`).
    dye_profile : (str, float), optional
        ``("ring", a)``: ``mu_a`` absorbs only beyond the radius ``a`` of the axis (a ring-dyed fiber);
        ``("core", a)``: only within it. The photons then walk white (``mu_a = 0``) and carry the absorption
        of their path's dyed length as a weight (:mod:`.kernel`, "Dye profile"); ``exited`` is read from the
        exit bins (``angular_bins``, default one bin), the walk's own bookkeeping (``absorbed``, ``energy``)
        is the white walk's.

    Returns
    -------
    CylinderResult
        Exited fraction (without the specular reflection) with standard error, unscattered
        part, timing, events per photon, capped count, energy balance and optional bins.

    Raises
    ------
    ParameterError
        (a ``ValueError``) on invalid parameters; the message names the parameter.
    """
    medium, walk_phase = _medium(mu_a, mu_s, g, phase_table, n)
    r = _finite_pos("radius", radius)
    photons = _positive_int("photons", photons)
    batch_size = _positive_int("batch_size", batch_size)
    if isinstance(seed, bool) or int(seed) != seed or not 0 <= int(seed) < 2**63:
        raise ParameterError(f"seed must be an integer in [0, 2^63), got {seed!r}")
    w = np.asarray(direction, dtype=float)
    if w.shape != (3,) or not np.all(np.isfinite(w)) or np.linalg.norm(w) == 0.0:
        raise ParameterError(f"direction must be a finite non-zero 3-vector, got {direction!r}")
    w = w / np.linalg.norm(w)
    if source == "beam":
        if math.hypot(w[1], w[2]) < 1e-12:
            raise ParameterError("direction is parallel to the cylinder axis: a beam along the axis never enters")
        mode_code = G.BEAM
    elif source == "point":
        if not w[2] > 0.0:
            raise ParameterError(
                "direction must point above the tangent plane at psi = 0 (w_z > 0) for source='point'; "
                "w_z = 0 is grazing incidence"
            )
        mode_code = G.POINT
    else:
        raise ParameterError(f"source must be 'beam' or 'point', got {source!r}")
    control = make_control(max_events, weight_threshold, survival)
    src = np.array([float(mode_code), w[0], w[1], w[2]])
    if angular_bins is None:
        mode, params = T.NONE, np.zeros(1)
    else:
        n_psi, n_mu, n_phi = (_positive_int("angular_bins", int(v), 100_000) for v in angular_bins)
        mode, params = T.CYLINDER_DIRECTIONS, np.array([float(n_psi), float(n_mu), float(n_phi), 1.0, 1.0])
    targets = None
    if dye_profile is not None:
        kind, a = dye_profile if isinstance(dye_profile, tuple) and len(dye_profile) == 2 else (None, None)
        if kind not in ("ring", "core") or not (isinstance(a, (int, float)) and 0.0 < a < r):
            raise ParameterError(f"dye_profile must be ('ring' or 'core', inner radius in (0, radius)), got {dye_profile!r}")
        mu_a_t = float(medium[K.M_MU_A])
        medium[K.M_MU_A] = 0.0
        medium[K.M_DYE_PROFILE] = K.DYE_RING if kind == "ring" else K.DYE_CORE
        medium[K.M_DYE_RADIUS] = float(a)
        targets = SpectralTargets(mu_a=np.array([mu_a_t]), mu_s=np.array([float(medium[K.M_MU_S])]),
                                  phases=[walk_phase], same_phase=np.array([True]), mu_a_dye=np.array([mu_a_t]))
        if mode == T.NONE:
            mode, params = T.CYLINDER_DIRECTIONS, np.array([1.0, 1.0, 1.0, 1.0, 1.0])
    inp = make_inputs(G.CYLINDER, np.array([r]), src, medium, walk_phase, control, mode, params, targets=targets)
    scal, bins, seconds = execute(inp, photons, int(seed), threads, batch_size)
    capped = _log_cap(scal, int(control[K.C_MAX_EVENTS]))
    angular = None
    if mode == T.CYLINDER_DIRECTIONS:
        shape = (int(params[0]), int(params[1]), int(params[2]))
        s = bins[:, 0].reshape(shape)
        s2 = bins[:, 1].reshape(shape)
        angular = CylinderAngular(
            psi_centers=2.0 * math.pi * np.arange(shape[0]) / shape[0],
            mu_edges=np.linspace(0.0, 1.0, shape[1] + 1),
            phi_edges=np.linspace(-math.pi, math.pi, shape[2] + 1),
            exits=s / photons,
            u_exits=_bins_stderr(s, s2, photons),
        )
    exited, u_exited = scal[T.S_EXIT0] / photons, _stderr(scal[T.S_EXIT0], scal[T.S_EXIT0_SQ], photons)
    if targets is not None:      # the profile's absorption is in the bins' weights (a photon exits in one bin)
        exited, u_exited = float(bins[:, 0].sum()) / photons, _stderr(float(bins[:, 0].sum()), float(bins[:, 1].sum()), photons)
    return CylinderResult(
        exited=exited,
        u_exited=u_exited,
        unscattered=scal[T.S_UNSCATTERED0] / photons,
        specular=scal[T.S_SPECULAR] / photons,
        absorbed=scal[T.S_ABSORBED] / photons,
        photons=photons,
        seconds=seconds,
        events_per_photon=scal[T.S_EVENTS] / photons,
        scatterings_per_photon=scal[T.S_SCATTERINGS] / photons,
        capped=capped,
        energy=_energy(scal, 1),
        direction=(float(w[0]), float(w[1]), float(w[2])),
        source=source,
        seed=int(seed),
        angular=angular,
    )
