"""The live view of an acquisition (`gonio acquire --live`, `gonio demo --live`, gonio.acquisition.live).

Against the mock instrument with an axis fault injected mid-run: the state endpoint follows the points
as they arrive and ends on the dataset as written; the page is reached only on 127.0.0.1, only with
its token, only by GET; clients that drop mid-run, a view that fails and a server that dies leave the
acquisition and its dataset as they are without the view; and the page itself, opened in headless
Chromium, draws the curves with Plotly, shows the fault and the finished dataset, without a console
error. With FABRIC_OPTICS_WRITE_DOCS_FIGURES=1 the browser test writes its screenshots into
docs/figures/ (live-view-running.png, live-view-finished.png), the ones the manual shows.
"""

from __future__ import annotations

import http.client
import json
import os
import socket
import struct
import subprocess
import sys
import textwrap
import threading
import time
from itertools import pairwise
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
import pytest

from fabric_optics.cli.gonio import main
from gonio.acquisition.journal import read_journal
from gonio.acquisition.live import LiveServer, LiveView
from gonio.acquisition.plan import load_plan
from gonio.acquisition.session import run_session
from gonio.data import read_dataset
from gonio.instrument import RetryPolicy
from gonio.instrument.transport import ModbusTransport, SerialTransport
from gonio.mock import MockInstrument

ROOT = Path(__file__).resolve().parents[3]
CHROMIUM = "/usr/bin/chromium"
SEED = 3
#: an axis fault at the 20th move command: about a third into the run (the driver re-homes and goes on)
FAULTS = "axis_fault=@20"
#: the flags Debian's chromium runs headless with here (no network of its own, no GPU)
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _plan(folder: Path, step: int = 10, wavelengths=(450, 550, 650)) -> Path:
    """Three incidences, in-plane every ``step`` degrees and two directions out of the plane (the
    beam-block points at the incidences skipped)."""
    path = folder / "red-cotton-live.toml"
    path.write_text(textwrap.dedent(f"""
        name = "red-cotton-live"
        [sample]
        name = "red cotton on the mock"
        [wavelengths]
        list_nm = {list(wavelengths)}
        [geometry]
        incidence_deg = [0, 30, 60]
        in_plane = {{start = -60, stop = 70, step = {step}}}
        directions_deg = [[45, 90], [30, 90]]
        skip_blocked = true
        [acquisition]
        itime_ms = 20
        readings = 8
        settle_ms = 0
        velocity_deg_s = 60
        """))
    return path


def _get(url: str, *, method: str = "GET", host: str | None = None) -> tuple[int, bytes]:
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=10)
    try:
        conn.putrequest(method, parts.path, skip_host=host is not None)
        if host is not None:
            conn.putheader("Host", host)
        conn.endheaders()
        response = conn.getresponse()
        return response.status, response.read()
    finally:
        conn.close()


def _state(url: str) -> dict:
    status, body = _get(url + "state.json")
    assert status == 200, body
    return json.loads(body)


def _comparable_meta(run: Path) -> dict:
    """meta.json without what differs between two runs of one plan on two mocks (time, link URLs), and with
    only the injected fault's retries: a reply late on a loaded machine adds a serial timeout's retry to one
    run and not the other."""
    meta = json.loads((run / "meta.json").read_text())
    meta.pop("created")
    meta.pop("instrument")
    retries = meta["provenance"]["retries"]
    meta["provenance"]["retries"] = {"axis_fault": retries.get("axis_fault", 0)}
    return meta


def _dataset_betas(run: Path) -> dict:
    """(theta_i, phi_i, theta_o, phi_o, wavelength) -> (beta, u_beta) of a written dataset."""
    t = read_dataset(run).table
    return {tuple(round(float(v), 6) for v in row[:5]): (row[5], row[6])
            for row in t[["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm", "beta", "u_beta"]].itertuples(
                index=False)}


def _acquire_in_process(mock, plan_path: Path, out: Path, subscribers=()) -> object:
    plan = load_plan(plan_path)
    return run_session(plan, ModbusTransport(mock.modbus_url, timeout_s=1.0),
                       SerialTransport(mock.serial_url, timeout_s=1.0), out, progress=False, seed=SEED,
                       retry=RetryPolicy(base_s=0.002), subscribers=subscribers)


def _drop_clients(url: str) -> list[socket.socket]:
    """Clients that go away mid-run: a half-sent request, a large answer reset unread, a silent
    connection (returned, held open until the run ends)."""
    parts = urlsplit(url)
    addr = (parts.hostname, parts.port)
    half = socket.create_connection(addr)
    half.sendall(f"GET {parts.path}state.json HTTP/1.1\r\nHost: 127.0.0".encode())
    half.close()
    reset = socket.create_connection(addr)
    reset.sendall(f"GET {parts.path}plotly.min.js HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode())
    reset.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    reset.close()                                   # RST: the server's write fails mid-answer
    return [socket.create_connection(addr)]


def test_state_follows_the_run_and_the_page_is_guarded(drv, tmp_path):
    """`gonio acquire --live` against the mock, an axis fault injected: points arrive, the fault and
    the retry show, the end is the dataset as written, identical to the same run without the view;
    403 without the token or from another Host, 405 for POST, nothing on another address than
    127.0.0.1; clients that drop mid-run change nothing."""
    plan = _plan(tmp_path)
    with MockInstrument(sample="red-cotton", speed="fast", seed=SEED, faults=FAULTS) as mock:
        assert main(["acquire", "--plan", str(plan), "--modbus", mock.modbus_url, "--serial", mock.serial_url,
                     "--out", str(tmp_path / "plain"), "--no-progress", "--seed", str(SEED)]) == 0
    with MockInstrument(sample="red-cotton", speed="fast", seed=SEED, faults=FAULTS) as mock:
        out = tmp_path / "live"
        proc = subprocess.Popen([sys.executable, "-m", "fabric_optics.cli.gonio", "acquire", "--plan", str(plan),
                                 "--modbus", mock.modbus_url, "--serial", mock.serial_url, "--out", str(out),
                                 "--no-progress", "--seed", str(SEED), "--live"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            first = proc.stdout.readline()
            assert first.startswith("gonio acquire: live view at http://127.0.0.1:"), first
            url = first.split()[-1]
            port, token = urlsplit(url).port, urlsplit(url).path.strip("/")
            assert len(token) >= 32
            # guarded: the token, the loopback Host, GET only, the loopback address only
            assert _get(f"http://127.0.0.1:{port}/state.json")[0] == 403
            assert _get(f"http://127.0.0.1:{port}/{token[:-1]}x/state.json")[0] == 403
            assert _get(url + "state.json", host="attacker.example")[0] == 403
            assert _get(url + "state.json", method="POST")[0] == 405
            assert _get(url + "state.json", method="DELETE")[0] == 405
            with pytest.raises(ConnectionRefusedError):
                socket.create_connection(("127.0.0.2", port), timeout=5).close()
            held: list[socket.socket] = []
            seen = []
            deadline = time.monotonic() + 120       # a view that never finishes fails here, not at the suite's timeout
            while time.monotonic() < deadline:
                st = _state(url)
                seen.append(st)
                if not held and st["done"] >= 3:
                    held = _drop_clients(url)
                if st["finished"]:
                    break
                time.sleep(0.02)
            code = proc.wait(timeout=60)
            for s in held:
                s.close()
            stdout, stderr = proc.stdout.read(), proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.stdout.close()
            proc.stderr.close()
        injected = mock.stats["faults"]
    assert code == 0, stderr
    assert (first + stdout).count("live view at") == 1
    assert injected == {"axis_fault": 1}
    # the dataset and the journal are those of the run without the view
    assert (out / "radiance.csv").read_bytes() == (tmp_path / "plain" / "radiance.csv").read_bytes()
    assert _comparable_meta(out) == _comparable_meta(tmp_path / "plain")
    assert _comparable_meta(out)["provenance"]["retries"] == {"axis_fault": 1}
    total = len(load_plan(plan).check().ordered)
    assert len(read_journal(out / "journal.jsonl").of_type("point")) == total
    # points arrived one by one, the position never went back, the time left was given
    running = [s for s in seen if s["status"] == "measuring" and 0 < s["done"] < total]
    assert len({s["done"] for s in running}) >= 3, [s["done"] for s in seen]
    assert all(a["done"] <= b["done"] for a, b in pairwise(seen))
    assert all(s["eta_s"] is not None and s["eta_s"] >= 0 for s in running)
    mid = running[len(running) // 2]
    assert mid["current"]["index"] == mid["done"] + 1
    assert sum(len(c["x"]) for c in mid["curves"]) == mid["done"]
    # the values shown mid-run are the dataset's (the same measurement equation), with their error bars
    final_values = _dataset_betas(out)
    for curve in mid["curves"]:
        for geometry, betas, u_betas in zip(curve["geometry"], curve["beta"], curve["u_beta"], strict=True):
            key = tuple(geometry)
            for wl, b, u in zip(mid["wavelengths_nm"], betas, u_betas, strict=True):
                want = final_values[key + (wl,)]
                assert b == pytest.approx(want[0], rel=1e-8) and u == pytest.approx(want[1], rel=1e-8)
    # the fault: counted where the driver retried it, and in the retry totals
    faulted = [f for f in seen[-1]["faults"] if "axis_fault" in f["kinds"]]
    # (a reply late on a loaded machine may add a serial timeout beside it)
    assert len(faulted) == 1 and faulted[0]["kinds"]["axis_fault"] == 1 and not faulted[0]["error"]
    assert any(s["retries"].get("axis_fault") == 1 for s in running)
    # the end: the dataset as written, every geometry at every wavelength
    end = seen[-1]
    assert end["status"] == "complete" and end["done"] == total and end["dataset"] == str(out)
    assert end["current"] is None and end["eta_s"] == 0
    shown = {}
    for curve in end["curves"]:
        for geometry, betas in zip(curve["geometry"], curve["beta"], strict=True):
            shown[tuple(geometry)] = betas
    assert len(shown) == total
    assert sorted(b for betas in shown.values() for b in betas) == sorted(v[0] for v in final_values.values())


def test_demo_writes_the_same_dataset_with_the_live_view(tmp_path, capsys):
    plain, live = tmp_path / "plain", tmp_path / "live"
    assert main(["demo", "--plan", "quick", "--out", str(plain), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["demo", "--plan", "quick", "--out", str(live), "--no-progress", "--live"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("gonio demo: live view at http://127.0.0.1:") == 1
    assert (live / "radiance.csv").read_bytes() == (plain / "radiance.csv").read_bytes()
    assert _comparable_meta(live) == _comparable_meta(plain)


def test_a_port_in_use_is_a_usage_error(tmp_path, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["demo", "--plan", "quick", "--out", str(tmp_path / "d"), "--no-progress",
                     "--live-port", str(port)]) == 2
    err = capsys.readouterr().err
    assert f"--live-port {port}: cannot listen on 127.0.0.1:{port}" in err and "Traceback" not in err
    assert not (tmp_path / "d").exists()


def test_a_failing_view_or_a_dead_server_leaves_the_acquisition_alone(drv, tmp_path, monkeypatch, caplog):
    """The view raising inside the engine's thread, and its server shut down mid-run: the acquisition
    completes and writes the dataset of a run without them."""
    plan = drv.write_plan(tmp_path, "small", incidence=(0, 45), in_plane=(-30, 20, 50))
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert _acquire_in_process(mock, plan, tmp_path / "plain").exit_code == 0

    view = LiveView(load_plan(plan), tmp_path / "live")
    server = LiveServer(view)
    points = []

    def kill_server_then_break_the_view(name, doc):
        if name == "point":
            points.append(doc)
            if len(points) == 2:
                server.httpd.shutdown()
                server.httpd.server_close()
                import gonio.acquisition.live as live

                monkeypatch.setattr(live, "point_beta", lambda *a, **k: 1 / 0)

    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        result = _acquire_in_process(mock, plan, tmp_path / "live", [kill_server_then_break_the_view, view])
    assert result.exit_code == 0 and result.points_measured == result.points_total == len(points)
    assert not server.thread.is_alive()
    assert view.broken and view.snapshot()["done"] == 1       # it took the first point, broke on the second
    assert [r.getMessage() for r in caplog.records if "live view" in r.getMessage()] == [
        "live view: stopped updating (ZeroDivisionError('division by zero')); the acquisition goes on"]
    assert (tmp_path / "live" / "radiance.csv").read_bytes() == (tmp_path / "plain" / "radiance.csv").read_bytes()
    server.close()      # closing a dead server does not raise


def test_a_stop_by_faults_is_shown_with_what_was_kept(tmp_path):
    """Axis faults at every other move: the driver's retry budget runs out and it stops safely; the
    view ends on the stop's message (an error) and on the dataset of the points kept."""
    out = tmp_path / "run"
    plan = load_plan("quick")
    view = LiveView(plan, out)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=1, faults="axis_fault=0.5") as mock:
        result = run_session(plan, ModbusTransport(mock.modbus_url, timeout_s=0.3),
                             SerialTransport(mock.serial_url, timeout_s=0.3), out, progress=False, seed=1,
                             retry=RetryPolicy(base_s=0.002), subscribers=[view])
    assert result.status == "stopped" and 0 < result.points_measured < result.points_total
    st = view.snapshot()
    assert st["status"] == "stopped" and st["finished"] and st["message"] == result.message
    assert st["done"] == result.points_measured and st["dataset"] == str(out)
    assert [f["text"] for f in st["faults"] if f["error"]] == [result.message]
    retried = sum(f["kinds"].get("axis_fault", 0) for f in st["faults"])
    assert retried == result.retries["axis_fault"] == st["retries"]["axis_fault"]
    values = _dataset_betas(out)
    assert sorted(b for c in st["curves"] for betas in c["beta"] for b in betas) == sorted(
        v[0] for v in values.values())


def test_a_resumed_run_shows_the_journals_points(drv, tmp_path):
    """On ``resume`` the view reads the points already journaled (and shows the dataset's values)."""
    plan_path = drv.write_plan(tmp_path, "small", incidence=(0, 45), in_plane=(-30, 20, 50))
    out = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        assert _acquire_in_process(mock, plan_path, out).exit_code == 0
    view = LiveView(load_plan(plan_path), out)
    view("event", {"type": "event", "what": "resume", "points_done": 6})
    st = view.snapshot()
    assert st["done"] == 6 and st["current"] is None and not view.broken
    values = _dataset_betas(out)
    got = sorted(b for c in st["curves"] for betas in c["beta"] for b in betas)
    np.testing.assert_allclose(got, sorted(v[0] for v in values.values()), rtol=1e-9)


def _chromium_page(playwright):
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: install Debian's chromium with `make browser` "
                    "(the browser tests need it; they are not skipped)")
    return playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)


def test_the_page_in_headless_chromium(drv, tmp_path, monkeypatch):
    """The page during a mock acquisition with an axis fault: Plotly's SVG drawn as points arrive,
    the fault and the retry shown, a second tab closed mid-run, the finished dataset at the end;
    no console error, no failed request."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("playwright is missing: `pip install -e '.[test]'` (it drives Debian's chromium, "
                    "installed by `make browser`)")
    write_docs = os.environ.get("FABRIC_OPTICS_WRITE_DOCS_FIGURES") == "1"
    shots = ROOT / "docs" / "figures" if write_docs else tmp_path
    plan_path = _plan(tmp_path, step=5, wavelengths=(450, 500, 550, 600, 650))
    plan = load_plan(plan_path)
    total = len(plan.check().ordered)
    monkeypatch.chdir(tmp_path)
    out = Path("run1")          # relative, as a user types it: the page shows "dataset in run1"
    view = LiveView(plan, out)
    server = LiveServer(view)
    problems: list[str] = []
    with sync_playwright() as pw, MockInstrument(sample="red-cotton", speed="fast", seed=SEED,
                                                 faults="axis_fault=@40") as mock:
        browser = _chromium_page(pw)
        try:
            page = browser.new_page(viewport={"width": 1100, "height": 860})
            page.on("console", lambda m: m.type in ("error", "warning") and problems.append(f"{m.type}: {m.text}"))
            page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            page.on("requestfailed", lambda r: problems.append(f"failed: {r.url} {r.failure}"))
            page.goto(server.url)
            ready = time.monotonic() + 60
            while page.text_content("#status") != "starting" and time.monotonic() < ready:
                time.sleep(0.02)
            assert page.text_content("#status") == "starting"
            result: list = []
            run = threading.Thread(target=lambda: result.append(_acquire_in_process(mock, plan_path, out, [view])))
            run.start()
            other = browser.new_page()          # a second tab, opened and closed mid-run
            other.goto(server.url, wait_until="commit")
            positions, running_shot = set(), False
            deadline = time.monotonic() + 60
            while (run.is_alive() or page.text_content("#status") != "complete") and time.monotonic() < deadline:
                status, faults = page.text_content("#status"), page.text_content("#faults")
                if status == "measuring":
                    positions.add(page.text_content("#position"))
                    if other is not None and len(positions) >= 2:
                        other.close()
                        other = None
                if not running_shot and status == "measuring" and "axis_fault" in faults:
                    assert page.locator("#plot svg.main-svg").count() >= 1
                    assert page.locator("#plot .scatterlayer .point").count() > 0
                    assert "axis_fault 1" in page.text_content("#retries")
                    page.screenshot(path=str(shots / "live-view-running.png"), full_page=True)
                    running_shot = True
                time.sleep(0.05)
            run.join()
            assert "dataset in" in page.text_content("#position")
            assert page.locator("#plot .scatterlayer .point").count() == total
            page.screenshot(path=str(shots / "live-view-finished.png"), full_page=True)
            assert "axis_fault x1" in page.text_content("#faults")
            assert "has ended" in page.text_content("#connection")
        finally:
            browser.close()
            server.close(linger_s=0)
    assert result and result[0].exit_code == 0
    assert running_shot, "the fault was never shown while the acquisition was running"
    assert len(positions) >= 2, positions
    assert problems == []
    assert len(read_dataset(tmp_path / out).table) == total * 5
    assert (shots / "live-view-finished.png").stat().st_size > 10_000
