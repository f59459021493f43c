"""A threaded TCP or UDP server for a simulated device, with a clean start and stop.

A simulated device (a robot controller, a profiler) speaking a protocol of its own needs
a server on 127.0.0.1 that its driver connects to, exactly as to the real device.
:class:`SimulatedDeviceServer` is that server, protocol-free:

- ``handler(message) -> reply``: the device's logic, one message in (bytes), the reply
  out (bytes, or None for no reply), called in the server's thread;
- TCP: the stream is cut into messages by ``framing`` (default :func:`line_frames`, one
  LF-terminated line; a binary protocol gives its own, which takes one message off the
  front of the buffer or returns None while the message is incomplete); one connection
  at a time, the next waits in the listen backlog; ``on_connect()`` is called for every
  connection accepted (a new session);
- UDP: every datagram is a message; the reply goes back to its sender;
- :meth:`SimulatedDeviceServer.send` sends unasked (a streaming device's frames) to the
  connected client (TCP) or to an address (UDP: the last sender by default);
- the port is chosen by the system (``port=0``) and reported: :attr:`~SimulatedDeviceServer.port`,
  :attr:`~SimulatedDeviceServer.address`;
- :meth:`SimulatedDeviceServer.stop` (or leaving the ``with`` block) stops the thread,
  joins it and closes every socket;
- an exception in the handler (or in ``framing`` or ``on_connect``) closes the connection
  and stops serving: the driver sees the link go, and :meth:`~SimulatedDeviceServer.stop`
  raises it as a :class:`~spherecal.core.errors.DeviceError` naming the server, so a test
  cannot pass over a simulator that broke.
"""

from __future__ import annotations

import select
import socket
import threading
from typing import Callable, Literal

from spherecal.core.errors import DeviceError

__all__ = ["SimulatedDeviceServer", "line_frames"]

#: How often the server's thread looks at its stop flag, s.
POLL_S = 0.02
#: How long :meth:`SimulatedDeviceServer.stop` waits for the thread, s.
JOIN_TIMEOUT_S = 5.0


def line_frames(buffer: bytearray) -> bytes | None:
    """The first LF-terminated line of ``buffer`` (with its LF), taken off it; None
    while no LF has arrived."""
    end = buffer.find(b"\n")
    if end < 0:
        return None
    line = bytes(buffer[: end + 1])
    del buffer[: end + 1]
    return line


class SimulatedDeviceServer:
    """A simulated device's server on ``host`` (default 127.0.0.1), in a thread (see the
    module).

    :param handler: ``handler(message: bytes) -> bytes | None``, the reply to one
        message (None: no reply); None ignores what arrives (a device that only sends).
    :param transport: ``"tcp"`` or ``"udp"``.
    :param framing: TCP only: ``framing(buffer: bytearray) -> bytes | None`` takes one
        message off the front of the bytes received so far (None: incomplete).
    :param name: the device in messages ("simulated example arm controller").
    :param port: the port to bind; 0 (default): one the system chooses, read it back
        from :attr:`port`.
    :param on_connect: TCP only: called with no argument for each accepted connection.
    :param max_message_bytes: TCP only: more bytes than this without a whole message
        stops the server with an error (a driver that never ends its message).
    """

    def __init__(self, handler: Callable[[bytes], bytes | None] | None, *,
                 transport: Literal["tcp", "udp"] = "tcp",
                 framing: Callable[[bytearray], bytes | None] = line_frames,
                 name: str = "simulated device", host: str = "127.0.0.1", port: int = 0,
                 on_connect: Callable[[], None] | None = None, max_message_bytes: int = 1 << 16):
        if transport not in ("tcp", "udp"):
            raise ValueError(f"{name}: transport must be 'tcp' or 'udp', got {transport!r}")
        self.handler = handler
        self.transport = transport
        self.framing = framing
        self.name = name
        self.on_connect = on_connect
        self.max_message_bytes = int(max_message_bytes)
        self._bind = (host, int(port))
        self._address: tuple[str, int] | None = None
        self._sock: socket.socket | None = None  # the listener (TCP) or the datagram socket (UDP)
        self._conn: socket.socket | None = None  # TCP: the connection being served
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._drop = threading.Event()
        self._thread: threading.Thread | None = None
        self._reported = False
        #: what the handler raised (None while it has not): the server stopped serving then
        self.error: BaseException | None = None
        #: connections accepted (TCP); datagrams' last sender (UDP), the default of :meth:`send`
        self.connections = 0
        self.peer: tuple[str, int] | None = None

    # lifecycle ---------------------------------------------------------------------------
    def start(self) -> "SimulatedDeviceServer":
        """Bind, listen (TCP) and start serving in a thread; returns the server."""
        if self._thread is not None:
            raise DeviceError(f"{self.name}: the server has already been started")
        kind = socket.SOCK_STREAM if self.transport == "tcp" else socket.SOCK_DGRAM
        sock = socket.socket(socket.AF_INET, kind)
        try:
            sock.bind(self._bind)
            if self.transport == "tcp":
                sock.listen(1)
        except OSError as exc:
            sock.close()
            raise DeviceError(f"{self.name}: cannot bind {self._bind[0]}:{self._bind[1]} ({exc})") from None
        self._sock = sock
        self._address = sock.getsockname()[:2]
        serve = self._serve_tcp if self.transport == "tcp" else self._serve_udp
        self._thread = threading.Thread(target=self._run, args=(serve,), name=f"spherecal-{self.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, join the thread, close every socket. Raises a
        :class:`~spherecal.core.errors.DeviceError` (once) when the handler raised. Safe
        to call twice."""
        self._stop.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(JOIN_TIMEOUT_S)
            if thread.is_alive():  # pragma: no cover - a handler that never returns
                raise DeviceError(f"{self.name}: the server's thread did not stop within {JOIN_TIMEOUT_S:g} s")
        self._close(self._conn)
        self._conn = None
        self._close(self._sock)
        self._sock = None
        self.check()

    def check(self) -> None:
        """Raise the handler's error now, as :meth:`stop` would (once)."""
        if self.error is not None and not self._reported:
            self._reported = True
            raise DeviceError(f"{self.name}: the server stopped: its handler raised "
                              f"{type(self.error).__name__}: {self.error}") from self.error

    def __enter__(self) -> "SimulatedDeviceServer":
        return self.start() if self._thread is None else self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is None:
            self.stop()
            return
        try:  # the block's own exception goes on; the handler's rides along as a note
            self.stop()
        except DeviceError as stopped:
            exc.add_note(str(stopped))

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the server is bound to (kept after it stops)."""
        if self._address is None:
            raise DeviceError(f"{self.name}: the server has not been started")
        return self._address

    @property
    def port(self) -> int:
        return self.address[1]

    def disconnect(self) -> None:
        """TCP: drop the connection being served (the driver sees the link go); the
        server then accepts the next one."""
        self._drop.set()

    def send(self, data: bytes, to: tuple[str, int] | None = None) -> None:
        """Send ``data`` unasked: to the connected client (TCP), or to ``to`` (UDP;
        default the last sender). :class:`~spherecal.core.errors.DeviceError` when there
        is no one to send to."""
        with self._send_lock:
            if self.transport == "tcp":
                if self._conn is None:
                    raise DeviceError(f"{self.name}: no client connected to send to")
                self._conn.sendall(data)
                return
            to = to or self.peer
            if to is None or self._sock is None:
                raise DeviceError(f"{self.name}: no address to send to (no datagram received, none given)")
            self._sock.sendto(data, to)

    # the thread --------------------------------------------------------------------------
    def _run(self, serve) -> None:
        try:
            serve()
        except BaseException as exc:  # surfaced by stop() and check()
            self.error = exc
            self._close(self._sock)  # nothing more is served: a driver's reconnection is refused
        finally:
            with self._send_lock:
                self._close(self._conn)
                self._conn = None

    def _readable(self, sock: socket.socket) -> bool:
        return bool(select.select([sock], [], [], POLL_S)[0])

    def _serve_tcp(self) -> None:
        while not self._stop.is_set():
            if not self._readable(self._sock):
                continue
            conn, _ = self._sock.accept()
            with self._send_lock:
                self._conn = conn
            self.connections += 1
            self._drop.clear()
            if self.on_connect is not None:
                self.on_connect()
            self._serve_connection(conn)
            with self._send_lock:
                self._close(conn)
                self._conn = None

    def _serve_connection(self, conn: socket.socket) -> None:
        buffer = bytearray()
        while not self._stop.is_set() and not self._drop.is_set():
            if not self._readable(conn):
                continue
            try:
                chunk = conn.recv(65536)
            except OSError:
                return
            if not chunk:
                return  # the driver closed the link
            buffer.extend(chunk)
            while (message := self.framing(buffer)) is not None:
                reply = self.handler(message) if self.handler is not None else None
                if reply:
                    try:
                        with self._send_lock:
                            conn.sendall(reply)
                    except OSError:  # the driver has gone while the reply was on its way
                        return
                if self._stop.is_set() or self._drop.is_set():
                    return
            if len(buffer) > self.max_message_bytes:
                raise DeviceError(f"{len(buffer)} bytes received without a whole message "
                                  f"(more than max_message_bytes = {self.max_message_bytes})")

    def _serve_udp(self) -> None:
        while not self._stop.is_set():
            if not self._readable(self._sock):
                continue
            data, sender = self._sock.recvfrom(65536)
            self.peer = sender
            reply = self.handler(data) if self.handler is not None else None
            if reply:
                with self._send_lock:
                    self._sock.sendto(reply, sender)

    @staticmethod
    def _close(sock: socket.socket | None) -> None:
        if sock is not None:
            try:
                sock.close()
            except OSError:  # pragma: no cover
                pass
