"""The journal's integrity chain: an edited reading is detected on --resume with one
line (exit 2); a kill's torn last line still is not an error; journals written before the chain
stay readable and are chained from the next append on."""

from __future__ import annotations

import json
import logging
import re

import pytest

from fabric_optics.cli.gonio import main
from gonio.acquisition.journal import Journal, JournalIntegrityError, parse_journal, read_journal
from gonio.mock import MockInstrument

_START = {"type": "start", "plan": "p", "plan_sha256": "a", "standard_sha256": "b", "time": 1.0}


def _point(i, mean=1234.5):
    return {"type": "point", "index": i, "axes_deg": [0, 10.0 * i, 0, 0],
            "geometry": [0, 0, 10.0 * i, 180], "calibration": 0,
            "readings": [{"wavelength_nm": 500.0, "itime_ms": 10, "gain": 0, "mean": mean,
                          "sem": 1.5, "n": 8, "ranging": 0}]}


def _journal(path, n=3) -> bytes:
    j, _ = Journal.open(path)
    j.append(_START)
    for i in range(n):
        j.append(_point(i))
    j.close()
    return path.read_bytes()


def _unchained(records) -> bytes:
    """A journal as a gonio before the chain wrote it (compact JSON, no "h")."""
    return b"".join(json.dumps(r, separators=(",", ":")).encode() + b"\n" for r in records)


def test_every_line_is_chained_and_an_edited_reading_is_named(tmp_path):
    path = tmp_path / "j.jsonl"
    data = _journal(path)
    assert all(b',"h":"' in line for line in data.splitlines())
    assert not read_journal(path).unchained_lines
    edited = data.replace(b'"mean":1234.5', b'"mean":12345', 2)     # first point: line 2
    assert edited.count(b'"mean":12345') == 2
    path.write_bytes(edited)
    with pytest.raises(JournalIntegrityError, match="line 2: integrity check failed"):
        read_journal(path)
    # a line removed, or inserted without a hash, breaks the chain too
    lines = data.splitlines(keepends=True)
    with pytest.raises(JournalIntegrityError, match="line 3: integrity check failed"):
        parse_journal(b"".join(lines[:2] + lines[3:]))
    inserted = json.dumps(_point(7), separators=(",", ":")).encode() + b"\n"
    with pytest.raises(JournalIntegrityError, match="line 3: no integrity hash"):
        parse_journal(b"".join(lines[:2] + [inserted] + lines[2:]))
    # ... also as the last line, complete with its newline (not a torn line)
    with pytest.raises(JournalIntegrityError, match="line 5: no integrity hash"):
        parse_journal(data + inserted)


@pytest.mark.parametrize("cut", [1, 30, 150, -3, -1])
def test_a_torn_last_line_is_not_an_integrity_error(tmp_path, cut):
    """What a kill leaves (any prefix of the last line, with the newline missing or not) is a
    torn line, cut on open; the chain continues from the line before."""
    path = tmp_path / "j.jsonl"
    data = _journal(path)
    last = data.rstrip(b"\n").rfind(b"\n") + 1
    path.write_bytes(data[:last + cut] if cut > 0 else data[:cut])
    content = read_journal(path)
    assert content.torn and len(content.of_type("point")) == (3 if cut == -1 else 2)
    j, _ = Journal.open(path)
    j.append(_point(9))
    j.close()
    assert [r["index"] for r in read_journal(path).of_type("point")][-1] == 9


def test_an_old_journal_without_a_chain_is_read_then_chained(tmp_path):
    path = tmp_path / "j.jsonl"
    old = [_START, _point(0), _point(1)]
    path.write_bytes(_unchained(old))
    content = read_journal(path)
    assert content.records == old and content.unchained_lines == 3
    j, _ = Journal.open(path)
    j.append(_point(2))
    j.close()
    content = read_journal(path)
    assert content.records == old + [_point(2)] and content.unchained_lines == 3
    # from now on an edit of an old line breaks the chain at the first chained line
    path.write_bytes(path.read_bytes().replace(b'"mean":1234.5', b'"mean":12345', 1))
    with pytest.raises(JournalIntegrityError, match="line 4: integrity check failed"):
        read_journal(path)


def _plan(drv, tmp_path):
    return drv.write_plan(tmp_path, "chain", incidence=(0, 45), in_plane=(-30, 20, 50),
                          wavelengths=(450, 550), readings=8)


def _acquire(mock, plan, out, *extra):
    return main(["acquire", "--plan", str(plan), "--modbus", mock.modbus_url, "--serial", mock.serial_url,
                 "--out", str(out), "--timeout", "0.5", "--no-progress", *extra])


def _stopped_run(drv, mock, plan, run) -> list[bytes]:
    """A run whose last two points and session end are cut off (as if killed): resumable."""
    assert drv.run(mock, plan, run).exit_code == 0
    lines = (run / "journal.jsonl").read_bytes().splitlines(keepends=True)
    points = [k for k, x in enumerate(lines) if b'"type":"point"' in x]
    kept = lines[:points[-2]]
    (run / "journal.jsonl").write_bytes(b"".join(kept))
    return kept


def test_resume_refuses_a_reading_multiplied_by_ten(drv, tmp_path, capsys):
    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=4) as mock:
        lines = _stopped_run(drv, mock, plan, run)
        k = next(k for k, x in enumerate(lines) if b'"type":"point"' in x)
        mean = re.search(rb'"mean":([0-9.e+-]+)', lines[k])
        assert mean is not None
        lines[k] = lines[k].replace(mean.group(0),
                                    b'"mean":' + repr(float(mean.group(1)) * 10).encode(), 1)
        edited = b"".join(lines)
        (run / "journal.jsonl").write_bytes(edited)
        capsys.readouterr()
        assert _acquire(mock, plan, run, "--resume") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert f"journal.jsonl: line {k + 1}: integrity check failed" in err[0]
    assert (run / "journal.jsonl").read_bytes() == edited          # nothing appended


def test_resume_of_a_journal_written_before_the_chain(drv, tmp_path, caplog):
    """The same run resumed from its unchained copy completes with the same dataset as an
    uninterrupted run, and says that the old records were read unchecked."""
    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=4) as mock:
        assert drv.run(mock, plan, tmp_path / "clean").exit_code == 0
        kept = _stopped_run(drv, mock, plan, run)
        old = [json.loads(x) for x in kept]
        for r in old:
            r.pop("h")
        (run / "journal.jsonl").write_bytes(_unchained(old))
        with caplog.at_level(logging.WARNING, logger="gonio"):
            assert drv.run(mock, plan, run, resume=True).exit_code == 0
    assert f"first {len(old)} records were written without an integrity chain" in caplog.text
    content = read_journal(run / "journal.jsonl")
    assert content.unchained_lines == len(old) and len(content.of_type("point")) == 6
    assert ((run / "radiance.csv").read_bytes()
            == (tmp_path / "clean" / "radiance.csv").read_bytes())
