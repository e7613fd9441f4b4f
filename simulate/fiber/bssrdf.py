"""The ``bssrdf`` route: the fiber BSSRDF stored by cell offset, and its summation (package docstring).

The rows are also what the ray tracer of fibre assemblies samples exits from (:mod:`simulate.raytrace.yarn`):
:func:`bssrdf_rows` and :func:`lit_rows` are public for it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simulate.fiber.model import Fiber, as_wavelengths
from simulate.fiber.spectral import BLEND, blended_groups, group_walk, spectral_optics, wavelength_groups
from simulate.montecarlo import geometry as G
from simulate.montecarlo import tallies as T
from simulate.montecarlo.accuracy import BATCH, FIRST_ROUND, mean_and_error
from simulate.montecarlo.rows import execute_rows
from simulate.montecarlo.transport import ParameterError, make_control, make_inputs

__all__ = ["lit_rows", "bssrdf_rows", "row_sources", "rows_inputs", "bssrdf_table", "bssrdf_route", "grid_cells", "bssrdf_for_beam"]


def lit_rows(dpsi: float) -> int:
    """Largest ``k`` with ``|k dpsi| < 90 deg + dpsi / 2``: the local azimuths whose cell is lit in part.

    Parameters
    ----------
    dpsi : float
        Width of a cell around the fiber (radians).

    Returns
    -------
    int
        ``k_max``: rows ``-k_max .. k_max`` are lit.
    """
    return int(math.floor((math.pi / 2 + dpsi / 2) / dpsi - 1e-12))


def row_sources(w_t: float, ks, dpsi: float) -> np.ndarray:
    """The CELL source rows of :func:`bssrdf_rows` for the local incidences ``(w_t, azimuth k dpsi)``.

    A beam at a cell whose normal makes the angle ``k dpsi`` with ``w_perp`` has
    ``w . n = rho cos(k dpsi)``, ``w . b = -rho sin(k dpsi)`` (``b = n x t`` at the top cell is +y).

    Parameters
    ----------
    w_t : float
        Axial component of the incident direction.
    ks : sequence of int
        The rows' local azimuth indices.
    dpsi : float
        Cell width (radians).

    Returns
    -------
    numpy.ndarray
        ``float64[len(ks), 5]`` source rows.
    """
    rho = math.sqrt(max(1.0 - w_t * w_t, 0.0))
    return np.array([[float(G.CELL), w_t, -rho * math.sin(k * dpsi), rho * math.cos(k * dpsi), dpsi / 2.0]
                     for k in ks]).reshape(-1, 5)


def rows_inputs(fiber, grid, medium, walk_phase, targets, control):
    """The kernel inputs shared by every row of :func:`bssrdf_rows` (the source is per row).

    Parameters
    ----------
    fiber : Fiber
        The fiber (radius, cell count).
    grid : tuple
        ``(n_psi, n_v, v_max, n_mu, n_phi)``: exit cells, axial bins and their half-range (um), exit
        direction bins.
    medium : numpy.ndarray
        The kernel's medium row of the walk (:func:`simulate.fiber.spectral.group_walk`).
    walk_phase : PhaseArrays
        The phase function walked.
    targets : SpectralTargets
        The scored wavelengths' optics.
    control : numpy.ndarray
        The kernel's control row (:func:`simulate.montecarlo.transport.make_control`).

    Returns
    -------
    KernelInputs
        The packed inputs (their source a placeholder).
    """
    n_psi, n_v, v_max, n_mu, n_phi = grid
    params = np.array([float(n_psi), float(n_mu), float(n_phi), float(n_v), float(v_max)])
    return make_inputs(G.CYLINDER, np.array([fiber.radius_um]), np.zeros(5), medium, walk_phase, control,
                       T.CYLINDER_DIRECTIONS, params, T.V_NONE, None, targets)


def bssrdf_rows(fiber, w_t, ks, grid, medium, walk_phase, targets, control, photons, seed, threads, scalars=None,
                into=None):
    """BSSRDF table rows: CELL-source runs for the local incidences ``(w_t, azimuth k dpsi)``.

    ``into`` (optional, ``[len(ks), n_psi, n_v, n_mu, n_phi, n_spec]``, e.g. a view of a larger table):
    the means are written there and no standard error is computed -- returns ``(into, None, photons,
    seconds)`` (the fit's walk keeps only the means: two ~10^8-byte arrays less per call).

    Returns ``T[len(ks), n_psi, n_v, n_mu, n_phi, n_spec]`` (mean exit weight per photon, launch
    weight ``max(w . n, 0)``) and its standard error. ``scalars`` (a list, optional) receives each
    row's scalar tally sums (the fit's re-weighting bound reads the scatterings from them).
    Row ``r`` is the run of seed ``seed + 7919 r``; all rows run in ONE parallel kernel call
    (:func:`simulate.montecarlo.rows.execute_rows`: bit-identical to one call per row).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    w_t : float
        Axial component of the incident direction.
    ks : sequence of int
        The rows' local azimuth indices.
    grid : tuple
        ``(n_psi, n_v, v_max, n_mu, n_phi)`` (:func:`rows_inputs`).
    medium : numpy.ndarray
        The kernel's medium row of the walk (:func:`simulate.fiber.spectral.group_walk`).
    walk_phase : PhaseArrays
        The phase function walked.
    targets : SpectralTargets
        The scored wavelengths' optics.
    control : numpy.ndarray
        The kernel's control row (:func:`simulate.montecarlo.transport.make_control`).
    photons : int
        Photons per row.
    seed : int
        Seed of row 0.
    threads : int or None
        Threads (results do not depend on it).
    scalars : list, optional
        Receives each row's scalar tally sums.
    into : numpy.ndarray, optional
        Where the means are written (then no standard error).

    Returns
    -------
    T : numpy.ndarray
        The rows (``into`` when given).
    u_T : numpy.ndarray or None
        Their standard error (None with ``into``).
    photons : int
        Photons walked.
    seconds : float
        Wall time of the kernel call.
    """
    n_psi, n_v, v_max, n_mu, n_phi = grid
    dpsi = 2.0 * math.pi / n_psi
    n_spec = targets.mu_a.size
    inp = rows_inputs(fiber, grid, medium, walk_phase, targets, control)
    seeds = np.array([seed + 7919 * r for r in range(len(ks))], dtype=np.int64)
    if into is not None:      # the means straight into ``into`` (mean_and_error's, bit for bit): rows.execute_rows
        s, _, seconds = execute_rows(inp, row_sources(w_t, ks, dpsi), seeds, photons, threads, BATCH, means=into)
        if scalars is not None:
            scalars.extend(s[r] for r in range(len(ks)))
        return into, None, photons * len(ks), seconds
    s, b, seconds = execute_rows(inp, row_sources(w_t, ks, dpsi), seeds, photons, threads, BATCH)
    out = np.zeros((len(ks), n_psi, n_v, n_mu, n_phi, n_spec))
    err = np.zeros_like(out)
    for r in range(len(ks)):
        if scalars is not None:
            scalars.append(s[r])
        mean, u = mean_and_error(b[r], photons)
        out[r] = mean.reshape(n_psi, n_v, n_mu, n_phi, n_spec)
        err[r] = u.reshape(n_psi, n_v, n_mu, n_phi, n_spec)
    return out, err, photons * len(ks), seconds


#: seed offset between the wavelength groups of one table (the exit table's rows add ``7919 r``, its
#: nodes ``104729 i``: :func:`simulate.fiber.farfield.exit_table`)
GROUP_SEED_STEP = 1_009


def bssrdf_table(
    fiber: Fiber,
    w_t: float,
    wavelengths_nm: Any,
    *,
    n_mu: int = 9,
    n_phi: int = 18,
    n_v: int = 1,
    v_max_um: float | None = None,
    photons_per_row: int = 100_000,
    seed: int = 0,
    threads: int | None = None,
    max_group: int | None = None,
    blend: int = BLEND,
) -> dict[str, Any]:
    """The fiber BSSRDF stored by offset, for one axial incidence component ``w_t``.

    Rows: local incident azimuths ``k dpsi`` (``|k dpsi| < 90 deg + dpsi/2``, every row lit on part
    of its cell), i.e. incident directions ``(w_t, -rho sin(k dpsi), rho cos(k dpsi))`` in A's
    frame, ``rho = sqrt(1 - w_t^2)``. Columns: exit cell offset (``n_psi = 360 / cell width``
    cells, 0 = A itself), axial offset ``v`` (``n_v`` bins on ``[-v_max, v_max]``; 1 = summed
    out), local exit direction (``n_mu`` x ``n_phi`` uniform bins in ``cos theta`` and azimuth),
    wavelength. Values: mean exit weight per photon entering A uniformly with launch weight
    ``max(w . n, 0)`` -- i.e. ``F_out / (E |A|)``; the docs/physics.md BSSRDF is
    ``T / (cos theta_in |B| dOmega cos theta_out)`` with ``F_in = E |A| cos theta_in``.

    Wavelengths: one walk per group (:func:`simulate.fiber.spectral.wavelength_groups`, at most
    ``max_group`` wavelengths each), group ``k`` on its own streams (``seed + GROUP_SEED_STEP * k``:
    the groups' errors are independent); across a group boundary the two walks are blended over
    ``blend`` wavelengths on each side (:func:`simulate.fiber.spectral.blended_groups`; 0: none), so
    a smooth material's table has no step there: the difference of two independent walks is spread
    over the zone. ``u_T`` of a blended value is ``sqrt(sum (w u)^2)`` over the walks.

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    w_t : float
        Axial component of the incident direction, in ``(-1, 1)``.
    wavelengths_nm : array_like
        Vacuum wavelengths (nm).
    n_mu, n_phi : int
        Local exit direction bins in ``cos theta`` and azimuth.
    n_v : int
        Axial offset bins (1: summed out).
    v_max_um : float, optional
        Half-range of the axial offsets (default 10 fiber radii).
    photons_per_row : int
        Photons per row and wavelength group.
    seed : int
        Random seed.
    threads : int, optional
        Threads (results do not depend on it).
    max_group : int, optional
        Largest wavelength group of one walk.
    blend : int
        Wavelengths blended on each side of a group boundary.

    Returns
    -------
    dict
        ``T``, ``u_T`` (``[k, psi, v, mu, phi, lambda]``), ``k``, grid edges, photons, seconds.
    """
    wl = as_wavelengths(wavelengths_nm)
    n_psi = fiber.cell_count("bssrdf route")
    if not -1.0 < w_t < 1.0:
        raise ParameterError(f"w_t must be in (-1, 1), got {w_t!r}")
    dpsi = 2.0 * math.pi / n_psi
    k_max = lit_rows(dpsi)
    ks = list(range(-k_max, k_max + 1))
    v_max = 10.0 * fiber.radius_um if v_max_um is None else float(v_max_um)
    optics = spectral_optics(fiber, wl)
    control = make_control()
    rows = np.zeros((len(ks), n_psi, n_v, n_mu, n_phi, wl.size))
    errs = np.zeros_like(rows)
    photons = 0
    seconds = 0.0
    groups = wavelength_groups(optics, max_size=max_group)
    for k, (group, (scored, weight)) in enumerate(zip(groups, blended_groups(groups, blend), strict=True)):
        medium, walk_phase, targets = group_walk(fiber, optics, group, white=True, scored=scored)
        t, u, p, s = bssrdf_rows(fiber, w_t, ks, (n_psi, n_v, v_max, n_mu, n_phi), medium, walk_phase, targets,
                                  control, photons_per_row, seed + GROUP_SEED_STEP * k, threads)
        rows[..., scored] += t * weight
        errs[..., scored] += (u * weight) ** 2   # variances: the groups' walks are independent
        photons += p
        seconds += s
    np.sqrt(errs, out=errs)
    return {
        "T": rows, "u_T": errs, "k": np.array(ks), "cell_width_rad": dpsi, "w_t": float(w_t),
        "v_edges_um": np.linspace(-v_max, v_max, n_v + 1), "mu_edges": np.linspace(0, 1, n_mu + 1),
        "phi_edges": np.linspace(-math.pi, math.pi, n_phi + 1), "wavelengths_nm": wl,
        "photons": photons, "seconds": seconds,
    }



def bssrdf_route(fiber, w_in, outputs_grid_bins, table, omega):
    """Summation of the BSSRDF rows for one beam (aligned azimuths exact, others interpolated).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    w_in : numpy.ndarray
        ``[3]`` incident direction in the fiber frame.
    outputs_grid_bins : tuple of numpy.ndarray
        ``(mu_i, phi_i)``: each output's cell of the direction grid (:func:`grid_cells`).
    table : dict
        The beam's rows (:func:`bssrdf_for_beam`).
    omega : numpy.ndarray
        Each output cell's projected solid angle.

    Returns
    -------
    R, u : numpy.ndarray
        ``[n_out, n_spec]`` volume BRDF of cell B and its standard error.
    """
    rows, errs, ks, dpsi = table["T"], table["u_T"], table["k"], table["cell_width_rad"]
    n_psi = rows.shape[1]
    beta = math.atan2(-w_in[1], w_in[2])  # w_perp along n(beta)
    x = beta / dpsi
    j0 = math.floor(x)
    frac = x - j0
    total = 0.0
    total_u2 = 0.0
    for j, weight in ((j0, 1.0 - frac), (j0 + 1, frac)):
        if weight == 0.0:
            continue
        acc = 0.0
        acc_u2 = 0.0
        for r, k in enumerate(ks):
            # cell A_i = beta_j - k dpsi, i = j - k; B (offset 0) relative to A_i is offset k - j
            offset = (k - j) % n_psi
            mu_i, phi_i = outputs_grid_bins
            acc = acc + rows[r, offset][:, mu_i, phi_i, :].sum(axis=0)  # v offsets summed out
            acc_u2 = acc_u2 + (errs[r, offset][:, mu_i, phi_i, :] ** 2).sum(axis=0)
        total = total + weight * acc
        total_u2 = total_u2 + (weight ** 2) * acc_u2
    return total / omega, np.sqrt(total_u2) / omega


def grid_cells(outputs: np.ndarray, n_mu: int, n_phi: int):
    """Map ranged outputs onto the cells of a (mu, phi) grid; refuse ranges that are not grid cells.

    Parameters
    ----------
    outputs : numpy.ndarray
        ``[P, 8]`` output rows (:func:`simulate.fiber.routes.range_outputs`).
    n_mu, n_phi : int
        The grid's bins in ``cos theta`` and azimuth.

    Returns
    -------
    mu_i, phi_i : numpy.ndarray
        Each output's cell.
    omega : numpy.ndarray
        Each cell's projected solid angle.

    Raises
    ------
    ParameterError
        When an output range is not one grid cell.
    """
    mu_edges = np.linspace(0, 1, n_mu + 1)
    phi_edges = np.linspace(-math.pi, math.pi, n_phi + 1)
    mu_i = np.clip(np.searchsorted(mu_edges, 0.5 * (outputs[:, 3] + outputs[:, 4])) - 1, 0, n_mu - 1)
    phi_i = np.clip(np.searchsorted(phi_edges, 0.5 * (outputs[:, 5] + outputs[:, 6])) - 1, 0, n_phi - 1)
    exact = np.isclose(outputs[:, 3], mu_edges[mu_i]) & np.isclose(outputs[:, 4], mu_edges[mu_i + 1]) & \
        np.isclose(outputs[:, 5], phi_edges[phi_i]) & np.isclose(outputs[:, 6], phi_edges[phi_i + 1])
    if not np.all(exact):
        raise ParameterError("bssrdf route: outputs must be cells of the BSSRDF direction grid (bssrdf_bins)")
    omega = 0.5 * (mu_edges[mu_i + 1] ** 2 - mu_edges[mu_i] ** 2) * (phi_edges[phi_i + 1] - phi_edges[phi_i])
    return mu_i, phi_i, omega


def bssrdf_for_beam(fiber, w_in, medium, walk_phase, targets, control, n_mu, n_phi, target, max_photons, seed,
                    threads):
    """The BSSRDF rows one beam needs (its axial component), photons per row from the target.

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    w_in : numpy.ndarray
        ``[3]`` incident direction in the fiber frame.
    medium : numpy.ndarray
        The kernel's medium row of the walk (:func:`simulate.fiber.spectral.group_walk`).
    walk_phase : PhaseArrays
        The phase function walked.
    targets : SpectralTargets
        The scored wavelengths' optics.
    control : numpy.ndarray
        The kernel's control row (:func:`simulate.montecarlo.transport.make_control`).
    n_mu, n_phi : int
        Local exit direction bins.
    target : float
        Target relative standard error.
    max_photons : int
        Photon budget per row.
    seed : int
        Seed of row 0.
    threads : int or None
        Threads (results do not depend on it).

    Returns
    -------
    dict
        ``T``, ``u_T``, ``k``, ``cell_width_rad``, ``photons``, ``seconds``.
    """
    n_psi = fiber.cell_count("bssrdf route")
    dpsi = 2.0 * math.pi / n_psi
    k_max = lit_rows(dpsi)
    ks = list(range(-k_max, k_max + 1))
    # photons per row: the table's error on one bin is what the summation adds up; a fixed
    # budget per row from the target (rows add in quadrature over ~pi/dpsi lit cells)
    per_row = int(min(max(FIRST_ROUND, 4.0 / target ** 2 / len(ks)), max_photons))
    per_row = int(math.ceil(per_row / BATCH) * BATCH)
    t, u, photons, seconds = bssrdf_rows(fiber, float(w_in[0]), ks, (n_psi, 1, 1.0, n_mu, n_phi), medium,
                                          walk_phase, targets, control, per_row, seed, threads)
    return {"T": t, "u_T": u, "k": ks, "cell_width_rad": dpsi, "photons": photons, "seconds": seconds}
