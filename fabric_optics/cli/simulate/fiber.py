"""``simulate fiber``: a fiber's BRDF table over the incident sphere (npz + JSON sidecar).

The grid's size is bounded before anything is allocated (:data:`MAX_TABLE_VALUES`); the work is
:func:`simulate.fiber.tables.fiber_table`.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from fabric_optics import api
from fabric_optics.cli.common import (
    UsageError,
    add_force,
    progress,
)
from fabric_optics.cli.simulate.options import (
    check_cost,
    pos_float,
    run_settings_arguments,
    write_failed,
)
from gonio.data.outputs import prepare_folder

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate fiber``."""
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("--out", type=Path, required=True, help="output directory (fiber-table.npz, fiber-table.json)")
    add_force(p)
    p.add_argument("--route", choices=("nee", "beam", "bssrdf"), default=None,
                   help="fiber route of the Monte Carlo (default: the config's)")
    p.add_argument("--step-deg", type=pos_float, default=30.0, dest="step_deg",
                   help="polar grid step in degrees, dividing 90 (default 30)")
    p.add_argument("--phi-step-deg", type=pos_float, default=45.0, dest="phi_step_deg",
                   help="azimuth grid step in degrees, dividing 90 (default 45)")
    run_settings_arguments(p)


#: Bound on a fiber table's size, direction pairs x wavelengths (``simulate fiber``): 10 million
#: values, about 0.6 GiB for the table's five arrays and the Monte Carlo tallies behind them (~64
#: bytes a value). A 5 deg x 10 deg grid at 33 wavelengths has 7.7 million; the default 432 pairs x 33.
MAX_TABLE_VALUES = 10_000_000


def _check_table_size(step_deg: float, phi_step_deg: float, n_wavelengths: int) -> None:
    """Refuse a table grid over :data:`MAX_TABLE_VALUES` from its step sizes alone (nothing allocated)."""
    pairs = (180.0 / step_deg) * (90.0 / phi_step_deg + 1) * (90.0 / step_deg) * (360.0 / phi_step_deg)
    values = pairs * n_wavelengths
    if values > MAX_TABLE_VALUES:
        raise UsageError(f"--step-deg {step_deg:g} / --phi-step-deg {phi_step_deg:g}: the table would have "
                          f"{pairs:,.0f} direction pairs x {n_wavelengths} wavelengths = {values:.3g} values "
                          f"(about {values * 64 / 2**30:,.3g} GiB); at most {MAX_TABLE_VALUES:,} (about "
                          f"{MAX_TABLE_VALUES * 64 / 2**30:.1f} GiB): use a coarser step")


def run(args: argparse.Namespace) -> int:
    """Run ``simulate fiber``; return the exit status."""
    import numpy as np

    from simulate.fiber.tables import TableGrid, fiber_table, is_fiber_table_dir, write_fiber_table

    config = api.load_config(args.config)
    wavelengths = np.asarray(config.wavelengths_nm, float)
    _check_table_size(args.step_deg, args.phi_step_deg, wavelengths.size)
    try:
        grid = TableGrid(args.step_deg, args.phi_step_deg)
    except ValueError as exc:
        raise UsageError(f"--step-deg/--phi-step-deg: {exc}") from None
    target = config.target_rel_err if args.target_rel_err is None else args.target_rel_err
    from simulate.config import ConfigError, require_single_population
    try:
        require_single_population(config, "simulate fiber")
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    check_cost("fiber", config, wavelengths, target, args.max_photons)
    prepare_folder(args.out, writer="simulate fiber", force=args.force, previous=is_fiber_table_dir)
    arrays, sidecar = fiber_table(
        config.fiber(wavelengths), wavelengths, grid, method=args.route or config.route,
        target_rel_err=target, seed=config.seed if args.seed is None else args.seed,
        threads=args.threads or None,
        max_photons=config.max_photons if args.max_photons is None else args.max_photons,
        progress=progress(args), config_provenance=config.provenance())
    try:
        write_fiber_table(args.out, arrays, sidecar)
    except OSError as exc:
        raise UsageError(write_failed(args.out, exc)) from None
    prov = sidecar["provenance"]
    print(f"wrote {args.out} ({math.prod(grid.shape)} direction pairs x {arrays['wavelength_nm'].size} "
          f"wavelengths; {prov['method']}; {prov['photons']} photons in {prov['seconds']:.1f} s)")
    return 0
