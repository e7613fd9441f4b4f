"""Data that could be lost or silently wrong (issue 9): retry counts, run-directory lock,
instrument claim, calibration validity, demo output, plan validation, resume, transcripts."""

from __future__ import annotations

import json
import logging

import pytest

from gonio.mock import MockInstrument

SEED = 5


def _plan(drv, tmp_path, name="integrity", **kw):
    kw.setdefault("incidence", (0, 45))
    kw.setdefault("in_plane", (-30, 20, 50))
    kw.setdefault("wavelengths", (450, 550, 650))
    kw.setdefault("readings", 8)
    return drv.write_plan(tmp_path, name, **kw)


# --- item 9: retries counted == faults injected ---------------------------------------------

@pytest.mark.parametrize("spec", ["checksum=0.3", "checksum=0.3,garbled=0.1,busy=0.1,truncated=0.1"])
def test_retry_counts_equal_the_faults_injected(drv, tmp_path, spec):
    """Every fault the mock injected is counted once (a bad checksum on the reply to the
    CHK ON that restores the checksum mode was not)."""
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=3, faults=spec) as mock:
        res = drv.run(mock, plan, tmp_path / "run", timeout_s=0.15)
        injected = dict(mock.stats["faults"])
    names = {"checksum": "serial_checksum", "garbled": "serial_garbled", "busy": "head_busy",
             "truncated": "serial_truncated"}
    counted = {names[k]: v for k, v in injected.items() if v}
    assert injected["checksum"] > 20
    assert res.retries == counted
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["provenance"]["retries"] == counted
