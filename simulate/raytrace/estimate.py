"""A fibre assembly (a weave or a felt) at a plan's geometries: the entry of ``simulate fabric --method mc``.

Two independent halves of the yarn table, one trace per incidence with each, the table's own
noise from their difference added to ``u_beta``; the target's error shared between the table
(:data:`TABLE_SHARE`) and the rays (:func:`ray_target`).

A felt
------
A felt's mesh (:mod:`simulate.geometry.felt`) is ONE random realisation of its fibers in a cell of
about 20 fibers across, and what is wanted is the felt's BRDF, the expectation over realisations (as
a measurement's spot averages thousands of fibers). Traced as a weave (one mesh, one azimuth), one
realisation's run would report a standard error well below the spread between realisations. Two
changes, both free in expectation:

- the felt is in-plane isotropic, so each incidence and its detectors are turned about the normal
  to ``N`` = :data:`FELT_ROTATIONS` azimuths and the traces averaged: the top fibers' few orientations
  are seen at ``N`` angles.
  The ``N`` rotations are traced as one wavefront (:func:`simulate.raytrace.integrator.trace_rotations`:
  ``N`` times smaller chunks of each, every bounce one Embree query for all of them), stopped when
  their mean reaches the ray target; the scene is built once per mesh;
- the felt is traced on ``K`` independent realisations (``mesh`` a tuple of ``K``, an even number;
  ``simulate fabric`` builds them at the run's seed plus :data:`simulate.products.FELT_SEED_STRIDE` times
  ``0 .. K - 1``, ``[method] felt_realisations``), realisation ``j`` with table half ``j mod 2``, at the
  rotations ``2 pi (i + j / K) / N``, each traced to ``sqrt(K / 2)`` times a half's ray target
  (the same rays in all). ``beta`` is their mean and ``u_beta`` comes from their spread
  (:func:`combine_realisations`): it holds the spread between realisations, so it predicts the spread
  between seeds (``tests/simulate/raytrace/test_felt.py``; measured, with what the realisations' count
  costs and gains: docs/notes/felt-structure.md 8, "The Monte Carlo noise").

What these choices cost and gain, measured: docs/notes/implementation.md, "The ray tracer's felt".
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from simulate.budget import medium_coefficients
from simulate.fabric.structure import CLOSE_PACKING
from simulate.media.medium import HGMedium
from simulate.montecarlo.accuracy import check_target, relative_error
from simulate.raytrace.integrator import CHUNK, MCResult, prepare, trace, trace_rotations, yarn_radius
from simulate.raytrace.materials import FiberSurface
from simulate.raytrace.pile import HELD_LOG_MU_S, pile_fiber
from simulate.raytrace.yarn import YarnTable, blend_halves, table_halves

__all__ = ["TABLE_NOISE", "TABLE_SHARE", "PILE_TABLE", "CLEAR_FIBER_SCATTERINGS", "clear_fiber_note", "table_photons",
           "ray_target", "fabric_beta", "mean_of", "twist_of", "yarn_model", "combine_realisations",
           "REALISATION_STREAM"]

log = logging.getLogger(__name__)


TABLE_NOISE = 1.2
"""The table's relative noise times ``sqrt(photons per row)`` (both halves together), measured
on red cotton and on the bench's weave (docs/notes/implementation.md). A fabric whose table is noisier shows it in ``table_rel_err`` and ``rel_err``."""
TABLE_SHARE = 0.7
"""The share of the target's error the table is given; the ray tracing gets ``sqrt(1 - 0.7^2) = 0.71``."""
TABLE_MIN_PHOTONS = 10_000
"""The fewest photons per row of the fiber's table (:func:`table_photons`)."""
PILE_TABLE = {"noise": 0.6, "share": 0.8, "min_photons": 4_000}
""":func:`table_photons` for the pile's table (:mod:`simulate.raytrace.pile`, scattering held per group): the
photons its rows need for the FABRIC's target, not more: its measured noise (0.6, leaning
conservative), the larger share of the target for the table (a table photon costs far more than a
ray's share of the error) and a lower floor (the pile's rows are many scattering radii thick, each
photon fills its row's cells densely); the table's noise at any count is measured (``table_rel_err``,
the halves' difference) and reported, not assumed. The measurements: docs/notes/implementation.md,
"The ray tracer's tables". The table's expected values do not depend on its photons."""


def table_photons(target_rel_err: float, noise: float = TABLE_NOISE, share: float = TABLE_SHARE,
                  min_photons: int = TABLE_MIN_PHOTONS) -> int:
    """Photons per BSSRDF row for a run at ``target_rel_err``: ``(noise / (share T))^2`` within [min_photons, 4e5].

    The pile's table (:mod:`simulate.raytrace.pile`, scattering held per wavelength group) takes
    :data:`PILE_TABLE`: its own measured noise, share and floor.

    The table's noise is a fixed pattern shared by every ray of the run; it is not hidden:
    :func:`fabric_beta` builds the table as two independent halves and puts their difference
    into ``u_beta``. The errors add in quadrature, ``rel^2 = t^2 + r^2``, and a table photon
    costs far more than a ray's share of the error, so the table gets the larger share
    (:data:`TABLE_SHARE`, near the cost optimum ``t^2 / r^2 = sqrt(cost_t / cost_r)``); the sum of
    the two then meets the target.

    Parameters
    ----------
    target_rel_err : float
        The run's target relative standard error ``T``.
    noise : float
        The table's relative noise at one photon per row (its error is ``noise / sqrt(photons)``).
    share : float
        The table's share of the target error.
    min_photons : int
        The floor.

    Returns
    -------
    int
        Photons per row.
    """
    t = check_target(target_rel_err) * float(share)
    return int(min(max((float(noise) / t) ** 2, int(min_photons)), 400_000))


def ray_target(target_rel_err: float, share: float = TABLE_SHARE) -> float:
    """The target of each half's trace: ``sqrt(2 (1 - share^2)) T`` (``share``: the table's, :func:`table_photons`).

    The two halves' traces are averaged (``u_rays^2 = (u_a^2 + u_b^2) / 4``), so each may have
    ``sqrt 2`` times the ray error the mean is given.

    Parameters
    ----------
    target_rel_err : float
        The run's target relative standard error ``T``.
    share : float
        The table's share of it.

    Returns
    -------
    float
        Each half's ray target.
    """
    return check_target(target_rel_err) * min(math.sqrt(2.0 * (1.0 - float(share) ** 2)), 0.999)


FELT_ROTATIONS = 8
"""Azimuthal rotations of each incidence and its detectors over which a felt is traced (module docstring)."""


REALISATION_STREAM = 104_729
"""The ray streams of a felt's realisation ``j`` start at the incidence's seed plus this times ``j // 2``
(realisations 0 and 1, on the two table halves, share their streams: common random numbers)."""
REALISATION_CHUNK_MIN = 128
"""The fewest rays per rotation in a chunk of one realisation's trace (:func:`fabric_beta`: a felt of more
than two realisations traces each with ``2 / K`` of the chunk, so its first round is not more than it needs)."""


def felt_rotations(mesh: Any) -> int:
    """:data:`FELT_ROTATIONS` for a felt's mesh (``open_fibers``: in-plane isotropic), 1 for a weave.

    Parameters
    ----------
    mesh : Mesh
        The traced mesh.

    Returns
    -------
    int
        Rotations each incidence is traced at.
    """
    return FELT_ROTATIONS if getattr(mesh, "open_fibers", False) else 1


CLEAR_FIBER_SCATTERINGS = 1.0
"""A fiber with fewer expected scattering events than this across its diameter (``2 R mu_s``) is nearly
clear: its exits keep to the cones refraction puts them on, which coarse azimuth bins smear
(:func:`clear_fiber_note`)."""


def fiber_scatterings(fiber: Any, wavelengths_nm: Any) -> float:
    """``2 R mu_s`` at the middle of ``wavelengths_nm``: the expected scattering events across the fiber.

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    wavelengths_nm : array_like
        The run's wavelengths (nm); 550 nm when empty.

    Returns
    -------
    float
        The scattering events.
    """
    medium = fiber.medium
    wl = np.asarray(wavelengths_nm, float).ravel()
    if not wl.size:
        wl = np.array([550.0])
    # a Mie medium's coefficients at all of wavelengths_nm, through the table cache: the cost check
    # before the run stored them (no Mie evaluation, no miepython import, in a run whose tables are cached)
    mu_s = float(medium.mu_s) if isinstance(medium, HGMedium) else float(
        medium_coefficients(medium, wl)["mu_s"][wl.size // 2])
    return 2.0 * float(fiber.radius_um) * mu_s


def default_exit_bins(fiber: Any, wavelengths_nm: Any, felt: bool) -> tuple[int, int]:
    """The exit bins ``(n_mu, n_phi)`` of a config that gives none.

    ``(10, 20)`` for a felt whose fiber is nearly clear (fewer than :data:`CLEAR_FIBER_SCATTERINGS`
    scattering events across it: its exits keep to cones that coarser bins smear), ``(5, 10)``
    otherwise -- turbid fibers, and woven yarns, whose table is the yarn pile's
    (:mod:`simulate.raytrace.pile`), converge there at about half the trace time.

    Parameters
    ----------
    fiber : Fiber
        The fabric's fiber.
    wavelengths_nm : array_like
        The run's wavelengths (nm); the middle one decides.
    felt : bool
        Whether the fabric is a felt (its tubes are single fibers).

    Returns
    -------
    tuple of int
        ``(n_mu, n_phi)``.
    """
    if felt and fiber_scatterings(fiber, wavelengths_nm) < CLEAR_FIBER_SCATTERINGS:
        return (10, 20)
    return (5, 10)


def clear_fiber_note(fiber: Any, wavelengths_nm: Any, exit_bins: tuple[int, int]) -> str | None:
    """The warning for a nearly clear fiber traced with coarse azimuth bins, else None.

    It is given when the fiber is nearly clear at the middle of ``wavelengths_nm`` (``2 R mu_s`` below
    :data:`CLEAR_FIBER_SCATTERINGS`) and the azimuth bins are 10 or fewer (36 deg or more): such a
    fiber's result moves between 10 and 20 azimuth bins by more than a fit's misfit, a turbid one's
    within its Monte Carlo noise (docs/physics.md 6, "Exit directions").

    Parameters
    ----------
    fiber : Fiber
        The fabric's fiber.
    wavelengths_nm : array_like
        The run's wavelengths (nm).
    exit_bins : tuple of int
        The yarn table's exit bins ``(n_mu, n_phi)``.

    Returns
    -------
    str or None
        The warning's text.
    """
    if int(exit_bins[1]) > 10:
        return None
    wl = np.asarray(wavelengths_nm, float).ravel()
    mid = float(wl[wl.size // 2]) if wl.size else 550.0
    n = fiber_scatterings(fiber, wl)
    if n >= CLEAR_FIBER_SCATTERINGS:
        return None
    return (f"the fiber is nearly clear ({n:.2g} scattering events across its diameter at {mid:g} nm) and "
            f"the yarn table's exit directions are binned at {int(exit_bins[1])} azimuths: its exits keep to "
            "cones that such bins smear, and the result can move by more than a fit's misfit at finer bins; "
            "[method] exit_bins = [10, 20] (the default for such a felt) resolves them (docs/physics.md 6, \"Exit directions\")")


def mean_of(parts: list[MCResult]) -> MCResult:
    """The mean of independent traces of one incidence (rotations): ``beta`` their mean, ``u`` of the mean.

    Parameters
    ----------
    parts : list of MCResult
        The traces.

    Returns
    -------
    MCResult
        Their mean (the one trace itself when there is one).
    """
    if len(parts) == 1:
        return parts[0]
    n = len(parts)
    p0 = parts[0]
    stops = [p.stop for p in parts if p.stop != "target"]
    return dataclasses.replace(
        p0, beta=np.mean([p.beta for p in parts], axis=0),
        u_beta=np.sqrt(np.sum([p.u_beta ** 2 for p in parts], axis=0)) / n,
        reflected=np.mean([p.reflected for p in parts], axis=0),
        transmitted=np.mean([p.transmitted for p in parts], axis=0),
        rays=int(sum(p.rays for p in parts)), seconds=float(sum(p.seconds for p in parts)),
        stop=stops[0] if stops else "target")


def combine_realisations(betas: Any, u_rays: Any) -> dict[str, np.ndarray]:
    """``beta`` and its standard error from ``K`` traces (``K`` even; trace ``j`` on table half ``j mod 2``).

    ``K = 2`` (one trace per half): ``u_beta^2 = (u_0^2 + u_1^2) / 4 + u_table^2`` with
    ``u_table^2 = mean_lambda ((beta_0 - beta_1) / 2)^2`` (the halves' difference, pooled over the
    wavelengths). ``K >= 4``: batch means. Each trace is an independent batch but for the table half
    it shares with the others of its half, so with ``A``, ``B`` the halves' means and
    ``s^2 = (sum_{j even} (beta_j - A)^2 + sum_{j odd} (beta_j - B)^2) / (K - 2)`` (the spread between
    traces of one half: their realisations and rays), ``u_beta^2 = s^2 / K + u_table^2`` with
    ``u_table^2 = max(0, mean_lambda ((A - B)^2 / 4 - s^2 / K))``: ``(A - B)^2 / 4`` has the expectation
    ``s^2 / K`` plus the table's share, ``var(table half) / 2``, of the mean's variance.

    Parameters
    ----------
    betas : array_like
        ``[K, D, L]`` each trace's result.
    u_rays : array_like
        ``[K, D, L]`` each trace's rays' standard error.

    Returns
    -------
    dict
        ``beta`` (their mean), ``u_beta``, ``u_rays`` (the rays' part, ``sqrt(sum u_j^2) / K``) and
        ``u_table`` (``[D, 1]``, the table's part).
    """
    x = np.asarray(betas, float)
    u = np.asarray(u_rays, float)
    K = x.shape[0]
    if K < 2 or K % 2:
        raise ValueError(f"combine_realisations: an even number of traces (one or more per table half), not {K}")
    if K == 2:
        ra, rb = x
        b = 0.5 * (ra + rb)
        u_rays2 = 0.25 * (u[0] ** 2 + u[1] ** 2)
        u_table = np.sqrt(np.mean((0.5 * (ra - rb)) ** 2, axis=1, keepdims=True))
        return {"beta": b, "u_beta": np.sqrt(u_rays2 + u_table ** 2), "u_rays": np.sqrt(u_rays2),
                "u_table": u_table}
    even, odd = x[0::2], x[1::2]
    a, c = even.mean(axis=0), odd.mean(axis=0)
    b = 0.5 * (a + c)
    s2 = (((even - a) ** 2).sum(axis=0) + ((odd - c) ** 2).sum(axis=0)) / (K - 2)
    u_real2 = s2 / K
    u_table2 = np.maximum(np.mean(0.25 * (a - c) ** 2 - u_real2, axis=1, keepdims=True), 0.0)
    return {"beta": b, "u_beta": np.sqrt(u_real2 + u_table2), "u_rays": np.sqrt((u ** 2).sum(axis=0)) / K,
            "u_table": np.sqrt(u_table2)}


def twist_of(structure: Any) -> tuple[float, float]:
    """The signed surface twist angles (warp, weft) in degrees, ``+`` Z and ``-`` S, of a config's structure.

    Parameters
    ----------
    structure : StructureSpec or None
        The config's ``[structure]`` (:class:`simulate.fabric.structure.StructureSpec`).

    Returns
    -------
    tuple of float
        ``(warp, weft)`` twist in degrees; ``(0, 0)`` without a structure or for a felt.
    """
    if structure is None or structure.kind != "woven":
        return (0.0, 0.0)
    return (float(structure.warp_twist_deg) * (1.0 if structure.warp_twist == "Z" else -1.0),
            float(structure.weft_twist_deg) * (1.0 if structure.weft_twist == "Z" else -1.0))


def yarn_model(mesh: Any, structure: Any = None, surface: str | None = None, volume: str | None = None
               ) -> tuple[str, str, float, float]:
    """What a mesh's tubes are made of: ``(surface, volume, spacing_ratio, packing_fraction)``.

    A weave's yarns with a woven ``[structure]`` are made of fibers (docs/physics.md 6, "Yarn made of
    fibers"): surface ``"fibers"`` (:class:`FiberSurface`) at the structure's fiber spacing, volume
    ``"pile"`` (:mod:`simulate.raytrace.pile`) at its packing fraction -- the Monte Carlo of the fabric
    the structured summation sums. Without a ``[structure]`` (as the summation's carpet of top
    cells) and for a felt's tubes, each of which IS one fiber: ``"tube"`` and ``"fiber"`` (the
    fiber's own table).

    Parameters
    ----------
    mesh : Mesh
        The traced mesh (a felt's open fibers are single fibers).
    structure : StructureSpec, optional
        The config's ``[structure]``.
    surface : str, optional
        Overrides the surface's choice.
    volume : {"fiber", "pile"}, optional
        Overrides the volume's choice.

    Returns
    -------
    tuple
        ``(surface, volume, spacing_ratio, packing_fraction)``.

    Raises
    ------
    ValueError
        When ``volume`` is neither ``"fiber"`` nor ``"pile"``.
    """
    woven = structure is not None and structure.kind == "woven" and not getattr(mesh, "open_fibers", False)
    surf = surface or ("fibers" if woven else "tube")
    vol = volume or ("pile" if woven else "fiber")
    if vol not in ("fiber", "pile"):
        raise ValueError(f"fabric_beta: volume must be 'fiber' or 'pile', not {vol!r}")
    spacing = float(structure.spacing_ratio) if woven else 1.0
    packing = float(structure.packing_fraction) if woven else CLOSE_PACKING
    return surf, vol, spacing, packing


def _trace_incidences(incidences: np.ndarray, inverse: np.ndarray, w_out: np.ndarray, meshes: tuple, mats: list,
                      beta: np.ndarray, u_beta: np.ndarray, background: Any, *, r_target: float, max_rays: int,
                      max_seconds: float, seed: int, threads: int, progress: bool, twist: tuple[float, float],
                      chunk: int, setups: dict, max_events: int, record: dict | None = None) -> list[dict]:
    """:func:`fabric_beta`'s traces: each incidence on each mesh, ``beta`` and ``u_beta`` filled in.

    Realisation ``j`` is traced with table half ``j mod 2``; the realisations are combined by
    :func:`combine_realisations`. Returns the incidences' run information.

    The realisations are traced one after the other, every incidence on each, and each one's scene is let go
    before the next (``background``: an executor that builds the next one's meanwhile, or None).
    ``record``: each incidence's traces' events go to ``record["incidences"]`` (:mod:`simulate.raytrace.reweight`),
    one log per realisation.
    """
    n_rot = felt_rotations(meshes[0])
    n_real = len(meshes)
    per_half = n_real // 2
    r_each = r_target * math.sqrt(per_half)
    rays_each = max_rays // per_half if max_rays else 0
    seconds_each = max_seconds / per_half if max_seconds else 0.0
    dets = []
    for k in range(len(incidences)):
        rows = np.nonzero(inverse == k)[0]
        det_key, det_inv = np.unique(np.round(w_out[rows], 9), axis=0, return_inverse=True)
        dets.append((rows, det_key, np.asarray(det_inv).reshape(-1), det_key / np.linalg.norm(det_key, axis=1)[:, None]))
    results: list[list[MCResult]] = [[] for _ in incidences]
    logs: list[list] = [[] for _ in incidences]
    pending = None
    for j, m in enumerate(meshes):
        mat = mats[j % 2]
        if pending is not None:     # this realisation's setup, built on another thread
            pending.result()
            pending = None
        if background is not None and j + 1 < n_real:
            if j == 0:
                prepare(m, mat, setups, twist_deg=twist)
            pending = background.submit(prepare, meshes[j + 1], mats[(j + 1) % 2], setups, twist_deg=twist)
        for k, wi in enumerate(incidences):
            det = dets[k][3]
            stream = seed + 7919 * k + REALISATION_STREAM * (j // 2)
            log_k = logs[k] if record is not None else None
            if n_rot > 1:    # the rotations as one wavefront, stopped on their mean (trace_rotations)
                parts = trace_rotations(m, mat, wi / np.linalg.norm(wi), det,
                                        [2.0 * math.pi * (i + j / n_real) / n_rot for i in range(n_rot)],
                                        target_rel_err=r_each, max_rays=rays_each, max_seconds=seconds_each,
                                        seed=stream, threads=threads, progress=progress,
                                        twist_deg=twist, chunk=chunk, setups=setups, max_events=max_events,
                                        record=log_k)
            else:
                parts = [trace(m, mat, wi / np.linalg.norm(wi), det, target_rel_err=r_each, max_rays=rays_each,
                               max_seconds=seconds_each, seed=stream, threads=threads, progress=progress,
                               twist_deg=twist, chunk=chunk, setups=setups, max_events=max_events, record=log_k)]
            results[k].append(mean_of(parts))
        if not any(later is m for later in meshes[j + 1:]):    # its scene is not needed again: let it go
            for key in [key for key in setups if key[0] == id(m)]:
                del setups[key]
    runs = []
    for k, wi in enumerate(incidences):
        rows, det_key, det_inv, _ = dets[k]
        res = results[k]
        c = combine_realisations([r.beta for r in res], [r.u_beta for r in res])
        b, u, u_rays, u_table = c["beta"], c["u_beta"], c["u_rays"], c["u_table"]
        if record is not None:
            record["incidences"].append({"rows": rows, "det_inv": det_inv, "realisations": logs[k],
                                         "ray_rel_err": relative_error(b, u_rays)})
        beta[rows] = b[det_inv]
        u_beta[rows] = u[det_inv]
        peak = np.maximum(b.max(axis=1, keepdims=True), 1e-300)
        stops = [r.stop for r in res if r.stop != "target"]
        runs.append({"w_in": wi.tolist(), "detectors": int(det_key.shape[0]), "rays": int(sum(r.rays for r in res)),
                     "seconds": float(sum(r.seconds for r in res)), "rel_err": relative_error(b, u),
                     "ray_rel_err": relative_error(b, u_rays),
                     "table_rel_err": float(np.sqrt(np.mean((u_table / peak) ** 2))),
                     "stop": stops[0] if stops else "target",
                     "reflected_mean": float(np.mean([r.reflected for r in res], axis=0).mean()),
                     "transmitted_mean": float(np.mean([r.transmitted for r in res], axis=0).mean()),
                     **{k2: v for k2, v in res[0].info.items() if k2 != "u_reflected_plus_transmitted"}})
    return runs


def fabric_beta(mesh: Any, fiber: Any, w_in: np.ndarray, w_out: np.ndarray, wavelengths_nm: np.ndarray, *,
                target_rel_err: float = 0.01, max_rays: int = 0, max_seconds: float = 0.0, seed: int = 0,
                threads: int = 1, progress: bool = False, tables: tuple[YarnTable, YarnTable] | None = None,
                structure: Any = None, cache: bool = True, surface: str | None = None,
                volume: str | None = None, exit_bins: tuple[int, int] = (5, 10),
                axial_shift: bool = False,
                w_t_nodes: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 0.95),
                max_events: int = 0, record: dict | None = None,
                populations: Sequence[tuple[float, Any]] | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """``beta`` and its standard error at P geometries ``(w_in, w_out)`` of the woven fabric.

    The BSSRDF table is built as two independent halves (seeds apart, half the photons each).
    Every distinct incidence is traced once with each half, with the same ray streams (common
    random numbers), towards all of its detector directions; ``beta`` is their mean. The
    standard error combines the ray tracing's (``(u_a^2 + u_b^2) / 4``) with the table's: the two
    halves differ by twice the full table's noise, so per detector ``u_table^2 = mean_lambda
    ((beta_a - beta_b) / 2)^2`` (pooled over the wavelengths, which leans conservative for the
    dark ones). The halves come from the disk cache when there (:func:`simulate.raytrace.table_halves`);
    ``info["table"]["cache"]`` says which.

    Parameters
    ----------
    mesh : Mesh or tuple of Mesh
        The micro-element; a tuple of ``K`` (an even number; a felt's realisations): trace ``j`` is on
        mesh ``j`` with half ``j mod 2``, each to ``sqrt(K / 2)`` times a half's ray target (and
        ``max_rays``, ``max_seconds`` over ``K / 2``), and for ``K >= 4`` the standard error is the batch
        means' of :func:`combine_realisations`.
    fiber : Fiber
        The yarns' fiber; with ``populations``, the surface term's (its roughness and host index, which
        the populations share).
    w_in, w_out : numpy.ndarray
        ``[P, 3]`` paired incident and exit directions in the fabric frame.
    wavelengths_nm : numpy.ndarray
        ``[L]`` vacuum wavelengths (nm).
    target_rel_err : float
        Target relative standard error of ``beta``.
    max_rays, max_seconds : int, float
        Budgets (0: none).
    seed : int
        Random seed.
    threads : int
        Threads (results do not depend on it).
    progress : bool
        Show a progress bar.
    tables : tuple of YarnTable, optional
        The two halves, used as they are (``volume`` and ``exit_bins`` then say nothing).
    structure : StructureSpec, optional
        A config's ``[structure]``: the yarns' twist (:func:`twist_of`) and what they are made of
        (:func:`yarn_model`).
    cache : bool
        Read and store the halves in the disk cache (False, or ``FABRIC_OPTICS_NO_CACHE=1``: always
        computed).
    surface, volume : str, optional
        Override :func:`yarn_model`'s choice.
    exit_bins : tuple of int
        The tables' exit directions per exit cell, ``(mu bins, phi bins)`` (a config's
        ``[method] exit_bins``; what they resolve and cost: docs/physics.md 6, "Exit directions").
    axial_shift : bool
        Shift a table row's exits along the fiber axis (docs/physics.md 6, "Axial shift").
    w_t_nodes : tuple of float
        The tables' axial incidence nodes.
    max_events : int
        The scattering events followed per ray (:func:`simulate.raytrace.trace`; 0: all, 1: the single
        scattering).
    record : dict, optional
        Filled with the run's events and table settings, from which
        :func:`simulate.raytrace.reweight.reweighted_beta` gives the result for another dye without
        tracing again.
    populations : sequence of (float, Fiber), optional
        A blend's ``(share, fiber)``: each population's halves walked as ``fiber``'s would be (a woven
        ``[structure]``: in the pile of that population's fibers, :mod:`simulate.raytrace.pile`) and mixed
        by share (:func:`simulate.raytrace.yarn.blend_halves`), so a ray entering a yarn (a felt's fiber)
        scatters, in expectation, as one of a population drawn by share.

    Returns
    -------
    beta, u_beta : numpy.ndarray
        ``[P, L]`` estimate and standard error.
    info : dict
        Run information (the table, the traces, the stops).
    """
    w_in = np.atleast_2d(np.asarray(w_in, float))
    w_out = np.atleast_2d(np.asarray(w_out, float))
    wl = np.asarray(wavelengths_nm, float)
    started = time.perf_counter()
    surf, vol, spacing, packing = yarn_model(mesh[0] if isinstance(mesh, (tuple, list)) else mesh, structure,
                                             surface, volume)
    split: dict[str, Any] = dict(PILE_TABLE) if vol == "pile" and tables is None else {}
    if tables is not None:
        if populations is not None:
            raise ValueError("fabric_beta: tables or populations, not both")
        vol = "tables given"
    else:
        def walked(f: Any) -> Any:
            return pile_fiber(f, yarn_radius(mesh), packing) if vol == "pile" else f

        grid: dict[str, Any] = {"held_log_mu_s": HELD_LOG_MU_S} if vol == "pile" else {}
        grid.update(n_mu=int(exit_bins[0]), n_phi=int(exit_bins[1]), w_t_nodes=tuple(float(x) for x in w_t_nodes))
        photons_per_row = table_photons(target_rel_err, **split) // 2
        if populations is not None:
            tables = blend_halves([(share, walked(f)) for share, f in populations], wl, photons_per_row, seed,
                                  threads if threads else None, cache=cache, **grid)
        else:
            tables = table_halves(walked(fiber), wl, photons_per_row, seed, threads if threads else None, cache=cache,
                                  **grid)
    r_target = ray_target(target_rel_err, split.get("share", TABLE_SHARE))
    mats = [FiberSurface(t, float(fiber.roughness), float(fiber.n_host), surf, spacing, bool(axial_shift))
            for t in tables]
    meshes = tuple(mesh) if isinstance(mesh, (tuple, list)) else (mesh, mesh)
    if len(meshes) < 2 or len(meshes) % 2:
        raise ValueError(f"fabric_beta: one mesh or an even number of them (realisations, alternately on the two "
                         f"table halves), not {len(meshes)}")
    twist = twist_of(structure)
    key = np.round(w_in, 9)
    incidences, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    beta = np.zeros((w_in.shape[0], wl.size))
    u_beta = np.zeros_like(beta)
    n_rot = felt_rotations(meshes[0])
    chunk = max(256, CHUNK // n_rot)
    if len(meshes) > 2:     # each realisation traces 2 / K of the rays: chunks as much smaller, within a floor
        chunk = max(REALISATION_CHUNK_MIN, chunk * 2 // len(meshes))
    setups: dict = {}
    # the next realisation's scene and table arrays are built on another thread while this one's
    # traces run (its traces then find them in ``setups``; no result depends on this); the first
    # one's before (Embree's scene is built holding the GIL: two builds side by side take as long as
    # one after the other, a build beside a trace takes the trace's idle GIL)
    background = ThreadPoolExecutor(max_workers=1) if threads != 1 else None
    if record is not None:
        record.update(incidences=[], shape=beta.shape, volume=vol, packing=packing,
                      tables=tuple({"shape": t.T.shape, "c_bar": t.c_bar, "tau": t.tau} for t in tables),
                      yarn_radius=yarn_radius(mesh) if vol == "pile" else None, seed=seed, threads=threads,
                      photons_per_row=table_photons(target_rel_err, **split) // 2,
                      grid={"n_mu": int(tables[0].n_mu), "n_phi": int(tables[0].n_phi),
                            "w_t_nodes": tuple(float(x) for x in tables[0].w_t_nodes)},
                      target_rel_err=float(target_rel_err), wavelengths_nm=wl.copy())
    try:
        runs = _trace_incidences(incidences, inverse, w_out, meshes, mats, beta, u_beta, background, r_target=r_target,
                                 max_rays=max_rays, max_seconds=max_seconds, seed=seed, threads=threads,
                                 progress=progress, twist=twist, chunk=chunk, setups=setups, max_events=max_events,
                                 record=record)
    finally:
        if background is not None:
            background.shutdown()
    photons = int(sum(t.photons for t in tables))
    info = {"table": {"photons": photons, "seconds": float(sum(t.seconds for t in tables)),
                      "cache": [t.cache for t in tables],
                      "halves": 2, "photons_per_row": int(photons // max(1, tables[0].T.shape[0] * tables[0].T.shape[1])),
                      "w_t_nodes": tables[0].w_t_nodes.tolist(),
                      "grid": [tables[0].n_psi, tables[0].n_v, tables[0].n_mu, tables[0].n_phi],
                      "axial_shift": bool(axial_shift)},
            "incidences": runs, "seconds": time.perf_counter() - started, "twist_deg": list(twist),
            "rotations": n_rot, "realisations": len({id(m) for m in meshes}),
            "yarn_surface": surf, "surface_spacing_ratio": spacing if surf == "fibers" else None,
            "yarn_volume": vol, "pile_packing_fraction": packing if vol == "pile" else None,
            "rays": int(sum(r["rays"] for r in runs)),
            "stop": "target" if all(r["stop"] == "target" for r in runs) else
            next(r["stop"] for r in runs if r["stop"] != "target")}
    return beta, u_beta, info
