"""Record and replay: the fixtures reproduce their datasets byte for byte; mismatches are loud."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fabric_optics.cli.gonio import main
from gonio.acquisition.record import load_transcript, reseal
from gonio.data import read_dataset
from gonio.mock import MockInstrument

ROOT = Path(__file__).resolve().parents[3]
FIXTURES = ROOT / "fixtures" / "recorded"
CASES = [("quick-lambert", "quick"), ("red-cotton-small", str(FIXTURES / "red-cotton-small.toml")),
         ("quick-faults", "quick")]


def _meta_without_versions(path: Path) -> dict:
    meta = json.loads(path.read_text())
    meta.pop("software", None)
    meta["provenance"].pop("versions", None)
    return meta


@pytest.mark.parametrize("name,plan", CASES, ids=[c[0] for c in CASES])
def test_replay_reproduces_the_fixture_dataset(tmp_path, name, plan, capsys):
    out = tmp_path / "replay"
    assert main(["replay", str(FIXTURES / f"{name}.jsonl"), "--plan", plan, "--out", str(out)]) == 0
    assert (out / "radiance.csv").read_bytes() == (FIXTURES / name / "radiance.csv").read_bytes()
    assert _meta_without_versions(out / "meta.json") == _meta_without_versions(FIXTURES / name / "meta.json")
    recorded = json.loads((FIXTURES / name / "meta.json").read_text())
    replayed = json.loads((out / "meta.json").read_text())
    if (recorded["software"], recorded["provenance"]["versions"]) == (
            replayed["software"], replayed["provenance"]["versions"]):
        # same software versions (as in CI from this checkout): the whole file, byte for byte
        assert (out / "meta.json").read_bytes() == (FIXTURES / name / "meta.json").read_bytes()
    ds = read_dataset(out)
    assert ds.meta["provenance"]["complete"] is True


def test_fault_fixture_exercises_the_recovery_paths():
    meta = json.loads((FIXTURES / "quick-faults" / "meta.json").read_text())
    retries = meta["provenance"]["retries"]
    from gonio.instrument import RETRY_KINDS
    for kind in RETRY_KINDS:
        if kind != "checksum_mode_lost":        # a consequence of a drop, not a fault kind
            assert retries.get(kind, 0) > 0, kind
    # faults never change the data: the faulted session equals the clean one of the same plan
    # up to the mock seed, so compare the structure and the values' plausibility
    clean = read_dataset(FIXTURES / "quick-lambert")
    faulted = read_dataset(FIXTURES / "quick-faults")
    assert clean.geometries().equals(faulted.geometries())
    assert abs(faulted.table.beta - 0.5).max() < 0.05


def test_a_different_request_fails_loudly_naming_the_index(tmp_path, capsys):
    src = (FIXTURES / "quick-lambert.jsonl").read_text().splitlines()
    k = next(i for i, ln in enumerate(src) if '"WAVE 500.0\\n"' in ln)
    src[k] = src[k].replace("WAVE 500.0", "WAVE 501.0")
    bad = tmp_path / "edited.jsonl"
    bad.write_text(reseal("\n".join(src) + "\n"))      # a valid chain: the replay must notice
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    index = sum(1 for ln in src[1:k] if '"dir":"tx"' in ln)
    assert f"request {index} (transcript line {k + 1}) differs" in err
    assert "WAVE 501.0" in err and "WAVE 500.0" in err


def test_replay_with_another_plan_fails(tmp_path, capsys):
    assert main(["replay", str(FIXTURES / "quick-lambert.jsonl"),
                 "--plan", str(FIXTURES / "red-cotton-small.toml"), "--out", str(tmp_path / "r")]) == 2
    assert "was recorded with plan 'quick'" in capsys.readouterr().err


def test_truncated_transcript_fails(tmp_path, capsys):
    src = (FIXTURES / "quick-lambert.jsonl").read_text().splitlines()
    short = tmp_path / "short.jsonl"
    short.write_text("\n".join(src[:200]) + "\n")
    assert main(["replay", str(short), "--plan", "quick", "--out", str(tmp_path / "r")]) == 1
    assert "the transcript ends" in capsys.readouterr().err


def test_record_then_replay_round_trip(drv, tmp_path):
    plan = drv.write_plan(tmp_path, "rec", incidence=(30,), in_plane=(-60, 10), wavelengths=(500,),
                          readings=8)
    with MockInstrument(sample="red-cotton", speed="fast", seed=4,
                        faults="garbled=0.1,modbus_busy=0.1") as mock:
        res = drv.run(mock, plan, tmp_path / "run", record=tmp_path / "t.jsonl")
        assert res.exit_code == 0
    t = load_transcript(tmp_path / "t.jsonl")
    assert t.header["seed"] == 4 and t.header["plan"] == "rec"
    kinds = {(m["ch"], m["dir"]) for m in t.messages}
    assert kinds == {("serial", "tx"), ("serial", "rx"), ("modbus", "tx"), ("modbus", "rx")}
    assert all(m["t"] >= 0 for m in t.messages)
    assert any(m["payload"] == {"exception": 6} for m in t.messages)
    assert main(["replay", str(tmp_path / "t.jsonl"), "--plan", str(plan), "--out", str(tmp_path / "rp")]) == 0
    assert (tmp_path / "rp" / "radiance.csv").read_bytes() == (tmp_path / "run" / "radiance.csv").read_bytes()
    assert (tmp_path / "rp" / "meta.json").read_bytes() == (tmp_path / "run" / "meta.json").read_bytes()


def test_bad_transcript_is_a_usage_error(tmp_path, capsys):
    p = tmp_path / "x.jsonl"
    p.write_text("hello\n")
    assert main(["replay", str(p), "--plan", "quick", "--out", str(tmp_path / "r")]) == 2
    assert "not a transcript header" in capsys.readouterr().err


@pytest.mark.parametrize("edit,needle", [
    (lambda m: {**m, "payload": "\u20ac"} if m.get("ch") == "serial" else m, "bytes 0..255"),
    (lambda m: {**m, "payload": [1]} if m.get("ch") == "modbus" else m, "must be an object"),
    (lambda m: {**m, "payload": {"registers": [70000]}}
     if m.get("ch") == "modbus" and m.get("dir") == "rx" and "registers" in m.get("payload", {})
     else m, "is malformed"),
])
def test_corrupt_transcripts_are_clear_errors(tmp_path, capsys, edit, needle):
    lines = (FIXTURES / "quick-lambert.jsonl").read_text().splitlines()
    edited = [lines[0]] + [json.dumps(edit(json.loads(x))) for x in lines[1:]]
    bad = tmp_path / "bad.jsonl"
    bad.write_text(reseal("\n".join(edited) + "\n"))
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


def test_refused_points_are_never_sent(drv, tmp_path):
    """Expected beam-block points (skip_blocked = true) are listed, skipped, and never reach the
    controller; a plan with out-of-limit points is refused before anything is sent (the
    validation of check-plan)."""
    from gonio import instrument as P
    from gonio.acquisition.engine import AcquisitionError

    bad = drv.write_plan(tmp_path, "refuse", incidence=(30, 88), in_plane=(-32, -28, -25, 10, 87),
                         wavelengths=(550,), readings=4, geometry_extra="skip_blocked = true")
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=9) as mock:
        with pytest.raises(AcquisitionError, match="out of the soft limits"):
            drv.run(mock, bad, tmp_path / "bad", record=tmp_path / "bad.jsonl")
        assert mock.frontend.requests == 0
    plan = drv.write_plan(tmp_path, "skip", incidence=(30,), in_plane=(-32, -28, -25, 10),
                          wavelengths=(550,), readings=4, geometry_extra="skip_blocked = true")
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=9) as mock:
        res = drv.run(mock, plan, tmp_path / "run", record=tmp_path / "t.jsonl")
        assert mock.controller.axes[1].fault == 0
    assert res.status == "complete" and res.points_total == 2 and res.points_measured == 2
    messages = load_transcript(tmp_path / "t.jsonl").messages
    targets = {0: set(), 1: set()}
    for m in messages:
        p = m["payload"]
        if m["dir"] == "tx" and m["ch"] == "modbus" and p.get("fn") == "write_registers":
            for a in (0, 1):
                if p["address"] == P.axis_target_address(a):
                    targets[a].add(P.registers_to_int32(p["values"][0], p["values"][1]))
        assert not (m["dir"] == "rx" and isinstance(p, dict) and "exception" in p), p
    assert not targets[1] & {-32_000, -28_000}
    assert {-25_000, 10_000} <= targets[1]
    meta = read_dataset(tmp_path / "run").meta["provenance"]
    assert len(meta["unmeasurable"]) == 2 and meta["points_planned"] == 2


def test_an_edited_reply_with_a_recomputed_checksum_fails_the_integrity_check(tmp_path, capsys):
    """A reply edited with its *HH checksum recomputed replayed with exit 0; the
    transcript's SHA-256 chain now fails at that line (exit 1, the line named)."""
    from gonio import instrument as P

    src = (FIXTURES / "quick-lambert.jsonl").read_text().splitlines()
    k = next(i for i, ln in enumerate(src) if '"dir":"rx"' in ln and "READ" not in ln
             and json.loads(ln)["ch"] == "serial" and "," in json.loads(ln)["payload"]
             and json.loads(ln)["payload"][0].isdigit())
    m = json.loads(src[k])
    payload = m["payload"].split("*")[0]
    mean, rest = payload.split(",", 1)
    forged = f"{float(mean) * 1.5:.1f},{rest}"
    m["payload"] = P.format_response(forged, True).decode("latin-1")
    h = m.pop("h")
    src[k] = json.dumps(m, separators=(",", ":"))[:-1] + f',"h":"{h}"}}'
    bad = tmp_path / "forged.jsonl"
    bad.write_text("\n".join(src) + "\n")
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert f"line {k + 1}: integrity check failed" in err and "Traceback" not in err
    assert not (tmp_path / "r" / "radiance.csv").exists()
    # the same edit, chain recomputed, is replayed (the chain detects edits, it does not
    # authenticate) - and the forged reading shows in the dataset
    bad.write_text(reseal("\n".join(src) + "\n"))
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r2")]) == 0
    assert ((tmp_path / "r2" / "radiance.csv").read_bytes()
            != (FIXTURES / "quick-lambert" / "radiance.csv").read_bytes())


def test_a_transcript_without_integrity_hashes_is_refused(tmp_path, capsys):
    lines = (FIXTURES / "quick-lambert.jsonl").read_text().splitlines()
    header = json.loads(lines[0])
    stripped = [json.dumps({**header, "format": "gonio-transcript/1"})]
    stripped += [json.dumps({k: v for k, v in json.loads(x).items() if k != "h"}) for x in lines[1:]]
    bad = tmp_path / "old.jsonl"
    bad.write_text("\n".join(stripped) + "\n")
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r")]) == 2
    assert "no integrity check" in capsys.readouterr().err
    # the header kept at /2 and the hashes removed: the first message line is named
    bad.write_text("\n".join([lines[0]] + stripped[1:]) + "\n")
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r")]) == 1
    assert "line 2: no integrity hash" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["quick-lambert", "quick-faults"])
def test_the_head_is_the_one_owner_of_the_shutter(name):
    """A session commands the shutter through the head only: the controller's
    shutter coil is read (the witness of a shutter closed under a point), never written; the
    head closes the shutter at the start and at the end."""
    from gonio.instrument.modbus_map import COIL_SHUTTER

    messages = load_transcript(FIXTURES / f"{name}.jsonl").messages
    requests = [m for m in messages if m["dir"] == "tx"]
    coil = [m["payload"] for m in requests if m["ch"] == "modbus"
            and m["payload"].get("address") == COIL_SHUTTER and "coil" in m["payload"]["fn"]]
    assert coil and all(p["fn"] == "read_coils" for p in coil)
    serial = [m["payload"] for m in requests if m["ch"] == "serial"]
    shutter = [p for p in serial if isinstance(p, str) and p.startswith("SHUTTER ")]
    assert shutter[0] == "SHUTTER CLOSE\n" and shutter[-1] == "SHUTTER CLOSE\n"


def test_a_safe_stop_closes_the_shutter_with_the_coil_only_when_the_head_failed():
    from gonio.acquisition.engine import Engine

    calls: list[str] = []

    class Head:
        def __init__(self, ok):
            self.ok = ok

        def shutdown(self):
            calls.append("head")
            return self.ok

    class Motion:
        def set_shutter(self, open_):
            calls.append(f"coil {open_}")

        def shutdown(self):
            calls.append("drives")

    for ok, expected in ((True, ["head", "drives"]), (False, ["head", "coil False", "drives"])):
        calls.clear()
        engine = Engine.__new__(Engine)
        engine.head, engine.motion = Head(ok), Motion()
        engine._make_safe()
        assert calls == expected
