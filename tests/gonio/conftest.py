"""Shared fixtures of the driver tests: small plans, mock instruments, a session runner."""

from __future__ import annotations

import logging
import textwrap
from pathlib import Path

import numpy as np
import pytest

from gonio.acquisition.plan import load_plan
from gonio.acquisition.session import run_session
from gonio.instrument import RetryPolicy
from gonio.instrument.transport import ModbusTransport, SerialTransport

logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


def write_plan(folder: Path, name: str = "small", *, incidence=(0, 45), in_plane=(-30, 20, 50),
               wavelengths=(450, 550, 650), itime_ms: int = 10, readings: int = 32,
               extra: str = "", geometry_extra: str = "") -> Path:
    """A small plan file (fast: short integration time, many readings for good u estimates)."""
    text = textwrap.dedent(f"""
        name = "{name}"
        [sample]
        name = "{name} sample"
        [wavelengths]
        list_nm = {list(wavelengths)}
        [geometry]
        incidence_deg = {list(incidence)}
        in_plane_deg = {list(in_plane)}
        {geometry_extra}
        [acquisition]
        itime_ms = {itime_ms}
        gain = 0
        readings = {readings}
        settle_ms = 0
        velocity_deg_s = 60
        {extra}
        """)
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


def run_mock_session(mock, plan_path, out: Path, *, resume=False, record=None, timeout_s=0.3,
                     seed=None):
    """Acquire ``plan_path`` on a running MockInstrument; returns the RunResult."""
    plan = load_plan(plan_path)
    modbus = ModbusTransport(mock.modbus_url, timeout_s=timeout_s)
    serial_link = SerialTransport(mock.serial_url, timeout_s=timeout_s)
    return run_session(plan, modbus, serial_link, out, resume=resume, record=record,
                       progress=False, seed=mock.seed if seed is None else seed,
                       retry=RetryPolicy(base_s=0.002))


def z_scores(ds, sample) -> np.ndarray:
    """(beta - truth) / u_beta for every row of a dataset."""
    t = ds.table
    truth = sample.beta(t.theta_i.to_numpy(), t.phi_i.to_numpy(), t.theta_o.to_numpy(),
                        t.phi_o.to_numpy(), t.wavelength_nm.to_numpy())
    return (t.beta.to_numpy() - truth) / t.u_beta.to_numpy()


@pytest.fixture
def small_plan(tmp_path) -> Path:
    return write_plan(tmp_path)


@pytest.fixture
def drv():
    """The helpers above, as a fixture (tests cannot import conftest in importlib mode)."""
    import types
    return types.SimpleNamespace(write_plan=write_plan, run=run_mock_session, z_scores=z_scores)
