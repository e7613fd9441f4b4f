"""Fault matrix: every fault kind of the mock at a rate; sessions complete with retries counted,
and because the driver retries whole measurement units, the data equal a clean session's."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.data import read_dataset
from gonio.mock import MockInstrument
from gonio.mock.faults import FAULT_KINDS

SEED = 21

# fault spec -> the retry counter it must show (serial link kind in brackets)
MATRIX = [
    ("serial_timeout=0.04", "serial_timeout", "pty"),
    ("busy=0.08", "head_busy", "pty"),
    ("garbled=0.08", "serial_garbled", "pty"),
    ("truncated=0.06", "serial_truncated", "pty"),
    ("checksum=0.08", "serial_checksum", "pty"),
    ("drop=0.03", "serial_timeout", "pty"),
    ("drop=0.03", "link_lost", "socket"),
    ("lamp=0.1", "lamp_unstable", "pty"),
    ("modbus_busy=0.08", "modbus_busy", "pty"),
    ("modbus_noresponse=0.04", "modbus_no_response", "pty"),
    ("axis_fault=0.2", "axis_fault", "pty"),
    ("modbus_drop=0.06", "modbus_link_lost", "pty"),       # Modbus TCP (the mock's default)
]


def test_matrix_covers_every_fault_kind():
    kinds = {spec.split("=")[0] for spec, _, _ in MATRIX}
    assert kinds == set(FAULT_KINDS)


def _plan(drv, tmp_path):
    return drv.write_plan(tmp_path, "faults", incidence=(0, 45), in_plane=(-30, 20, 50),
                          wavelengths=(450, 550, 650), readings=8)


def _clean(drv, tmp_path, serial):
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", serial=serial, speed="fast", seed=SEED) as mock:
        res = drv.run(mock, plan, tmp_path / f"clean-{serial}", timeout_s=0.15)
    assert res.exit_code == 0
    return (tmp_path / f"clean-{serial}" / "radiance.csv").read_bytes()


@pytest.mark.parametrize("spec,counter,serial", MATRIX, ids=[f"{m[0]}-{m[2]}" for m in MATRIX])
def test_fault_kind(drv, tmp_path, spec, counter, serial):
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", serial=serial, speed="fast", seed=SEED,
                        faults=spec) as mock:
        res = drv.run(mock, plan, tmp_path / "run", timeout_s=0.15)
        injected = mock.stats["faults"]
        assert mock.controller.shutter_open is False
        assert all(ax.motion is None for ax in mock.controller.axes)
    assert sum(injected.values()) > 0, "the mock injected nothing: the rate is too low"
    assert res.status == "complete", res.message
    ds = read_dataset(tmp_path / "run")
    retries = ds.meta["provenance"]["retries"]
    assert retries.get(counter, 0) > 0, retries
    # no point lost, none duplicated, and identical numbers to a clean session
    assert len(ds.table) == 6 * 3
    assert (tmp_path / "run" / "radiance.csv").read_bytes() == _clean(drv, tmp_path, serial)


def test_modbus_drop_tcp_every_drop_reconnected_and_counted(drv, tmp_path):
    """At a rate, drops hit whichever requests the timing puts there (status polling varies), so
    only what holds for any placement is asserted: the session completes, each dropped
    connection is exactly one modbus_link_lost retry (no busy refusal: an executed HOME_ALL is
    not re-sent), and the numbers equal a clean session's. Which request is dropped, and whether
    an executed move is re-sent, is tested deterministically in test_link_drops.py."""
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED,
                        faults="modbus_drop=0.1") as mock:
        # TCP drops are an EOF, not a silence: a generous timeout keeps a loaded machine from
        # adding no-response retries to the exact count
        res = drv.run(mock, plan, tmp_path / "run", timeout_s=1.0)
        drops = mock.stats["modbus_drops"]
        assert mock.controller.shutter_open is False
    assert res.status == "complete", res.message
    retries = read_dataset(tmp_path / "run").meta["provenance"]["retries"]
    assert drops > 0 and retries == {"modbus_link_lost": drops}, (drops, retries)
    assert (tmp_path / "run" / "radiance.csv").read_bytes() == _clean(drv, tmp_path, "pty")


def test_modbus_drop_rtu_session_completes(drv, tmp_path):
    """Over RTU a drop is a silent interface: timeouts, retried after re-opening the port."""
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", modbus="rtu", speed="fast", seed=SEED,
                        faults="modbus_drop=0.05") as mock:
        res = drv.run(mock, plan, tmp_path / "run", timeout_s=0.15)
        drops = mock.stats["modbus_drops"]
    assert res.status == "complete", res.message
    retries = read_dataset(tmp_path / "run").meta["provenance"]["retries"]
    assert drops > 0 and retries.get("modbus_no_response", 0) >= drops, (drops, retries)
    # the link does not change the numbers: equal to a clean session over Modbus TCP
    assert (tmp_path / "run" / "radiance.csv").read_bytes() == _clean(drv, tmp_path, "pty")


def test_all_faults_at_once(drv, tmp_path):
    spec = ("serial_timeout=0.01,busy=0.03,garbled=0.03,truncated=0.02,checksum=0.03,drop=0.01,"
            "lamp=0.03,modbus_busy=0.03,modbus_noresponse=0.01,axis_fault=0.1,modbus_drop=0.02")
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED, faults=spec) as mock:
        res = drv.run(mock, plan, tmp_path / "run", timeout_s=0.15)
        assert mock.controller.shutter_open is False
    assert res.status == "complete"
    ds = read_dataset(tmp_path / "run")
    assert sum(ds.meta["provenance"]["retries"].values()) >= 5
    assert (tmp_path / "run" / "radiance.csv").read_bytes() == _clean(drv, tmp_path, "pty")


class _DyingLink:
    """Wraps the serial transport; after ``after`` exchanges the head never answers again."""

    def __init__(self, inner, after):
        self.inner, self.after, self.n = inner, after, 0
        self.channel, self.url, self.timeout_s = inner.channel, inner.url, 0.05

    def exchange(self, line, **kw):
        self.n += 1
        if self.n > self.after:
            return b""
        return self.inner.exchange(line, **kw)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def test_unrecoverable_fault_stops_safely_and_resume_completes(drv, tmp_path):
    from gonio.acquisition.plan import load_plan
    from gonio.acquisition.session import run_session
    from gonio.instrument import RetryPolicy
    from gonio.instrument.transport import ModbusTransport, SerialTransport

    plan_path = _plan(drv, tmp_path)
    out = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        serial_link = _DyingLink(SerialTransport(mock.serial_url, timeout_s=0.05), after=75)
        res = run_session(load_plan(plan_path), ModbusTransport(mock.modbus_url, timeout_s=0.2),
                          serial_link, out, progress=False, seed=SEED,
                          retry=RetryPolicy(base_s=0.001))
        assert res.status == "stopped" and res.exit_code == 1
        assert "photometer head" in res.message
        # safe: shutter closed (through the controller's coil) and every axis at rest
        assert mock.controller.shutter_open is False
        assert all(ax.motion is None for ax in mock.controller.axes)
        assert 0 < res.points_measured < 6
        records = [json.loads(x) for x in (out / "journal.jsonl").read_text().splitlines()]
        points = [r for r in records if r["type"] == "point"]
        assert len(points) == res.points_measured
        ds = read_dataset(out)
        assert len(ds.table) == 3 * len(points)          # every measured point kept
        assert ds.meta["provenance"]["complete"] is False
        # resume on a healthy link: completes, and equals a clean uninterrupted session
        res2 = drv.run(mock, plan_path, out, resume=True, timeout_s=0.15)
        assert res2.status == "complete"
    assert (out / "radiance.csv").read_bytes() == _clean(drv, tmp_path, "pty")
    records = [json.loads(x) for x in (out / "journal.jsonl").read_text().splitlines()]
    keys = [tuple(r["geometry"]) for r in records if r["type"] == "point"]
    assert len(keys) == len(set(keys)) == 6
    assert np.isclose(read_dataset(out).table.beta.mean(), 0.5, rtol=0.02)
