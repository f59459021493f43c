"""The driver's TCP link to the RAPID socket server (``socket://host:port``).

:class:`TcpLink` offers the part of pyserial's ``Serial`` interface the driver uses
(``read``, ``in_waiting``, ``write``, ``flush``, ``reset_input_buffer``, ``close``), so that
the driver's framing, timeouts, resends and stale-reply rules are one code for both
links. Over pyserial's own ``socket://`` handler it adds what a TCP link to a controller
needs: the connection attempt waits at most the configured timeout, small lines go out
at once (``TCP_NODELAY``), a connection the controller closed reads as an error saying
so (never as silence), and closing does not sleep.
"""

from __future__ import annotations

import select
import socket

from .config import parse_socket_url


class ControllerClosedError(ConnectionError):
    """The controller closed the connection (its program was stopped and reset, it
    restarted, or it dropped the connection after an error)."""


class TcpLink:
    """A connected TCP socket to ``url`` (``socket://host:port``).

    ``timeout`` bounds one :meth:`read` (s); ``write_timeout`` one :meth:`write`;
    ``connect_timeout`` the connection attempt. Errors are OSError (ConnectionError for a
    closed or refused connection, TimeoutError for a write that did not go out)."""

    def __init__(self, url: str, *, timeout: float, write_timeout: float, connect_timeout: float):
        host, port = parse_socket_url(url)
        self.url = url
        self.timeout = timeout
        self._write_timeout = write_timeout
        self._sock: socket.socket | None = socket.create_connection((host, port), timeout=connect_timeout)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        self._sock.settimeout(write_timeout)

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def _connected(self) -> socket.socket:
        if self._sock is None:
            raise ConnectionError(f"{self.url}: the connection is closed")
        return self._sock

    def _recv(self, n: int) -> bytes:
        data = self._connected().recv(n)
        if not data:
            raise ControllerClosedError(f"{self.url}: the controller closed the connection")
        return data

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes: what has arrived, waiting at most :attr:`timeout` for the
        first; b"" when nothing came."""
        ready, _, _ = select.select([self._connected()], [], [], self.timeout)
        return self._recv(size) if ready else b""

    @property
    def in_waiting(self) -> int:
        """A positive number when bytes wait to be read (not their count), else 0."""
        ready, _, _ = select.select([self._connected()], [], [], 0)
        return 4096 if ready else 0

    def write(self, data: bytes) -> int:
        self._connected().sendall(data)
        return len(data)

    def flush(self) -> None:
        """Nothing to do: :meth:`write` returns once the data is handed to the network."""

    def reset_input_buffer(self) -> None:
        """Discard every byte that has arrived and not been read."""
        while self.in_waiting:
            self._recv(4096)

    def close(self) -> None:
        """Close the connection (the controller sees it end). Idempotent."""
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:  # the controller has gone already
            pass
        sock.close()
