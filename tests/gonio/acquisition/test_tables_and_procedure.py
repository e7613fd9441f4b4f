"""The instrument's tables: the generated protocol document, the register descriptors, and the
plan's procedure steps executed by the engine."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gonio.acquisition.journal import read_journal
from gonio.acquisition.plan import PlanError, parse_plan
from gonio.instrument import MODBUS_MAP, DeviceError, MotionController, RetryPolicy, SampleSlot, register_blocks
from gonio.instrument.docs import GENERATORS, render
from gonio.instrument.transport import ModbusTransport
from gonio.mock import MockInstrument

ROOT = Path(__file__).resolve().parents[3]


def test_the_committed_protocol_document_is_generated_from_the_tables():
    """docs/instrument.md's register map and command set are the code's tables: regenerate with
    `python -m gonio.instrument.docs docs/instrument.md` after changing a table."""
    text = (ROOT / "docs" / "instrument.md").read_text(encoding="utf-8")
    for name in GENERATORS:
        assert f"<!-- BEGIN GENERATED: {name} -->" in text
    assert render(text) == text
    for row in MODBUS_MAP.values():
        assert f"| `{row.name}` |" in text


def test_a_changed_table_shows_as_drift(monkeypatch):
    text = (ROOT / "docs" / "instrument.md").read_text(encoding="utf-8")
    import gonio.instrument.docs as docs
    monkeypatch.setitem(docs.GENERATORS, "errors", lambda: "| code | message |\n|---|---|\n| 999 | New |")
    assert render(text) != text


def test_register_blocks_follow_the_rows():
    assert register_blocks("coil") == ((0, 2),)
    assert register_blocks("input")[0] == (0, 2)
    with pytest.raises(ValueError):
        MODBUS_MAP["TARGET"].address_of()          # a per-axis row needs the axis


def test_register_descriptors_read_and_write_through_the_table():
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=0) as mock:
        motion = MotionController(ModbusTransport(mock.modbus_url, timeout_s=0.5), RetryPolicy())
        assert motion.firmware_word == 0x0104
        motion.sample_slot = SampleSlot.WHITE_REFERENCE
        assert motion.sample_slot == SampleSlot.WHITE_REFERENCE and mock.controller.slot == 1
        motion.lamp = True
        assert motion.lamp is True and mock.controller.lamp_on
        motion.velocity_cdeg_s[2] = 500
        assert motion.velocity_cdeg_s[2] == 500 and mock.controller.axes[2].velocity == 500
        with pytest.raises(DeviceError, match="VELOCITY"):
            motion.velocity_cdeg_s[2] = 0              # refused by the row's validator, not sent
        with pytest.raises(AttributeError):
            motion.axis_status[0] = 1                  # an input register is read-only


@pytest.mark.parametrize("procedure, needle", [
    ('steps = ["home", "measure"]', "needs a 'calibrate' before it"),
    ('steps = ["home", "calibrate"]', "'measure' exactly once"),
    ('steps = ["home", "calibrate", "dance", "measure"]', "unknown step 'dance'"),
    ("recalibrate_every = -1", "must be >= 0"),
])
def test_bad_procedures_are_named(procedure, needle):
    text = ('[sample]\nname = "s"\n[geometry]\nincidence_deg = [0]\nin_plane_deg = [30]\n'
            f"[procedure]\n{procedure}\n")
    with pytest.raises(PlanError, match="procedure") as err:
        parse_plan(text, "p.toml")
    assert needle in str(err.value)


def test_a_plan_may_recalibrate_every_n_points(drv, tmp_path):
    """recalibrate_every = 2: dark and white standard again after every 2 points; each point is
    reduced with the calibration it was measured with, and the meta records the procedure."""
    plan = drv.write_plan(tmp_path, "recal", extra="\n[procedure]\nrecalibrate_every = 2\n")
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=4) as mock:
        res = drv.run(mock, plan, tmp_path / "run")
    assert res.status == "complete", res.message
    records = read_journal(tmp_path / "run" / "journal.jsonl").records
    cals = [r["id"] for r in records if r["type"] == "calibration"]
    points = [r["calibration"] for r in records if r["type"] == "point"]
    assert cals == [0, 1, 2] and points == [0, 0, 1, 1, 2, 2]
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["provenance"]["procedure"] == {"steps": ["home", "calibrate", "measure"],
                                               "recalibrate_every": 2}
    assert meta["provenance"]["calibrations"] == [0, 1, 2]
