"""A live view of an acquisition: a local, read-only web page that follows the engine's records.

:class:`LiveView` is a subscriber of the engine (:mod:`gonio.acquisition.subscribers`), like the
journal writer and the progress display: it only reads the records it is handed, reduces each point to
the radiance factor with its uncertainty (:func:`gonio.acquisition.reduce.point_beta`, the dataset's
own measurement equation) and keeps the result in a state guarded by a lock. :class:`LiveServer`
serves that state, the page and Plotly (bundled with the ``plotly`` package: no network) from
:class:`http.server.ThreadingHTTPServer` on a daemon thread. The page polls ``state.json`` and redraws
with ``Plotly.react``: the curves per incidence with error bars, the plan's position (point k of N,
the geometry being measured), the time left, the retries and faults the driver met, and in the end the
finished dataset as written (its ``radiance.csv``).

What it may never do is disturb the acquisition:

- the subscriber never raises: a failure inside it is logged once and the view stops updating, the
  acquisition and its journal go on (the journal writer is the engine's first subscriber anyway);
- the acquisition thread only appends under the lock; the server thread copies and serialises,
  outside any I/O, and writes to its clients without the lock, so a slow, killed or half-open
  client blocks nothing but its own request thread (each has a socket timeout);
- the server is a daemon thread the acquisition never waits for: if it dies, the acquisition goes on.

Access: the server listens on 127.0.0.1 only, every URL carries a random token
(:func:`secrets.token_urlsafe`; a request without it gets 403, as does one whose ``Host`` is not
the loopback's, against DNS rebinding), and it answers GET only (anything else: 405).
"""

from __future__ import annotations

import json
import logging
import math
import secrets
import sys
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import urlsplit

from gonio.acquisition.calibration import WhiteStandard, load_white_standard
from gonio.acquisition.journal import read_journal
from gonio.acquisition.plan import Plan, PlanPoint
from gonio.acquisition.reduce import point_beta, point_key
from gonio.acquisition.rundir import JOURNAL_NAME

__all__ = ["LiveView", "LiveServer", "LOOPBACK", "POLL_MS"]

log = logging.getLogger(__name__)

LOOPBACK = "127.0.0.1"
#: how often the page asks for the state (milliseconds)
POLL_MS = 500
#: Plotly's default colour sequence: one colour per incidence, in the plan's order
_COLOURS = ("#636efa", "#ef553b", "#00cc96", "#ab63fa", "#ffa15a", "#19d3f3", "#ff6692", "#b6e880",
            "#ff97ff", "#fecb52")
#: the statuses of the engine's ``stop`` document that are not a normal end
_STOPPED = ("stopped", "interrupted", "failed")


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


def _axes_text(axes) -> str:
    source, detector, plane, rotation = (float(a) for a in axes)
    return f"θi {source:g}°, s {detector:g}°, plane {plane:g}°, rotation {rotation:g}°"


class LiveView:
    """Subscriber that keeps what the live page shows (thread-safe; see the module docstring).

    Parameters
    ----------
    plan : Plan
        The plan being measured (its motion order gives the position; its wavelengths the columns).
    out : str or Path
        The run directory: on ``resume`` the journal's earlier points are read from it, and on
        ``stop`` the finished dataset.
    standard : WhiteStandard, optional
        The white standard's table (default: the plan's).
    clock : callable, optional
        Monotonic clock for the time left (injectable for tests).
    """

    def __init__(self, plan: Plan, out: str | Path, *, standard: WhiteStandard | None = None,
                 clock=time.monotonic):
        self.plan, self.out, self.clock = plan, Path(out), clock
        base = plan.path.parent if plan.path else None
        self.standard = standard or load_white_standard(plan.white_standard, base=base)
        self.ordered: list[PlanPoint] = plan.check().ordered
        self.wavelengths = [float(w) for w in plan.wavelengths_nm]
        incidences = sorted({p.source_deg for p in self.ordered})
        self._colour = {ti: _COLOURS[k % len(_COLOURS)] for k, ti in enumerate(incidences)}
        self._rotations = len({p.rotation_deg for p in self.ordered})
        self._lock = threading.Lock()
        self._calibrations: dict[int, dict] = {}
        self._done: set[tuple[float, ...]] = set()
        self._next = 0              # the first point of the motion order not measured (done only grows)
        self._last_retries: dict[str, int] = {}
        self._t_todo = 0.0
        self._session_points = 0
        self._session_todo = 0
        self.broken = False
        self._curves: dict[tuple, dict] = {}
        self._state: dict = {
            "plan": plan.name, "sample": str(plan.sample.get("name", "")),
            "wavelengths_nm": self.wavelengths, "status": "starting", "message": "",
            "total": len(self.ordered), "done": 0, "current": None, "last": None, "eta_s": None,
            "retries": {}, "faults": [], "finished": False, "dataset": None, "curves": [],
            "version": 0, "poll_ms": POLL_MS}

    # --- the engine's side ---------------------------------------------------------------
    def __call__(self, name: str, doc: dict) -> None:
        """Take one document of the engine; never raises (a failure stops the view, not the run)."""
        if self.broken:
            return
        try:
            with self._lock:
                self._take(name, doc)
                self._state["version"] += 1
        except Exception as exc:  # noqa: BLE001 - the view must never stop the acquisition
            self.broken = True
            log.warning("live view: stopped updating (%r); the acquisition goes on", exc)

    def _take(self, name: str, doc: dict) -> None:
        s = self._state
        if name == "start":
            s["status"] = "calibrating"
        elif name == "calibration":
            self._calibrations[int(doc["id"])] = doc
            self._retries_at(doc, "calibration")
        elif name == "event":
            self._event(doc)
        elif name == "todo":
            s["status"] = "measuring"
            self._t_todo = self.clock()
            self._session_todo = int(doc["total"]) - int(doc["done"])
            s["done"] = len(self._done)
            self._position()
        elif name == "point":
            self._point(doc, live=True)
        elif name == "stop":
            self._stop(doc)

    def _event(self, doc: dict) -> None:
        s, what = self._state, doc.get("what")
        if what == "resume":
            self._load_journal()
        elif what == "calibration_invalid":
            self._fault("calibration", {}, f"calibration invalid: {doc.get('message', '')}", error=True)
        elif what == "session_end":
            self._retries_at(doc, "the end of the acquisition", note="" if doc.get("status") == "complete"
                             else " (retried until the stop)")
            if doc.get("status") != "complete":
                s["status"], s["message"] = doc.get("status", "stopped"), str(doc.get("message", ""))

    def _load_journal(self) -> None:
        """On resume: the points the journal already holds (read, never written)."""
        for r in read_journal(self.out / JOURNAL_NAME).records:
            if r["type"] == "calibration":
                self._calibrations[int(r["id"])] = r
            elif r["type"] == "point" and r["calibration"] in self._calibrations:
                self._point(r, live=False)

    def _point(self, rec: dict, *, live: bool) -> None:
        key = point_key(rec)
        if key in self._done:
            return
        cal = self._calibrations[rec["calibration"]]
        wl, beta, u_beta = point_beta(rec, cal, self.standard, self.plan.reference_deg)
        self._add(rec["axes_deg"], rec["geometry"], dict(zip(wl.tolist(), zip(beta.tolist(), u_beta.tolist(), strict=True), strict=True)))
        self._done.add(key)
        s = self._state
        s["done"] = len(self._done)
        s["last"] = {"axes_deg": [float(a) for a in rec["axes_deg"]], "text": _axes_text(rec["axes_deg"])}
        if not live:
            return
        if rec.get("saturated_nm"):
            self._fault(f"point {len(self._done)}", {}, "saturated at every setting (not stored) at "
                        + ", ".join(f"{w:g}" for w in rec["saturated_nm"]) + " nm", error=False)
        self._retries_at(rec, f"point {len(self._done)} of {s['total']} ({_axes_text(rec['axes_deg'])})")
        self._session_points += 1
        remaining = max(self._session_todo - self._session_points, 0)
        s["eta_s"] = (self.clock() - self._t_todo) / self._session_points * remaining
        self._position()

    def _position(self) -> None:
        while self._next < len(self.ordered) and self.ordered[self._next].key in self._done:
            self._next += 1
        nxt = self.ordered[self._next] if self._next < len(self.ordered) else None
        self._state["current"] = None if nxt is None else {
            "index": len(self._done) + 1, "axes_deg": list(nxt.axes_deg), "text": _axes_text(nxt.axes_deg)}

    def _retries_at(self, doc: dict, where: str, note: str = " (retried: the driver recovered)") -> None:
        """A fault is what the driver retried: the growth of the record's cumulative retry counts."""
        counts = {k: int(v) for k, v in (doc.get("retries") or {}).items()}
        grown = {k: v - self._last_retries.get(k, 0) for k, v in counts.items()
                 if v > self._last_retries.get(k, 0)}
        if counts:
            self._last_retries = counts
            self._state["retries"] = dict(sorted(counts.items()))
        if grown:
            self._fault(where, grown, ", ".join(f"{k} x{v}" for k, v in sorted(grown.items())) + note,
                        error=False)

    def _fault(self, where: str, kinds: dict, text: str, *, error: bool) -> None:
        self._state["faults"].append({"where": where, "kinds": kinds, "text": text, "error": error})

    def _stop(self, doc: dict) -> None:
        s = self._state
        s["status"] = str(doc["status"])
        s["current"], s["eta_s"] = None, 0.0 if doc["status"] == "complete" else None
        if doc["status"] in _STOPPED:
            self._fault("stop", {}, s["message"] or f"{doc['status']} (see the terminal)", error=True)
        if doc["measured"]:
            self._dataset()
        s["finished"] = True

    def _dataset(self) -> None:
        """The curves of the finished dataset, as written (read back from the run directory)."""
        from gonio.data import read_dataset
        from gonio.data.geometry import fabric_to_axes

        table = read_dataset(self.out).table
        self._curves.clear()
        for geometry, rows in table.groupby(["theta_i", "phi_i", "theta_o", "phi_o"], sort=False):
            values = dict(zip(rows["wavelength_nm"].astype(float), zip(rows["beta"], rows["u_beta"], strict=True),
                               strict=True))
            self._add(fabric_to_axes(*geometry), geometry, values)
        self._state["dataset"] = str(self.out)

    def _add(self, axes, geometry, values: dict) -> None:
        """Put one geometry into its curve.

        A curve is the in-plane points of an incidence (and rotation), or its points out of the plane;
        ``geometry``: (theta_i, phi_i, theta_o, phi_o); ``values``: wavelength -> (beta, u_beta).
        """
        source, detector, plane, rotation = (float(a) for a in axes)
        in_plane = abs(plane) < 1e-6
        key = (source, rotation, in_plane)
        curve = self._curves.get(key)
        if curve is None:
            label = f"θi = {source:g}°" + (f", φi = {rotation:g}°" if self._rotations > 1 else "")
            curve = self._curves[key] = {
                "label": label + ("" if in_plane else ", out of plane"), "in_plane": in_plane,
                "colour": self._colour.get(source, _COLOURS[0]), "points": []}
        row = [values.get(w, (math.nan, math.nan)) for w in self.wavelengths]
        curve["points"].append((detector, _axes_text(axes), [_finite(b) for b, _ in row],
                                [_finite(u) for _, u in row], [round(float(g), 6) for g in geometry]))
        curve["points"].sort(key=lambda p: p[0])

    # --- the server's side ---------------------------------------------------------------
    def snapshot(self) -> dict:
        """A copy of the state for the page (taken under the lock; safe from any thread)."""
        with self._lock:
            s = dict(self._state)
            s["faults"] = list(s["faults"])
            s["curves"] = [{"label": c["label"], "in_plane": c["in_plane"], "colour": c["colour"],
                            "x": [p[0] for p in c["points"]], "text": [p[1] for p in c["points"]],
                            "beta": [p[2] for p in c["points"]], "u_beta": [p[3] for p in c["points"]],
                            "geometry": [p[4] for p in c["points"]]}
                           for _, c in sorted(self._curves.items(), key=lambda kv: (kv[0][0], kv[0][1], not kv[0][2]))]
        return s

    @property
    def version(self) -> int:
        """Grows with every change of the state."""
        with self._lock:
            return int(self._state["version"])

    def ended(self, message: str) -> None:
        """Mark the view finished when the command ends without a ``stop`` (a failure before it)."""
        with self._lock:
            if not self._state["finished"]:
                self._state.update(status="ended", message=message, finished=True, current=None)
                self._state["version"] += 1


class LiveServer:
    """The live page of ``view`` on ``http://127.0.0.1:PORT/TOKEN/`` (a daemon thread).

    Parameters
    ----------
    view : LiveView
        The state it serves.
    port : int, optional
        Port on 127.0.0.1 (0: one the system chooses).

    Raises
    ------
    OSError
        When the port cannot be listened on (in use, or privileged).
    """

    def __init__(self, view: LiveView, port: int = 0):
        from plotly.offline import get_plotlyjs

        self.view = view
        self.token = secrets.token_urlsafe(24)
        self._plotly = get_plotlyjs().encode()
        self._cache: tuple[int, bytes, bool] = (-1, b"", False)
        self._cache_lock = threading.Lock()
        self.final_served = threading.Event()
        self.last_poll = -math.inf
        self.httpd = _Server((LOOPBACK, int(port)), _Handler)
        self.httpd.live = self
        self.port = int(self.httpd.server_address[1])
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.2},
                                       name="gonio-live-view", daemon=True)
        self.thread.start()

    @property
    def url(self) -> str:
        """The page's address, token included."""
        return f"http://{LOOPBACK}:{self.port}/{self.token}/"

    def state_json(self) -> tuple[bytes, bool]:
        """The state as JSON (serialised once per change of the view) and whether it is the final one."""
        with self._cache_lock:
            if self.view.version != self._cache[0]:
                snap = self.view.snapshot()
                self._cache = (snap["version"], json.dumps(snap, allow_nan=False).encode(), bool(snap["finished"]))
            return self._cache[1], self._cache[2]

    def close(self, linger_s: float = 5.0) -> None:
        """Stop serving. Never raises.

        First, when a page polled in the last seconds, give it up to ``linger_s`` to fetch the finished
        state (so that it ends on the dataset).
        """
        try:
            if time.monotonic() - self.last_poll < 4 * POLL_MS / 1000 and self.thread.is_alive():
                self.final_served.wait(linger_s)
            self.httpd.shutdown()
            self.httpd.server_close()
        except Exception as exc:  # noqa: BLE001 - closing the view never fails the command
            log.debug("live view: closing: %r", exc)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    live: LiveServer

    def handle_error(self, request, client_address) -> None:
        # a client that went away mid-answer (closed tab, killed browser) is no error of ours
        log.debug("live view: request from %s ended: %r", client_address, sys.exc_info()[1])


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    server_version = "gonio-live"
    sys_version = ""
    timeout = 10        # a client that opens a connection and sends nothing holds only its thread

    def log_message(self, format, *args) -> None:  # noqa: A002 - the base class's signature
        log.debug("live view: " + format, *args)

    def _send(self, status: int, body: bytes, ctype: str = "text/plain; charset=utf-8",
              extra: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Referrer-Policy", "no-referrer")
        self.send_header("Content-Security-Policy",
                         "default-src 'none'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
                         "img-src 'self' data:; connect-src 'self'; font-src 'self' data:")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(body)

    def _allowed(self, path: str) -> str | None:
        """The part of ``path`` after ``/TOKEN`` when the request may be answered, else None."""
        host = (self.headers.get("Host") or "").rsplit(":", 1)[0].strip("[]")
        if host not in (LOOPBACK, "localhost"):
            return None
        token = self.server.live.token
        first, _, rest = path.lstrip("/").partition("/")
        if not secrets.compare_digest(first.encode(), token.encode()):
            return None
        return "/" + rest if (rest or path.endswith("/")) else ""

    def do_GET(self) -> None:
        live = self.server.live
        path = urlsplit(self.path).path
        rest = self._allowed(path)
        if rest is None:
            self._send(HTTPStatus.FORBIDDEN, b"forbidden: open the address gonio printed, token included\n")
        elif rest == "":
            self._send(HTTPStatus.MOVED_PERMANENTLY, b"", extra={"Location": f"/{live.token}/"})
        elif rest == "/":
            self._send(HTTPStatus.OK, _PAGE.encode(), "text/html; charset=utf-8")
        elif rest == "/state.json":
            body, final = live.state_json()
            live.last_poll = time.monotonic()
            self._send(HTTPStatus.OK, body, "application/json")
            if final:
                live.final_served.set()
        elif rest == "/live.js":
            self._send(HTTPStatus.OK, _SCRIPT.encode(), "text/javascript; charset=utf-8")
        elif rest == "/plotly.min.js":
            self._send(HTTPStatus.OK, live._plotly, "text/javascript; charset=utf-8")
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n")

    def _refuse(self) -> None:
        self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"read-only: GET only\n", extra={"Allow": "GET"})

    do_POST = do_PUT = do_DELETE = do_PATCH = do_HEAD = do_OPTIONS = do_TRACE = do_CONNECT = _refuse


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>gonio live view</title>
<link rel="icon" href="data:,">
<style>
body { font: 14px system-ui, sans-serif; margin: 1em 2em; color: #222; }
h1 { font-size: 1.3em; margin: 0 0 .3em; }
#status { font-weight: bold; } .complete { color: #1a7f37; } .stopped, .failed, .interrupted, .ended { color: #c62828; }
dl { display: grid; grid-template-columns: max-content auto; gap: .2em 1em; margin: .5em 0; }
dt { color: #666; } dd { margin: 0; } progress { width: 20em; }
#faults li.error { color: #c62828; font-weight: bold; } #faults li { color: #b35c00; }
#plot { width: 100%; height: 520px; }
</style>
<script src="plotly.min.js"></script><script src="live.js" defer></script></head>
<body>
<h1>gonio live view: plan <span id="plan">...</span> <small id="sample"></small></h1>
<dl>
<dt>status</dt><dd><span id="status">connecting</span> <span id="message"></span></dd>
<dt>position</dt><dd><progress id="progress" value="0" max="1"></progress> <span id="position"></span></dd>
<dt>now at</dt><dd id="current">-</dd>
<dt>time left</dt><dd id="eta">-</dd>
<dt>retries</dt><dd id="retries">none</dd>
<dt>wavelength</dt><dd><select id="wavelength"></select></dd>
</dl>
<div id="plot"></div>
<h2 style="font-size:1.1em">Faults</h2><ul id="faults"><li id="nofault">none so far</li></ul>
<p id="connection"></p>
</body></html>
"""

_SCRIPT = """"use strict";
// Polls state.json (written by gonio's live view) and redraws with Plotly.react; no other logic.
const $ = (id) => document.getElementById(id);
const select = $("wavelength");
let version = -1;
let latest = null;

function duration(s) {
  if (s === null || s === undefined) return "-";
  s = Math.round(s);
  return s < 60 ? `${s} s` : `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s`;
}

function draw(st) {
  const j = Number(select.value);
  const traces = st.curves.map((c) => ({
    type: "scatter", mode: c.in_plane ? "lines+markers" : "markers", name: c.label,
    x: c.x, y: c.beta.map((b) => b[j]), text: c.text,
    error_y: {type: "data", array: c.u_beta.map((u) => u[j]), visible: true},
    marker: {color: c.colour, symbol: c.in_plane ? "circle" : "diamond"}, line: {color: c.colour},
    hovertemplate: "%{text}<br>β %{y:.4g}<extra></extra>",
  }));
  const layout = {
    title: {text: `${st.finished && st.dataset ? "dataset" : "measured so far"}, ${st.wavelengths_nm[j]} nm`},
    xaxis: {title: {text: "signed detector angle s (deg, + mirror side)"}, zeroline: false},
    yaxis: {title: {text: "radiance factor β"}, rangemode: "tozero"},
    margin: {t: 40, r: 10},
  };
  Plotly.react("plot", traces, layout, {displaylogo: false, responsive: true});
}

function show(st) {
  if (select.options.length === 0) {
    st.wavelengths_nm.forEach((w, k) => select.add(new Option(`${w} nm`, k)));
    const mid = st.wavelengths_nm.map((w) => Math.abs(w - 550));
    select.value = mid.indexOf(Math.min(...mid));
    select.onchange = () => draw(latest);
  }
  $("plan").textContent = st.plan;
  $("sample").textContent = st.sample ? `(sample: ${st.sample})` : "";
  $("status").textContent = st.status;
  $("status").className = st.status;
  $("message").textContent = st.message;
  $("progress").max = Math.max(st.total, 1);
  $("progress").value = st.done;
  $("position").textContent = `point ${st.done} of ${st.total}` + (st.dataset ? `, dataset in ${st.dataset}` : "");
  $("current").textContent = st.current ? `point ${st.current.index}: ${st.current.text}` : "-";
  $("eta").textContent = duration(st.eta_s);
  const r = Object.entries(st.retries).map(([k, v]) => `${k} ${v}`).join(", ");
  $("retries").textContent = r || "none";
  const list = $("faults");
  list.replaceChildren(...st.faults.map((f) => {
    const li = document.createElement("li");
    li.textContent = `${f.where}: ${f.text}`;
    if (f.error) li.className = "error";
    return li;
  }));
  if (st.faults.length === 0) list.append(Object.assign(document.createElement("li"), {textContent: "none so far"}));
  draw(st);
}

async function poll() {
  let st;
  try {
    const response = await fetch("state.json", {cache: "no-store"});
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    st = await response.json();
  } catch (err) {
    $("connection").textContent = `gonio no longer answers (${err.message}): the acquisition's command has ended.`;
    return;
  }
  if (st.version !== version) { version = st.version; latest = st; show(st); }
  if (st.finished) {
    $("connection").textContent = "The acquisition has ended; this page keeps its last state.";
    return;
  }
  setTimeout(poll, st.poll_ms);
}
poll();
"""
