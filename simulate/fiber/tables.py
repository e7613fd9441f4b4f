"""The fiber BRDF table: ``R_B`` over the incident sphere x B's outgoing hemisphere, on disk.

``simulate fiber CONFIG --out DIR [--method nee|beam|bssrdf]`` tabulates the top cell's BRDF
``R_B = R_surf + R_vol`` (:mod:`simulate.fiber`; ``R = L_o / E_perp``, fiber frame: x = fiber
axis ``t``, z = outward normal of B, y = ``b`` = z x x) with its Monte Carlo standard errors, at the
config's wavelengths, and writes two files (an open format: numpy's npz and JSON):

``DIR/fiber-table.npz``
    ``theta_in_deg [Ti]``, ``phi_in_deg [Pi]``, ``theta_out_deg [To]``, ``phi_out_deg [Po]``,
    ``wavelength_nm [L]``; ``R``, ``u_R``, ``R_vol``, ``u_R_vol`` of shape ``[Ti, Pi, To, Po, L]``
    and ``R_surf`` of shape ``[Ti, Pi, To, Po]`` (``R = R_surf + R_vol``; ``u_R = u_R_vol``, the
    surface term being exact). Angles in degrees, ``R`` dimensionless (per unit irradiance on a
    plane normal to the beam: the ordinary BRDF is ``R / cos(theta_in)`` in 1/sr for
    ``theta_in < 90``).
``DIR/fiber-table.json``
    ``{"format": "fiber-brdf-table/1", "grid": {...}, "units": {...}, "symmetry": "...",
    "provenance": {...}}``: the grid definition (below), units, the config (name, SHA-256, text),
    seed, route, requested and achieved error, photons, seconds and software versions.

Grid. Directions are ``w = (sin t cos p, sin t sin p, cos t)`` in the fiber frame.

- ``w_in`` covers the whole sphere through the cylinder's mirror symmetries: ``w_t -> -w_t``
  and ``w_b -> -w_b``, applied to BOTH directions, leave ``R_B`` unchanged, so the table holds
  ``w_in`` with ``x >= 0, y >= 0`` only: ``phi_in`` on the nodes ``0, d_phi, ..., 90`` and
  ``theta_in`` on the MIDPOINTS of ``[0, 180]`` in steps ``d_theta`` (7.5, 22.5, ..., 172.5 for
  15 deg: no pole and never the fiber axis ``theta = 90, phi = 0``, where the beam does not hit
  the fiber). ``theta_in > 90`` is light arriving from below B's tangent plane.
- ``w_out`` covers B's upper hemisphere: ``theta_out`` on the midpoints of ``[0, 90]`` in steps
  ``d_theta``, ``phi_out`` on the nodes ``0, d_phi, ..., 360 - d_phi``.
- To read ``R_B(w_in, w_out)`` for any ``w_in``: flip the sign of x in both directions if
  ``w_in,x < 0``, then of y if ``w_in,y < 0`` (:func:`simulate.fabric.canonical_pairs`), and
  interpolate in the table.

The default grid (30 deg polar x 45 deg azimuth: 6 x 3 incident x 3 x 8 outgoing = 432 pairs, 18
incident directions) and the default 5 % target error (of each curve's spectral peak) are coarse on
purpose, to run in a few minutes on 2 cores; ``--step-deg``, ``--phi-step-deg`` and
``--target-rel-err`` refine it (the cost grows with the number of incident directions, times
1/target^2).
"""

from __future__ import annotations

import io
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from gonio.data.dataset import atomic_write
from simulate.fiber.model import Fiber, surface_brdf
from simulate.fiber.routes import volume_brdf
from simulate.montecarlo.accuracy import REL_ERR_DEFINITION, relative_error
from simulate.optics.microfacet import directions_deg
from simulate.provenance import jsonable, software_versions

__all__ = ["FORMAT", "JSON_NAME", "NPZ_NAME", "TableGrid", "fiber_table", "write_fiber_table",
           "read_fiber_table", "is_fiber_table_dir"]

FORMAT = "fiber-brdf-table/1"
#: Default target relative error of a table (the config's target is for the fabric runs).
DEFAULT_TABLE_REL_ERR = 0.05
NPZ_NAME = "fiber-table.npz"
JSON_NAME = "fiber-table.json"


class TableGrid:
    """The table's direction grid (see the module docstring)."""

    def __init__(self, step_deg: float = 30.0, phi_step_deg: float = 45.0):
        if not (0 < step_deg <= 90 and (180.0 / step_deg).is_integer()):
            raise ValueError(f"step_deg must divide 180 and 90 evenly (e.g. 5, 10, 15, 30), got {step_deg:g}")
        if not (0 < phi_step_deg <= 90 and (90.0 / phi_step_deg).is_integer()):
            raise ValueError(f"phi_step_deg must divide 90 evenly (e.g. 10, 15, 30, 45), got {phi_step_deg:g}")
        self.step_deg, self.phi_step_deg = float(step_deg), float(phi_step_deg)
        self.theta_in_deg = np.arange(step_deg / 2, 180.0, step_deg)
        self.phi_in_deg = np.arange(0.0, 90.0 + 1e-9, phi_step_deg)
        self.theta_out_deg = np.arange(step_deg / 2, 90.0, step_deg)
        self.phi_out_deg = np.arange(0.0, 360.0 - 1e-9, phi_step_deg)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """The table's axes: ``(theta_in, phi_in, theta_out, phi_out)`` node counts."""
        return (self.theta_in_deg.size, self.phi_in_deg.size, self.theta_out_deg.size,
                self.phi_out_deg.size)

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """All ``(w_in, w_out)`` pairs ``[P, 3]`` in C order of :attr:`shape`."""
        ti, pi, to, po = np.meshgrid(self.theta_in_deg, self.phi_in_deg, self.theta_out_deg,
                                     self.phi_out_deg, indexing="ij")
        return directions_deg(ti.ravel(), pi.ravel()), directions_deg(to.ravel(), po.ravel())

    def as_dict(self) -> dict:
        """The grid's nodes and steps as JSON-ready lists, with what each axis spans (the table's sidecar)."""
        return {"theta_in_deg": self.theta_in_deg.tolist(), "phi_in_deg": self.phi_in_deg.tolist(),
                "theta_out_deg": self.theta_out_deg.tolist(), "phi_out_deg": self.phi_out_deg.tolist(),
                "step_deg": self.step_deg, "phi_step_deg": self.phi_step_deg,
                "theta_in": "midpoints of [0, 180] (w_in over the sphere, x >= 0, y >= 0 by symmetry)",
                "phi_in": "nodes 0..90", "theta_out": "midpoints of [0, 90]", "phi_out": "nodes 0..360"}


def fiber_table(fiber: Fiber, wavelengths_nm: Any, grid: TableGrid, *, method: str = "nee",
                target_rel_err: float | None = None, seed: int = 0, threads: int | None = None,
                max_photons: int | None = None, progress: bool = False,
                config_provenance: dict | None = None) -> tuple[dict[str, np.ndarray], dict]:
    """Compute the table arrays and the sidecar's metadata (not written).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    wavelengths_nm : array_like
        Vacuum wavelengths (nm).
    grid : TableGrid
        The incident and exit directions of the table.
    method : {"nee", "beam", "bssrdf"}
        The volume route (:func:`simulate.fiber.volume_brdf`).
    target_rel_err : float, optional
        Target relative standard error of the volume term (default :data:`DEFAULT_TABLE_REL_ERR`).
    seed : int
        Random seed.
    threads : int, optional
        Threads (results do not depend on it).
    max_photons : int, optional
        Photon budget per incident direction and wavelength group.
    progress : bool
        Show a progress bar.
    config_provenance : dict, optional
        :meth:`simulate.config.SimulationConfig.provenance` of the config the fiber came from, recorded
        in the sidecar.

    Returns
    -------
    arrays : dict of str to numpy.ndarray
        The grid's axes, ``R`` (volume + surface), ``u_R`` and the two terms apart.
    sidecar : dict
        Format, grid, units, frame, symmetry and provenance.
    """
    target = DEFAULT_TABLE_REL_ERR if target_rel_err is None else float(target_rel_err)
    seed = int(seed)
    wavelengths = np.asarray(wavelengths_nm, float)
    w_in, w_out = grid.pairs()
    started = time.perf_counter()
    est = volume_brdf(fiber, w_in, w_out, wavelengths, method=method, target_rel_err=target,
                      max_photons=max_photons, seed=seed, threads=threads, progress=progress)
    r_surf = np.asarray(surface_brdf(fiber, w_in, w_out), float)
    seconds = time.perf_counter() - started
    shape = grid.shape
    R_vol = np.asarray(est.R, float).reshape(shape + (wavelengths.size,))
    u_vol = np.asarray(est.u_R, float).reshape(shape + (wavelengths.size,))
    R_surf = r_surf.reshape(shape)
    arrays = {"theta_in_deg": grid.theta_in_deg, "phi_in_deg": grid.phi_in_deg,
              "theta_out_deg": grid.theta_out_deg, "phi_out_deg": grid.phi_out_deg,
              "wavelength_nm": wavelengths, "R": R_vol + R_surf[..., None], "u_R": u_vol,
              "R_vol": R_vol, "u_R_vol": u_vol, "R_surf": R_surf}
    sidecar = {
        "format": FORMAT,
        "grid": grid.as_dict(),
        "arrays": {k: list(v.shape) for k, v in arrays.items()},
        "units": {"angles": "deg", "wavelength_nm": "nm (vacuum)",
                  "R": "L_o / E_perp (dimensionless); BRDF = R / cos(theta_in) in 1/sr"},
        "frame": "fiber frame: x = fiber axis t, z = outward normal of the top cell B, y = z x x; "
                 "directions point away from the surface",
        "symmetry": "R(w_in, w_out) = R(S w_in, S w_out) for S = diag(-1,1,1) and diag(1,-1,1)",
        "provenance": {
            "command": "simulate fiber", "config": config_provenance, "method": method,
            "seed": seed, "target_rel_err": target,
            "rel_err": relative_error(R_vol.reshape(-1, wavelengths.size), u_vol.reshape(-1, wavelengths.size)),
            "rel_err_definition": REL_ERR_DEFINITION,
            "photons": int(est.photons), "seconds": seconds, "fiber_info": jsonable(est.info),
            "versions": software_versions(),
        },
    }
    return arrays, sidecar


def write_fiber_table(out_dir: str | Path, arrays: dict[str, np.ndarray], sidecar: dict) -> Path:
    """Write ``fiber-table.npz`` then ``fiber-table.json`` atomically into ``out_dir``.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        The output folder (made when missing).
    arrays : dict of str to numpy.ndarray
        The table's arrays (:func:`fiber_table`).
    sidecar : dict
        Its metadata.

    Returns
    -------
    pathlib.Path
        The folder.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)  # type: ignore[arg-type]  # numpy stubs type **kwds as allow_pickle
    atomic_write(out / NPZ_NAME, buffer.getvalue())
    atomic_write(out / JSON_NAME, (json.dumps(jsonable(sidecar), indent=2) + "\n").encode())
    return out


def read_fiber_table(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """Read a table directory written by :func:`write_fiber_table`.

    Parameters
    ----------
    path : str or pathlib.Path
        The folder.

    Returns
    -------
    arrays : dict of str to numpy.ndarray
        The table's arrays.
    sidecar : dict
        Its metadata.

    Raises
    ------
    ValueError
        When the sidecar does not name this table format.
    """
    root = Path(path)
    sidecar = json.loads((root / JSON_NAME).read_text())
    if sidecar.get("format") != FORMAT:
        raise ValueError(f"{root / JSON_NAME}: not a {FORMAT} table")
    with np.load(root / NPZ_NAME, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    return arrays, sidecar


def is_fiber_table_dir(out: Path) -> bool:
    """True when the folder ``out`` holds a fiber table (its JSON sidecar says so).

    Such a folder is a previous ``simulate fiber`` output, which the command replaces with ``--force``
    (:func:`gonio.data.outputs.prepare_folder`).

    Parameters
    ----------
    out : pathlib.Path
        The folder asked for as output.

    Returns
    -------
    bool
        Whether its sidecar names a fiber table.
    """
    try:
        meta = json.loads((Path(out) / JSON_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("format") == FORMAT
