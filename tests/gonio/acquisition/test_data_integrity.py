"""Data that could be lost or silently wrong: retry counts, run-directory lock,
instrument claim, calibration validity, demo output, plan validation, resume, transcripts."""

from __future__ import annotations

import json
import logging

import pytest

from fabric_optics.cli.gonio import main
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
        # no timeout faults here: a generous link timeout keeps a loaded machine from adding
        # no-response retries of its own to the exact count
        res = drv.run(mock, plan, tmp_path / "run", timeout_s=1.0)
        injected = dict(mock.stats["faults"])
    names = {"checksum": "serial_checksum", "garbled": "serial_garbled", "busy": "head_busy",
             "truncated": "serial_truncated"}
    counted = {names[k]: v for k, v in injected.items() if v}
    assert injected["checksum"] > 20
    assert res.retries == counted
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["provenance"]["retries"] == counted


# --- helpers ----------------------------------------------------------------------------------

def _acquire_argv(mock, plan, out, *extra):
    return ["acquire", "--plan", str(plan), "--modbus", mock.modbus_url, "--serial", mock.serial_url,
            "--out", str(out), "--timeout", "0.3", "--no-progress", "--seed", str(mock.seed),
            *map(str, extra)]


def _one_line_error(capsys, needle):
    err = capsys.readouterr().err.strip()
    assert needle in err, err
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    return err


def _writes(mock) -> int:
    """Write requests the mock controller executed (the CLI's connect-time probe only reads)."""
    return mock.stats.get("modbus_writes", 0)


def _journal_points(out):
    from gonio.acquisition.journal import read_journal
    return read_journal(out / "journal.jsonl").of_type("point")


# --- item 1: --record never overwrites, never names the run's own files ---------------------

def test_record_refuses_an_existing_file_and_the_run_directory_files(drv, tmp_path, capsys):
    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert main(_acquire_argv(mock, plan, run)) == 0
        capsys.readouterr()
        journal = (run / "journal.jsonl").read_bytes()
        # the journal itself, by any spelling
        for target in (run / "journal.jsonl", run / "." / "journal.jsonl"):
            assert main(_acquire_argv(mock, plan, run, "--resume", "--record", target)) == 2
            _one_line_error(capsys, "file of the run directory")
        assert (run / "journal.jsonl").read_bytes() == journal
        # a new run directory: its journal-to-be and dataset files are refused too
        for name in ("journal.jsonl", "radiance.csv", "meta.json"):
            assert main(_acquire_argv(mock, plan, tmp_path / "new", "--record",
                                      tmp_path / "new" / name)) == 2
            _one_line_error(capsys, "file of the run directory")
        assert not (tmp_path / "new" / "journal.jsonl").exists()
        # an existing transcript (any existing file) is never overwritten
        other = tmp_path / "other.jsonl"
        other.write_text("precious\n")
        assert main(_acquire_argv(mock, plan, tmp_path / "run2", "--record", other)) == 2
        _one_line_error(capsys, "the file exists")
        assert other.read_text() == "precious\n"
        assert not (tmp_path / "run2" / "journal.jsonl").exists()
        # a new file in the run directory is fine
        assert main(_acquire_argv(mock, plan, tmp_path / "run3", "--record",
                                  tmp_path / "run3" / "session.jsonl")) == 0
    assert (run / "journal.jsonl").read_bytes() == journal


# --- item 2: one session per run directory ----------------------------------------------------

def test_a_second_session_on_a_locked_run_directory_is_refused(drv, tmp_path, capsys):
    from gonio.acquisition.rundir import RunDirLock

    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert main(_acquire_argv(mock, plan, run)) == 0
        capsys.readouterr()
        journal = (run / "journal.jsonl").read_bytes()
        writes = _writes(mock)
        with RunDirLock.acquire(run):          # another session holds the run directory
            for extra in ((), ("--resume",)):
                assert main(_acquire_argv(mock, plan, run, *extra)) == 2
                _one_line_error(capsys, "another gonio session is using this run directory")
        assert _writes(mock) == writes          # nothing commanded (connect-time probes aside)
        assert (run / "journal.jsonl").read_bytes() == journal
        # released: --resume works again
        assert main(_acquire_argv(mock, plan, run, "--resume")) == 0


def test_the_lock_is_held_for_the_whole_session(drv, tmp_path):
    """A second lock attempt fails at every exchange of a running session, dataset write
    included (checked from inside the session, at deterministic moments)."""
    from gonio.acquisition.plan import load_plan
    from gonio.acquisition.rundir import RunDirLock, RunDirLocked
    from gonio.acquisition.session import run_session
    from gonio.data import dataset as dataset_module
    from gonio.instrument import RetryPolicy
    from gonio.instrument.transport import ModbusTransport, SerialTransport

    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    probes = []

    def probe():
        try:
            RunDirLock.acquire(run).release()
            probes.append(False)
        except RunDirLocked:
            probes.append(True)

    class Probing(SerialTransport):
        def exchange(self, line, **kw):
            probe()
            return super().exchange(line, **kw)

    real_write = dataset_module.write_dataset

    def write_and_probe(ds, out):
        probe()
        return real_write(ds, out)

    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        try:
            import gonio.acquisition.subscribers
            gonio.acquisition.subscribers.write_dataset = write_and_probe
            res = run_session(load_plan(plan), ModbusTransport(mock.modbus_url, timeout_s=0.3),
                              Probing(mock.serial_url, timeout_s=0.3), run, progress=False,
                              seed=SEED, retry=RetryPolicy(base_s=0.002))
        finally:
            gonio.acquisition.subscribers.write_dataset = real_write
    assert res.exit_code == 0
    assert len(probes) > 20 and all(probes)
    RunDirLock.acquire(run).release()          # released at the end


# --- item 7: acquire refuses what check-plan refuses ----------------------------------------

@pytest.mark.parametrize("kw,needle", [
    ({"incidence": (0, 1e9)}, "out of the soft limits"),
    ({"incidence": (30,), "in_plane": (-30, 20)}, "beam-block zone and skip_blocked = false"),
])
def test_acquire_refuses_plans_that_check_plan_refuses(drv, tmp_path, capsys, kw, needle):
    plan = _plan(drv, tmp_path, "refused", **kw)
    assert main(["check-plan", "--plan", str(plan)]) == 1
    capsys.readouterr()
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert main(_acquire_argv(mock, plan, tmp_path / "run")) == 2
        _one_line_error(capsys, needle)
        assert _writes(mock) == 0               # nothing commanded (connect-time probes aside)
    assert not (tmp_path / "run" / "journal.jsonl").exists()


# --- item 8: wavelengths finer than the head's 0.1 nm step ----------------------------------

@pytest.mark.parametrize("wavelengths,extra,needle", [
    ("list_nm = [500.01, 500.04]", "", "'wavelengths.list_nm': wavelength 500.01 nm is finer"),
    ("start_nm = 500\nstop_nm = 501\nstep_nm = 0.05", "", "'wavelengths.step_nm': wavelength 500.05"),
    ("start_nm = 500.25\nstop_nm = 501\nstep_nm = 0.5", "", "'wavelengths.start_nm': wavelength 500.25"),
])
def test_wavelengths_finer_than_the_monochromator_step_are_refused(tmp_path, capsys, wavelengths,
                                                                     extra, needle):
    from gonio.acquisition.plan import PlanError, load_plan

    path = tmp_path / "fine.toml"
    path.write_text(f'[sample]\nname = "x"\n[wavelengths]\n{wavelengths}\n'
                    '[geometry]\nincidence_deg = [0]\nin_plane_deg = [45]\n')
    with pytest.raises(PlanError, match=needle.replace("(", r"\(").replace(".", r"\.")):
        load_plan(path)
    assert main(["check-plan", "--plan", str(path)]) == 2
    _one_line_error(capsys, needle)


def test_wavelengths_on_the_grid_are_kept_exactly(tmp_path):
    from gonio.acquisition.plan import load_plan

    path = tmp_path / "grid.toml"
    path.write_text('[sample]\nname = "x"\n[wavelengths]\nstart_nm = 500\nstop_nm = 500.5\n'
                    'step_nm = 0.1\n[geometry]\nincidence_deg = [0]\nin_plane_deg = [45]\n')
    assert list(load_plan(path).wavelengths_nm) == [500.0, 500.1, 500.2, 500.3, 500.4, 500.5]


# --- item 10: the dataset writer's stale temporary files ------------------------------------

def test_stale_temporary_dataset_files_are_removed_on_resume(drv, tmp_path):
    import os
    import tempfile

    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert drv.run(mock, plan, run).exit_code == 0
        # what a SIGKILL inside atomic_write leaves: mkstemp's own names
        stale = []
        for name in ("radiance.csv", "meta.json"):
            fd, p = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=run)
            os.write(fd, b"half a dataset")
            os.close(fd)
            stale.append(p)
        keep = [run / ".radiance.csv.mine.tmp", run / "notes.tmp", run / "radiance.csv.tmp",
                run / ".radiance.csv.abcdefgh.tmp.bak"]
        for k in keep:
            k.write_text("not the writer's")
        assert drv.run(mock, plan, run, resume=True).exit_code == 0
    assert not any(os.path.exists(p) for p in stale)
    assert all(k.read_text() == "not the writer's" for k in keep)


# --- item 5: demo replaces only a previous demo's output ------------------------------------

def test_demo_replaces_only_a_previous_demo(drv, tmp_path, capsys):
    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert drv.run(mock, plan, run).exit_code == 0
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    demo = ["demo", "--plan", str(plan), "--no-progress", "--out"]
    # another run's folder: refused, --force included, nothing touched, no mock started
    for force in ((), ("--force",)):
        assert main(demo + [str(run), *force]) == 2
        _one_line_error(capsys, "a run folder is never replaced")
        assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    # a demo folder is replaced by the next demo (asked with --force)
    out = tmp_path / "demo"
    assert main(demo + [str(out)]) == 0
    assert main(demo + [str(out), "--force"]) == 0
    capsys.readouterr()
    assert len(_journal_points(out)) == 6
    # a demo folder whose journal another session replaced is not the demo's any more
    (out / "journal.jsonl").write_bytes(before["journal.jsonl"])
    for force in ((), ("--force",)):
        assert main(demo + [str(out), *force]) == 2
        _one_line_error(capsys, "a run folder is never replaced")
        assert (out / "journal.jsonl").read_bytes() == before["journal.jsonl"]


# --- item 4: the calibration is validated, never stored or reused when invalid --------------

def _session(mock, plan, out, serial_cls=None, **kw):
    from gonio.acquisition.plan import load_plan
    from gonio.acquisition.session import run_session
    from gonio.instrument import RetryPolicy
    from gonio.instrument.transport import ModbusTransport, SerialTransport

    serial_cls = serial_cls or SerialTransport
    return run_session(load_plan(plan), ModbusTransport(mock.modbus_url, timeout_s=0.3),
                       serial_cls(mock.serial_url, timeout_s=0.3), out, progress=False,
                       seed=mock.seed, retry=RetryPolicy(base_s=0.002), **kw)


def test_white_standard_with_the_shutter_closed_is_refused_then_measured_again(drv, tmp_path,
                                                                               caplog):
    """The shutter stays closed during calibration (every SHUTTER OPEN becomes CLOSE on the
    wire): the run stops safely (exit 1) without journaling that calibration; the resume
    measures it again and the dataset equals a clean run's."""
    from gonio.instrument.transport import SerialTransport

    class ShutterStuck(SerialTransport):
        def exchange(self, line, **kw):
            return super().exchange(line.replace(b"SHUTTER OPEN", b"SHUTTER CLOSE"), **kw)

    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert _session(mock, plan, tmp_path / "clean").exit_code == 0
        res = _session(mock, plan, tmp_path / "run", serial_cls=ShutterStuck)
        assert res.exit_code == 1 and res.status == "stopped"
        assert "white standard at 450 nm" in res.message and "shutter open" in res.message
        assert mock.controller.shutter_open is False
        from gonio.acquisition.journal import read_journal
        content = read_journal(tmp_path / "run" / "journal.jsonl")
        assert content.of_type("calibration") == [] and content.of_type("point") == []
        assert [e["what"] for e in content.of_type("event")] == ["calibration_invalid",
                                                                  "session_end"]
        res = _session(mock, plan, tmp_path / "run", resume=True)
    assert res.exit_code == 0 and res.points_measured == 6
    assert ((tmp_path / "run" / "radiance.csv").read_bytes()
            == (tmp_path / "clean" / "radiance.csv").read_bytes())


def test_an_invalid_journaled_calibration_is_measured_again_with_its_points(drv, tmp_path, caplog):
    """A journal from before the check holds a calibration with the white standard at the dark
    level (and points measured with it): resume never reuses it, measures the calibration and
    those points again, and says why."""
    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert _session(mock, plan, tmp_path / "clean").exit_code == 0
        assert _session(mock, plan, run).exit_code == 0
        lines = (run / "journal.jsonl").read_text().splitlines()
        records = [json.loads(x) for x in lines]
        cal = next(r for r in records if r["type"] == "calibration")
        darks = {(d["itime_ms"], d["gain"]): d for d in cal["darks"]}
        for r in cal["reference"]:
            r["mean"] = darks[(r["itime_ms"], r["gain"])]["mean"]
        kept = [r for r in records if r["type"] != "event"][:-2]   # last two points not measured
        (run / "journal.jsonl").write_text("".join(json.dumps(r) + "\n" for r in kept))
        with caplog.at_level(logging.INFO, logger="gonio"):
            res = _session(mock, plan, run, resume=True)
    assert res.exit_code == 0 and res.points_measured == 6
    assert "calibration measured again: the journal's calibration 0 is invalid" in caplog.text
    from gonio.acquisition.journal import read_journal
    content = read_journal(run / "journal.jsonl")
    assert len(content.of_type("calibration")) == 2
    assert len(content.of_type("point")) == 4 + 6         # every point measured again
    assert ((run / "radiance.csv").read_bytes()
            == (tmp_path / "clean" / "radiance.csv").read_bytes())


# --- item 9: the journal is not trusted blindly on resume -----------------------------------

@pytest.mark.parametrize("edit,needle", [
    (lambda p: p.update(geometry=[45, 0, 33, 180]), "line 4: point at geometry (45, 0, 33, 180) "
                                                    "is not a measurable point"),
    (lambda p: p.update(axes_deg=[45, 33, 0, 0]), "line 4: point at geometry"),
])
def test_resume_refuses_a_journal_point_that_is_not_in_the_plan(drv, tmp_path, capsys, edit,
                                                                 needle):
    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert _session(mock, plan, run).exit_code == 0
        records = [json.loads(x) for x in (run / "journal.jsonl").read_text().splitlines()]
        points = [k for k, r in enumerate(records) if r["type"] == "point"]
        assert points[1] == 3                       # line 4
        edit(records[points[1]])
        text = "".join(json.dumps(r) + "\n" for r in records)
        (run / "journal.jsonl").write_text(text)
        assert main(_acquire_argv(mock, plan, run, "--resume")) == 2
        _one_line_error(capsys, needle)
    assert (run / "journal.jsonl").read_text() == text


# --- item 3: the instrument is claimed; another client taking it stops the session ---------

def test_another_client_taking_the_instrument_stops_the_session_safely(drv, tmp_path):
    """A second client writes its owner token while the session measures (at the 40th head
    command, mid-point): the session stops safely (exit 1, shutter closed, drives stopped),
    keeps the points journaled before, and stores nothing measured after the takeover."""
    from gonio.instrument import MotionController
    from gonio.instrument.transport import ModbusTransport, SerialTransport

    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    seen = {}

    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        intruder = MotionController(ModbusTransport(mock.modbus_url, timeout_s=0.3))

        class Intruded(SerialTransport):
            n = 0

            def exchange(self, line, **kw):
                Intruded.n += 1
                if Intruded.n == 40 + 20:      # 20 commands into the points
                    seen["points"] = len(_journal_points(run))
                    seen["owner"] = mock.controller.owner
                    intruder.claim(0xBEEF)
                return super().exchange(line, **kw)

        res = _session(mock, plan, run, serial_cls=Intruded)
        assert mock.controller.shutter_open is False
        assert all(ax.motion is None for ax in mock.controller.axes)
        assert mock.controller.owner == 0xBEEF        # not released: not ours any more
        intruder.transport.close()
    assert seen["owner"] not in (0, 0xBEEF)            # the session had claimed it
    assert 1 <= seen["points"] < 6
    assert res.exit_code == 1 and res.status == "stopped"
    assert "another client took the instrument" in res.message
    assert res.points_measured == seen["points"] == len(_journal_points(run))


def test_owner_token_released_at_the_end_and_serial_line_opened_exclusively(drv, tmp_path,
                                                                             capsys):
    from gonio.instrument.transport import LinkLost, SerialTransport

    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert _session(mock, plan, tmp_path / "run").exit_code == 0
        assert mock.controller.owner == 0
        first = SerialTransport(mock.serial_url)
        first.open()
        try:
            with pytest.raises(LinkLost, match="exclusive"):
                SerialTransport(mock.serial_url).open()
            assert main(_acquire_argv(mock, plan, tmp_path / "second")) == 2
            _one_line_error(capsys, "--serial: cannot reach the device")
        finally:
            first.close()


def test_a_shutter_closed_under_the_session_discards_the_point(drv, tmp_path):
    """Another client's safe stop closes the shutter mid-point (the session still owns the
    instrument): the point is not journaled (its last readings would be dark), the session
    stops safely (exit 1) and the resume completes with the data of a clean run."""
    from gonio.instrument import MotionController
    from gonio.instrument.transport import ModbusTransport, SerialTransport

    plan = _plan(drv, tmp_path)
    run = tmp_path / "run"
    seen = {}
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert _session(mock, plan, tmp_path / "clean").exit_code == 0
        other = MotionController(ModbusTransport(mock.modbus_url, timeout_s=0.3))

        class Interfered(SerialTransport):
            n = 0

            def exchange(self, line, **kw):
                Interfered.n += 1
                if Interfered.n == 60:
                    assert not line.startswith(b"SHUTTER")     # mid-point, not reopening it
                    seen["points"] = len(_journal_points(run))
                    other.set_shutter(False)
                return super().exchange(line, **kw)

        res = _session(mock, plan, run, serial_cls=Interfered)
        other.transport.close()
        assert res.exit_code == 1 and "shutter was closed during the point" in res.message
        assert res.points_measured == seen["points"] == len(_journal_points(run)) >= 1
        assert _session(mock, plan, run, resume=True).exit_code == 0
    assert (run / "radiance.csv").read_bytes() == (tmp_path / "clean" / "radiance.csv").read_bytes()
