"""Small sweeps: the red-cotton config on a tiny plan, an in-process dask cluster (no ports)."""

from __future__ import annotations

from pathlib import Path

import pytest

from fabric_optics.sweep.runner import SweepSpec, parse_params
from gonio.acquisition.plan import load_plan
from simulate.config import load_config


def plan_text(wavelengths: str, in_plane: str = "[-30, 0, 30, 60]") -> str:
    return f"""
[sample]
name = "tiny"
[wavelengths]
{wavelengths}
[geometry]
incidence_deg = [0, 45]
in_plane_deg = {in_plane}
"""


#: three wavelengths, eight geometries: a task of the classic model takes a fraction of a second
TINY_PLAN = plan_text("list_nm = [450, 550, 650]")


def write_plan(folder: Path, text: str = TINY_PLAN, name: str = "tiny.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def make_spec(plan_path: Path, params: list[str], method: str = "classic", target: float = 0.1) -> SweepSpec:
    config = load_config("red-cotton")
    return SweepSpec(config, load_plan(plan_path), parse_params(params, config), method=method,
                     target_rel_err=target, threads=1)


@pytest.fixture
def inproc_client():
    """A one-worker, one-thread LocalCluster inside the test process (inproc transport: no ports),
    closed after the test. One thread: numba's parallel kernels are not launched concurrently."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            yield client
