"""Closed loop: acquire a mock sample of known truth and recover it within the stated u_beta."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.dataset import read_dataset
from gonio.mock import MockInstrument

WAVELENGTHS = (400, 450, 500, 550, 600, 650, 700, 750)


def _plan(drv, tmp_path, name="loop"):
    return drv.write_plan(tmp_path, name, incidence=(0, 30, 60), in_plane=(-50, -20, 10, 40, 70),
                      wavelengths=WAVELENGTHS)


def _check_recovery(drv, ds, sample, min_rows):
    z = drv.z_scores(ds, sample)
    assert len(z) >= min_rows
    assert np.all(np.isfinite(z))
    inside = np.mean(np.abs(z) < 3.0)
    assert inside >= 0.99, f"only {inside:.3f} of the points within 3 u_beta"
    # the stated uncertainty is neither much too small nor much too large
    assert 0.6 < np.std(z) < 1.4, np.std(z)
    return z


@pytest.mark.parametrize("modbus,serial", [("tcp", "pty"), ("rtu", "socket")])
def test_lambert_recovered(drv, tmp_path, modbus, serial):
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", modbus=modbus, serial=serial, speed="fast",
                        seed=11) as mock:
        assert mock.modbus_url.startswith("tcp://" if modbus == "tcp" else "rtu://")
        result = drv.run(mock, plan, tmp_path / "run")
        assert result.status == "complete" and result.exit_code == 0
        ds = read_dataset(tmp_path / "run")
        _check_recovery(drv, ds, mock.sample, 15 * len(WAVELENGTHS))
        assert np.allclose(ds.table.beta, 0.5, rtol=0.05)
        assert ds.kind == "measured"
        assert ds.meta["provenance"]["seed"] == 11
        assert ds.meta["instrument"]["idn"].startswith("KIAM,GPS-1,")
        assert ds.meta["provenance"]["complete"] is True
        # the shutter is closed and the drives are stopped at the end
        assert mock.controller.shutter_open is False
        assert all(ax.motion is None for ax in mock.controller.axes)


def test_red_cotton_recovered(drv, tmp_path):
    plan = _plan(drv, tmp_path, "cotton")
    with MockInstrument(sample="red-cotton", modbus="tcp", serial="pty", speed="fast",
                        seed=5) as mock:
        result = drv.run(mock, plan, tmp_path / "run")
        assert result.exit_code == 0
        ds = read_dataset(tmp_path / "run")
        _check_recovery(drv, ds, mock.sample, 15 * len(WAVELENGTHS))
        # the red dye: the red end is several times brighter than the blue end at 0/40
        spec = ds.spectrum(0.0, 0.0, 40.0, 180.0)
        assert spec.beta.iloc[-1] > 3 * spec.beta.iloc[0]


def test_auto_ranging_never_stores_saturation(drv, tmp_path):
    """A bright sample at a long integration time saturates; the stored values are still right."""
    plan = drv.write_plan(tmp_path, "bright", incidence=(0,), in_plane=(10, 40),
                      wavelengths=(550, 600), itime_ms=400, readings=16)
    with MockInstrument(sample="lambert:0.9", speed="fast", seed=2) as mock:
        result = drv.run(mock, plan, tmp_path / "run")
        assert result.exit_code == 0
    import json
    recs = [json.loads(x) for x in (tmp_path / "run" / "journal.jsonl").read_text().splitlines()]
    points = [r for r in recs if r["type"] == "point"]
    ranging = [x["ranging"] for p in points for x in p["readings"]]
    assert max(ranging) > 0                      # some readings were retaken at a shorter time
    assert all(x["mean"] < 60000 for p in points for x in p["readings"])
    ds = read_dataset(tmp_path / "run")
    assert np.all(np.abs(drv.z_scores(ds, mock.sample)) < 4)
