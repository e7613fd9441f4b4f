"""``gonio mock``: serve the mock goniophotometer until SIGINT/SIGTERM.

Usage::

    gonio mock [--modbus tcp://127.0.0.1:PORT | --modbus rtu] [--serial pty | --serial socket://127.0.0.1:PORT]
               [--sample NAME|FILE] [--faults SPEC] [--speed fast|real] [--seed N]

Prints ONE JSON line ``{"modbus": "...", "serial": "..."}`` on stdout (flushed) once both
endpoints are up, then serves until SIGINT or SIGTERM and exits 0. Binds to loopback only: a
non-loopback address is refused (exit 2). ``--modbus tcp`` / ``--serial socket`` pick a free
port. The ``--faults`` syntax is described in :mod:`gonio.mock.faults`.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading

from gonio.mock.faults import FAULT_KINDS, FaultSpecError
from gonio.mock.instrument import MockConfigError, MockInstrument
from gonio.mock.samples import SampleError

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``gonio mock``."""
    p = argparse.ArgumentParser(
        prog="gonio mock",
        description="Mock goniophotometer on real protocol endpoints (loopback and pseudo-terminals only). "
                    "Prints one JSON line with the endpoints, then serves until SIGINT/SIGTERM.")
    p.add_argument("--modbus", default="tcp", metavar="tcp://127.0.0.1:PORT|rtu",
                   help="Modbus TCP listener on loopback (PORT 0 or 'tcp' = any free port) or RTU over a "
                        "pseudo-terminal pair (default: tcp)")
    p.add_argument("--serial", default="pty", metavar="pty|socket://127.0.0.1:PORT",
                   help="photometer head on a pseudo-terminal or a loopback socket (default: pty)")
    p.add_argument("--sample", default="red-cotton", metavar="NAME|FILE",
                   help="lambert:RHO, red-cotton, a radiance-coefficient dataset directory, "
                        "or an RGL .bsdf file (a real material of the EPFL database, e.g. "
                        "fixtures/real/acrylic_felt_green_rgb.bsdf; default: red-cotton)")
    p.add_argument("--faults", default=None, metavar="SPEC",
                   help="comma-separated kind=RATE or kind=@N; kinds: " + ", ".join(FAULT_KINDS))
    p.add_argument("--speed", default="fast", choices=("fast", "real"),
                   help="fast scales motion times by 0.01 and integration times by 0.001 (default: fast)")
    p.add_argument("--seed", default=0, type=int, help="seed of the noise and of the faults (default: 0)")
    p.add_argument("-v", "--verbose", action="store_true", help="log requests and faults on stderr")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run ``gonio mock``; returns the exit code (0 after SIGINT/SIGTERM, 2 on a usage error)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="gonio mock: %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if not args.verbose:
        # pymodbus logs undecodable requests with their raw frames: only with -v
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    try:
        mock = MockInstrument(sample=args.sample, modbus=args.modbus, serial=args.serial,
                              faults=args.faults, speed=args.speed, seed=args.seed)
    except (MockConfigError, FaultSpecError, SampleError) as exc:
        print(f"gonio mock: error: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()

    def on_signal(signum, frame) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            mock.start()
        except MockConfigError as exc:
            print(f"gonio mock: error: {exc}", file=sys.stderr)
            return 2
        except OSError as exc:
            print(f"gonio mock: error: cannot open the endpoints: {exc}", file=sys.stderr)
            return 2
        sys.stdout.write(json.dumps({"modbus": mock.modbus_url, "serial": mock.serial_url}) + "\n")
        sys.stdout.flush()
        while not stop.wait(0.2):
            pass
    finally:
        mock.stop()
        for s, h in previous.items():
            signal.signal(s, h)
    if args.verbose:
        print(f"gonio mock: stats {json.dumps(mock.stats)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
