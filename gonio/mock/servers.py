r"""Transports of the mock: pseudo-terminals, the RTU pty bridge and the head's socket listener.

Everything here runs on one asyncio event loop (the mock's background thread), except the RTU
bridge, a small thread copying bytes between two pseudo-terminal masters so that a Modbus RTU
server and a client can each open a ``/dev/pts/N`` path (no socat needed).

The head is served by :class:`HeadLink`: bytes are split into lines at ``\n`` (a preceding
``\r`` is dropped), and lines are handled one at a time in order; each reply is written after
the command's own duration (integration time) has elapsed.

The Modbus TCP server is pymodbus' ``ModbusTcpServer`` with one change
(:func:`make_dropping_tcp_server`): each connection's request handler records itself in a
context variable while it handles a request, so the simulator action of that request
(:meth:`gonio.mock.motion.ModbusFrontend.action`, awaited inside the handler's task) can close
*that* connection (``handler.transport.close()``: asyncio's ``connection_lost`` then runs
pymodbus' own clean-up, and the listener keeps accepting new connections). In pymodbus 3.16 a
``ServerRequestHandler`` is created per connection by ``ModbusBaseServer.callback_new_connection``
and ``handle_request`` awaits ``pdu.datastore_update`` -> ``SimCore`` -> the action; an action
raising ``NoSuchIdException`` with ``ignore_missing_devices=True`` sends no answer.
"""

from __future__ import annotations

import asyncio
import contextvars
import errno
import logging
import os
import select
import threading
import tty

from gonio.mock.head import DROP_SILENCE_S, MAX_LINE_BYTES, PhotometerHead

__all__ = ["open_raw_pty", "PtyBridge", "HeadLink", "serve_head_pty", "serve_head_socket",
           "make_dropping_tcp_server", "drop_current_modbus_connection"]

log = logging.getLogger(__name__)


def open_raw_pty() -> tuple[int, int, str]:
    """``(master_fd, slave_fd, slave_path)`` of a new pseudo-terminal in raw mode."""
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    return master, slave, os.ttyname(slave)


class PtyBridge:
    """Two raw pseudo-terminals joined back to back by a copying thread.

    ``server_path`` and ``client_path`` are the two slave devices; bytes written to one are read
    from the other. The slave fds are held open by the bridge so the masters never see a hang-up.
    """

    def __init__(self):
        self._ma, self._sa, self.server_path = open_raw_pty()
        self._mb, self._sb, self.client_path = open_raw_pty()
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="gonio-mock-rtu-bridge", daemon=True)
        self._stop = False

    def start(self) -> PtyBridge:
        """Start bridging on its thread; returns the bridge."""
        self._thread.start()
        return self

    def _run(self) -> None:
        peer = {self._ma: self._mb, self._mb: self._ma}
        while not self._stop:
            try:
                ready, _, _ = select.select([self._ma, self._mb, self._wake_r], [], [], 1.0)
            except (OSError, ValueError):
                return
            for fd in ready:
                if fd == self._wake_r:
                    return
                try:
                    data = os.read(fd, 4096)
                except OSError as exc:
                    if exc.errno in (errno.EIO, errno.EAGAIN):
                        continue
                    return
                if data:
                    try:
                        os.write(peer[fd], data)
                    except OSError:
                        pass

    def stop(self) -> None:
        """Stop the bridge, wait for its thread and close its descriptors."""
        self._stop = True
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass
        self._thread.join(timeout=2.0)
        for fd in (self._ma, self._sa, self._mb, self._sb, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass


class HeadLink:
    """One byte stream to the head: line splitting, ordered handling, replies, drops."""

    def __init__(self, head: PhotometerHead, lock: asyncio.Lock, write, on_drop):
        self.head = head
        self.lock = lock
        self.write = write              # callable(bytes)
        self.on_drop = on_drop          # callable() -> None
        self.buffer = bytearray()
        self.queue: asyncio.Queue[bytes] = asyncio.Queue()
        self.overflow = False
        self.silent_until = 0.0
        self.task = asyncio.get_running_loop().create_task(self._worker())

    def feed(self, data: bytes) -> None:
        """Take bytes received on the link (ignored while the link is silent)."""
        loop = asyncio.get_running_loop()
        if loop.time() < self.silent_until:
            return
        self.buffer.extend(data)
        while True:
            i = self.buffer.find(b"\n")
            if i < 0:
                break
            line = bytes(self.buffer[:i])
            del self.buffer[:i + 1]
            if self.overflow:
                self.overflow = False
                continue
            if line.endswith(b"\r"):
                line = line[:-1]
            if line.strip(b" \t\r"):
                self.queue.put_nowait(line)
        if len(self.buffer) > MAX_LINE_BYTES:
            self.buffer.clear()
            if not self.overflow:
                self.overflow = True
                self.queue.put_nowait(b"\xff" * 2)       # answered with ERR 101

    def flush_input(self) -> None:
        """Discard everything received and not yet handled."""
        self.buffer.clear()
        while not self.queue.empty():
            self.queue.get_nowait()

    async def _worker(self) -> None:
        while True:
            line = await self.queue.get()
            async with self.lock:
                try:
                    reply = self.head.handle_line(line)
                except Exception:       # a bug in the mock must not silence the head for good
                    log.exception("head: command %r crashed the mock; no reply", line[:40])
                    continue
                if reply.delay_s > 0:
                    await asyncio.sleep(reply.delay_s)
            if reply.drop:
                self.flush_input()
                self.silent_until = asyncio.get_running_loop().time() + DROP_SILENCE_S * self.head.time_scale
                self.on_drop()
                continue
            if reply.data:
                self.write(reply.data)

    def close(self) -> None:
        """Stop serving the connection."""
        self.task.cancel()


async def serve_head_pty(head: PhotometerHead, lock: asyncio.Lock):
    """Serve the head on a new raw pseudo-terminal; returns ``(slave_path, closer)``."""
    master, slave, path = open_raw_pty()
    os.set_blocking(master, False)
    loop = asyncio.get_running_loop()

    def write(data: bytes) -> None:
        try:
            os.write(master, data)
        except BlockingIOError:
            log.warning("head pty: output buffer full, reply dropped (is the driver reading?)")
        except OSError as exc:
            log.warning("head pty: write failed: %s", exc)

    link = HeadLink(head, lock, write, on_drop=lambda: None)

    def readable() -> None:
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                return
            raise
        if data:
            link.feed(data)

    loop.add_reader(master, readable)

    def close() -> None:
        loop.remove_reader(master)
        link.close()
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass

    return path, close


async def serve_head_socket(head: PhotometerHead, lock: asyncio.Lock, host: str, port: int):
    """Serve the head on a TCP listener; returns ``(port, closer)``. Clients share one head."""
    links: set[HeadLink] = set()

    async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        def write(data: bytes) -> None:
            if not writer.is_closing():
                writer.write(data)

        def drop() -> None:
            log.info("head socket: closing the client connection (injected drop)")
            writer.close()

        link = HeadLink(head, lock, write, on_drop=drop)
        links.add(link)
        try:
            while True:
                data = await reader.read(4096)
                if not data:
                    break
                link.feed(data)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            link.close()
            links.discard(link)
            if not writer.is_closing():
                writer.close()

    server = await asyncio.start_server(client, host, port)
    bound = server.sockets[0].getsockname()[1]

    async def close() -> None:
        server.close()
        for link in list(links):
            link.close()
        try:
            await asyncio.wait_for(server.wait_closed(), 1.0)
        except Exception:      # noqa: BLE001 - best-effort shutdown (includes the timeout)
            pass

    return bound, close


_HANDLER: contextvars.ContextVar = contextvars.ContextVar("gonio_mock_modbus_handler", default=None)


def _handler_class():
    from pymodbus.server.requesthandler import ServerRequestHandler

    class _TrackedHandler(ServerRequestHandler):
        """pymodbus' per-connection handler, visible to the action while it handles a request."""

        async def handle_request(self):
            token = _HANDLER.set(self)
            try:
                await super().handle_request()
            finally:
                _HANDLER.reset(token)

    return _TrackedHandler


def drop_current_modbus_connection() -> bool:
    """Close the Modbus TCP connection whose request is being handled (from the action).

    Returns False when called outside a request of a :func:`make_dropping_tcp_server` server.
    """
    handler = _HANDLER.get()
    transport = getattr(handler, "transport", None) if handler is not None else None
    if transport is None:
        return False
    transport.close()
    return True


def make_dropping_tcp_server(*args, **kwargs):
    """A ``pymodbus.server.ModbusTcpServer`` (same arguments) whose connections the action can drop.

    See :func:`drop_current_modbus_connection` and the module docstring.
    """
    from pymodbus.server import ModbusTcpServer

    handler_cls = _handler_class()

    class _Server(ModbusTcpServer):
        def callback_new_connection(self):
            return handler_cls(self, self.trace_packet, self.trace_pdu, self.trace_connect)

    return _Server(*args, **kwargs)
