"""Simulating a fabric at a plan's geometries and wavelengths (``simulate fabric``)."""

from __future__ import annotations

import os

from fabric_optics import validate as _v
from fabric_optics.api.loading import load_config, load_plan
from fabric_optics.errors import InputError, typed_errors
from gonio.acquisition.plan import Plan
from gonio.data.dataset import Dataset
from simulate.config import SimulationConfig

__all__ = ["FABRIC_METHODS", "simulate"]


FABRIC_METHODS = ("summation", "classic", "mc", "auto")
"""The fabric models `simulate` takes (`method=`): summation over the fabric's fibers, the classic Lambert +
Cook-Torrance model, Monte Carlo ray tracing of the fabric, or per geometry the cheapest within the target."""


@typed_errors
def simulate(config: str | os.PathLike | SimulationConfig, plan: str | os.PathLike | Plan = "red-cotton",
             method: str = "summation", *, target_rel_err: float | None = None, seed: int | None = None,
             threads: int | None = None, max_photons: int | None = None, measurable_only: bool = False,
             progress: bool = False, max_seconds: float = 0.0) -> Dataset:
    """Simulate a fabric's radiance coefficient at a plan's geometries and wavelengths (`simulate fabric`).

    The result is a dataset like a measured one, at the plan's geometries, so that `compare` can
    set the two side by side. The run's cost is estimated before it starts and a run beyond
    `max_seconds` is refused rather than left to run for days.

    Parameters
    ----------
    config : str, path or SimulationConfig
        The fabric: a preset name, a config TOML file or a loaded config (`load_config`).
    plan : str, path or Plan, default "red-cotton"
        Where to evaluate it: a plan preset, a plan TOML file or a loaded plan (`load_plan`).
    method : str, default "summation"
        One of `FABRIC_METHODS`: `"summation"` (over the fabric's fibers), `"classic"` (Lambert +
        Cook-Torrance), `"mc"` (Monte Carlo ray tracing of the fabric) or `"auto"` (per geometry the
        cheapest method whose error is within the target).
    target_rel_err : float, optional
        Relative standard error the Monte Carlo aims at; the config's by default.
    seed : int, optional
        Random seed (the config's by default); the same seed gives the same numbers with any
        number of threads.
    threads : int, optional
        Worker threads; `0` uses every core numba may; the config's by default.
    max_photons : int, optional
        Upper bound on the photons of each Monte Carlo walk; the config's by default.
    measurable_only : bool, default False
        Leave out the plan's geometries the instrument cannot measure (the beam-blocked zone).
    progress : bool, default False
        Show a progress bar.
    max_seconds : float, default 0.0
        Refuse a run estimated to take longer (0: the built-in bound of one day).

    Returns
    -------
    Dataset
        A simulated dataset; `u_beta` is the Monte Carlo's standard error, `meta["provenance"]`
        records the config, the method and the software that made it.

    Raises
    ------
    InputError
        An unknown method, config or plan, an argument out of range (the message names it), or a
        run refused by its cost estimate.

    Examples
    --------
    The `quick` plan (incidences 0 and 45 deg, three observation angles, six wavelengths) and the
    classic model, the quickest (a few seconds):

    >>> import fabric_optics as fo
    >>> sim = fo.simulate("red-cotton", plan="quick", method="classic")
    >>> sim.kind, len(sim), sim.wavelengths_nm.tolist()
    ('simulated', 36, [400.0, 450.0, 500.0, 550.0, 600.0, 650.0])
    """
    from simulate.virtual import fabric_dataset

    if method not in FABRIC_METHODS:
        raise InputError(f"method {method!r}: choose one of {', '.join(FABRIC_METHODS)}")
    _v.rel_err("target_rel_err", target_rel_err)
    _v.seed("seed", seed)
    _v.threads("threads", threads)
    _v.integer("max_photons", max_photons, 1, 10**15, none=True)
    _v.flag("measurable_only", measurable_only)
    _v.flag("progress", progress)
    _v.number("max_seconds", max_seconds, 0.0)
    config, plan = load_config(config), load_plan(plan)
    _v.cost(config, plan.wavelengths_nm, target_rel_err, max_photons)
    return fabric_dataset(config, plan, method, target_rel_err=target_rel_err, seed=seed,
                          threads=threads, max_photons=max_photons, measurable_only=measurable_only,
                          progress=progress, max_seconds=max_seconds)
