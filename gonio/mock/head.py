"""Mock spectro-photometer head: the ASCII command set of :mod:`gonio.instrument.head_commands` and its physics.

:class:`PhotometerHead` turns one command line into one reply (or none, under an injected
fault). It reads the geometry, lamp, shutter and sample slot from the shared
:class:`gonio.mock.motion.MotionController` and produces counts with :mod:`gonio.mock.physics`
from the sample's truth (:mod:`gonio.mock.samples`). Transports (pseudo-terminal, socket) live in
:mod:`gonio.mock.servers`.

Repetition counter: the number of readings delivered since the last state-changing command
(a move or homing, WAVE, ITIME, GAIN, SHUTTER, the lamp or shutter coil, the sample slot, *RST).
It keys the noise together with the state (:func:`gonio.mock.physics.noise_key`). Readings of a
faulted exchange (garbled, truncated, checksum, lamp) do not advance it.

Blank lines are ignored (they are not commands). A line longer than :data:`MAX_LINE_BYTES`
answers ``ERR 101``. A command that is not printable ASCII answers ``ERR 101``.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from gonio.data import geometry as G
from gonio.instrument import head_commands as HC
from gonio.instrument import head_framing as HF
from gonio.instrument import modbus_map as MM
from gonio.mock import physics
from gonio.mock.faults import FaultInjector
from gonio.mock.motion import MotionController
from gonio.mock.samples import WhiteReference

__all__ = ["PhotometerHead", "HeadReply", "MAX_LINE_BYTES", "DROP_SILENCE_S", "IDN_SERIAL",
           "IDN_FIRMWARE", "BANDWIDTH_NM", "DEFAULTS"]

log = logging.getLogger(__name__)

MAX_LINE_BYTES = 256
DROP_SILENCE_S = 0.5
"""After a ``drop`` fault on a pseudo-terminal the head ignores input this long (times speed)."""
IDN_SERIAL = "MOCK0001"
IDN_FIRMWARE = "2.3"
BANDWIDTH_NM = 5.0
TEMPERATURE_C = -10.0
DEFAULTS = {"wavelength_dnm": 5500, "itime_ms": 100, "gain_step": 0}


@dataclass
class HeadReply:
    """What to send back: ``data`` (None = nothing), after ``delay_s``; ``drop`` the link."""

    data: bytes | None
    delay_s: float = 0.0
    drop: bool = False


class PhotometerHead:
    """State and command interpreter of the photometer head."""

    def __init__(self, controller: MotionController, sample, seed: int = 0,
                 faults: FaultInjector | None = None, time_scale: float = 0.01,
                 integration_scale: float = 0.001):
        self.controller = controller
        self.sample = sample
        self.reference = WhiteReference()
        self.seed = int(seed)
        self.faults = faults
        self.time_scale = float(time_scale)
        self.integration_scale = float(integration_scale)
        self.wavelength_dnm = DEFAULTS["wavelength_dnm"]
        self.itime_ms = DEFAULTS["itime_ms"]
        self.gain_step = DEFAULTS["gain_step"]
        self.chk = False
        self.errors: deque[tuple[int, str]] = deque(maxlen=HC.ERROR_QUEUE_LENGTH)
        self.repetition = 0
        self.commands = 0
        controller.on_state_change = self.state_changed

    # --- state --------------------------------------------------------------------------------
    def state_changed(self) -> None:
        """A state-changing command happened: restart the repetition count."""
        self.repetition = 0

    def reading_state(self) -> physics.ReadingState:
        """What a reading depends on now: axes, sample slot, wavelength, integration, gain, shutter, lamp."""
        c = self.controller
        return physics.ReadingState(c.positions_mdeg(), c.slot, self.wavelength_dnm, self.itime_ms,
                                    self.gain_step, c.shutter_open, c.lamp_on)

    def link_reset(self) -> None:
        """The link dropped: checksum mode off, error queue cleared (measurement state kept)."""
        self.chk = False
        self.errors.clear()

    # --- command handling ---------------------------------------------------------------------
    def handle_line(self, raw: bytes) -> HeadReply:
        """Interpret one command line (terminator stripped) and build the reply."""
        self.commands += 1
        faults = self.faults
        fault = faults.head_fault() if faults is not None else None
        if fault == "drop":
            log.info("head: %r -> link dropped (injected fault)", raw[:40])
            self.link_reset()
            return HeadReply(None, drop=True)
        if fault == "serial_timeout":
            log.info("head: %r -> no answer (injected fault)", raw[:40])
            return HeadReply(None)
        if fault == "busy":
            log.info("head: %r -> busy (injected fault)", raw[:40])
            return HeadReply(self._error(103))
        payload, delay, consumed, lamp_fault = self._execute(raw)
        if fault is None and self.chk and faults is not None and faults.fires("checksum"):
            fault = "checksum"
        if fault is None and not lamp_fault:
            self.repetition += consumed
        line = HF.format_response(payload, self.chk)
        if fault is not None and faults is not None:       # every fault is drawn from the injector
            if lamp_fault:
                # the flagged reading never reaches the driver intact: the lamp fault is not
                # counted (only the fault the driver can see is, as for the other kinds)
                faults.stats["lamp"] -= 1
            if fault == "garbled":
                line = self._garble(line, faults.rng("garbled"))
            elif fault == "truncated":
                line = self._truncate(line, faults.rng("truncated"))
            elif fault == "checksum":
                line = self._bad_checksum(line)
            log.info("head: %r -> %s reply (injected fault)", raw[:40], fault)
        return HeadReply(line, delay_s=delay)

    def _error(self, code: int) -> bytes:
        self.errors.append((code, HC.HEAD_ERRORS[code]))
        return HF.format_response(f"ERR {code},{HC.HEAD_ERRORS[code]}", self.chk)

    def _execute(self, raw: bytes) -> tuple[str, float, int, bool]:
        """Run a command: (payload, delay in s, readings delivered, lamp fault)."""
        try:
            text = raw.decode("ascii")
            if not text.isprintable():
                raise HC.head_error(101)
            cmd, value = HC.match_command(text)
        except UnicodeDecodeError:
            cmd, value, text = None, None, ""
            err = HC.head_error(101)
        except HC.HeadError as exc:
            cmd, err = None, exc
        if cmd is None:
            self.errors.append((err.code, err.message))
            return f"ERR {err.code},{err.message}", 0.0, 0, False
        try:
            return self._run(cmd, value)
        except HC.HeadError as exc:
            self.errors.append((exc.code, exc.message))
            return f"ERR {exc.code},{exc.message}", 0.0, 0, False

    def _run(self, cmd: HC.HeadCommand, value) -> tuple[str, float, int, bool]:  # noqa: C901
        key = cmd.key
        c = self.controller
        if cmd.changes_state and key != "READ?":
            self.state_changed()
        if key == "*IDN?":
            return f"{HC.IDN_MAKER},{HC.IDN_MODEL},{IDN_SERIAL},{IDN_FIRMWARE}", 0.0, 0, False
        if key == "*RST":
            self.wavelength_dnm = DEFAULTS["wavelength_dnm"]
            self.itime_ms = DEFAULTS["itime_ms"]
            self.gain_step = DEFAULTS["gain_step"]
            c.shutter_open = False
            return "OK", 0.0, 0, False
        if key == "WAVE":
            self.wavelength_dnm = int(round(float(value) * 10))
            return "OK", 0.0, 0, False
        if key == "WAVE?":
            return f"{self.wavelength_dnm / 10:.1f}", 0.0, 0, False
        if key == "BW?":
            return f"{BANDWIDTH_NM:.1f}", 0.0, 0, False
        if key == "SHUTTER":
            c.shutter_open = value == "OPEN"
            return "OK", 0.0, 0, False
        if key == "SHUTTER?":
            return ("OPEN" if c.shutter_open else "CLOSED"), 0.0, 0, False
        if key == "ITIME":
            self.itime_ms = int(value)
            return "OK", 0.0, 0, False
        if key == "ITIME?":
            return str(self.itime_ms), 0.0, 0, False
        if key == "GAIN":
            self.gain_step = int(value)
            return "OK", 0.0, 0, False
        if key == "GAIN?":
            return str(self.gain_step), 0.0, 0, False
        if key == "TEMP?":
            return f"{TEMPERATURE_C:.1f}", 0.0, 0, False
        if key == "SYST:ERR?":
            if not self.errors:
                return '0,"No error"', 0.0, 0, False
            code, message = self.errors.popleft()
            return f'{code},"{message}"', 0.0, 0, False
        if key == "CHK":
            self.chk = value == "ON"
            return "OK", 0.0, 0, False
        if key == "READ?":
            return self._read(int(value))
        raise AssertionError(f"command {key} in the table but not implemented")  # programming error

    def true_value(self, state: physics.ReadingState) -> tuple[float, float]:
        """``(f, cos theta_o)`` of what is in the beam at the current geometry and wavelength."""
        pos = [MM.mdeg_to_deg(p) for p in state.positions_mdeg]
        ti, pi_, to, po = G.axes_to_fabric(*pos)
        cos_o = math.cos(math.radians(to))
        target = self.reference if state.slot == MM.SampleSlot.WHITE_REFERENCE else self.sample
        if not (state.shutter_open and state.lamp_on):
            return 0.0, cos_o
        f = float(np.asarray(target.beta(ti, pi_, to, po, state.wavelength_nm)))
        return f, cos_o

    def _read(self, n: int) -> tuple[str, float, int, bool]:
        state = self.reading_state()
        if state.shutter_open and not state.lamp_on:
            raise HC.head_error(201)
        try:
            f, cos_o = self.true_value(state)
        except ValueError as exc:      # DatasetError: request outside the sample's data
            log.warning("head: READ? refused, the sample has no value here: %s", exc)
            raise HC.head_error(102) from None
        signal, dark = physics.expected_counts(state, f, cos_o)
        if signal + dark >= HC.OVERLOAD_COUNTS:
            raise HC.head_error(301)
        readings = physics.simulate_readings(self.seed, state, f, cos_o, self.repetition, n)
        faults = self.faults
        lamp_rng = (faults.rng("lamp") if faults is not None and state.shutter_open and faults.fires("lamp")
                    else None)
        lamp_fault = lamp_rng is not None
        mean, std, n_out, flags = physics.summarise(readings)
        if lamp_rng is not None:
            rng = lamp_rng
            perturbed = np.clip(np.rint(readings * (1.0 + 0.05 * rng.standard_normal(n)) + 0.1 * signal
                                        * (rng.random() - 0.5)), 0, HC.ADC_MAX_COUNTS)
            mean, std, n_out, flags = physics.summarise(perturbed)
            flags |= HC.FLAG_LAMP_UNSTABLE
            log.info("head: READ? lamp unstable (injected fault)")
        delay = n * self.itime_ms / 1000.0 * self.integration_scale
        return f"{mean:.3f},{std:.3f},{n_out},{flags}", delay, n, lamp_fault

    # --- corruptions (faults) -----------------------------------------------------------------
    @staticmethod
    def _garble(line: bytes, rng: np.random.Generator) -> bytes:
        """The reply with a run of its body's bytes replaced by non-ASCII ones drawn from ``rng``."""
        body = bytearray(line[:-2])
        if not body:
            body = bytearray(b"?")
        k = int(rng.integers(1, max(2, len(body) // 2 + 1)))
        start = int(rng.integers(0, len(body) - k + 1)) if len(body) > k else 0
        body[start:start + k] = bytes(rng.integers(0x80, 0x100, size=k, dtype=np.uint8).tolist())
        return bytes(body) + HF.LINE_TERMINATOR

    @staticmethod
    def _truncate(line: bytes, rng: np.random.Generator) -> bytes:
        """The reply cut after a number of its body's bytes drawn from ``rng``."""
        body_len = len(line) - len(HF.LINE_TERMINATOR)
        return line[: int(rng.integers(1, max(2, body_len)))]      # at least one byte, never the \r\n

    def _bad_checksum(self, line: bytes) -> bytes:
        body = line[:-2]
        if len(body) >= 3 and body[-3:-2] == b"*":
            good = int(body[-2:], 16)
            return body[:-2] + f"{(good ^ 0x5A):02X}".encode() + HF.LINE_TERMINATOR
        return line
