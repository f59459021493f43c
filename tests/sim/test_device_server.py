"""The simulated device server (spherecal.plugins.SimulatedDeviceServer): a TCP or UDP
server in a thread that serves a device's handler, reports its port, stops cleanly
(thread joined, sockets closed) and surfaces an exception of its handler."""

from __future__ import annotations

import socket
import struct
import threading

import pytest

from spherecal.plugins import DeviceError, SimulatedDeviceServer, line_frames


def _client(server: SimulatedDeviceServer) -> socket.socket:
    sock = socket.create_connection(server.address, timeout=2.0)
    return sock


def _read_line(sock: socket.socket) -> bytes:
    data = b""
    while not data.endswith(b"\n"):
        chunk = sock.recv(1024)
        if not chunk:
            return data
        data += chunk
    return data


def test_line_frames_takes_one_whole_line_at_a_time():
    buffer = bytearray(b"PING 1\nPI")
    assert line_frames(buffer) == b"PING 1\n"
    assert line_frames(buffer) is None and buffer == bytearray(b"PI")


def test_tcp_server_serves_lines_reports_its_port_and_stops_cleanly():
    seen = []

    def handler(line: bytes) -> bytes:
        seen.append(line)
        return line.upper()

    with SimulatedDeviceServer(handler, name="echo") as server:
        host, port = server.address
        assert host == "127.0.0.1" and port == server.port > 0
        with _client(server) as sock:
            sock.sendall(b"one\ntw")  # a message split across two writes is served whole
            assert _read_line(sock) == b"ONE\n"
            sock.sendall(b"o\n")
            assert _read_line(sock) == b"TWO\n"
        thread = server._thread
    assert seen == [b"one\n", b"two\n"]
    assert not thread.is_alive() and not server.running
    with pytest.raises(ConnectionRefusedError):  # the listener is closed
        socket.create_connection(("127.0.0.1", port), timeout=1.0)
    server.stop()  # twice is fine


def test_each_connection_is_announced_and_the_next_waits_for_the_first():
    sessions = []
    server = SimulatedDeviceServer(lambda line: f"{len(sessions)}\n".encode(), name="sessions",
                                   on_connect=lambda: sessions.append(1)).start()
    try:
        with _client(server) as first:
            first.sendall(b"a\n")
            assert _read_line(first) == b"1\n"
        with _client(server) as second:
            second.sendall(b"b\n")
            assert _read_line(second) == b"2\n"
        assert server.connections == 2
    finally:
        server.stop()


def test_a_binary_protocol_brings_its_own_framing():
    """Frames of a 2-byte big-endian length and a payload; the reply is the payload's sum."""

    def frames(buffer: bytearray) -> bytes | None:
        if len(buffer) < 2 or len(buffer) < 2 + int.from_bytes(buffer[:2], "big"):
            return None
        n = int.from_bytes(buffer[:2], "big")
        payload = bytes(buffer[2:2 + n])
        del buffer[:2 + n]
        return payload

    with SimulatedDeviceServer(lambda p: struct.pack(">H", sum(p)), framing=frames) as server:
        with _client(server) as sock:
            sock.sendall(b"\x00\x03\x01\x02\x03\x00\x01\x0a")
            assert sock.recv(2) == b"\x00\x06"
            assert sock.recv(2) == b"\x00\x0a"


def test_an_error_in_the_handler_drops_the_link_and_is_raised_on_stop():
    def handler(line: bytes) -> bytes:
        if line.startswith(b"bad"):
            raise ValueError("cannot parse 'bad'")
        return b"ok\n"

    server = SimulatedDeviceServer(handler, name="simulated acme controller").start()
    with _client(server) as sock:
        sock.sendall(b"good\n")
        assert _read_line(sock) == b"ok\n"
        sock.sendall(b"bad\n")
        assert _read_line(sock) == b""  # the driver sees the link go
    with pytest.raises(DeviceError, match=r"simulated acme controller: the server stopped: its handler raised "
                                          r"ValueError: cannot parse 'bad'") as err:
        server.stop()
    assert isinstance(err.value.__cause__, ValueError)
    server.stop()  # raised once; stopping again is quiet


def test_a_with_block_that_fails_keeps_its_own_error_and_notes_the_handlers():
    def handler(line: bytes) -> bytes:
        raise KeyError("j7")

    with pytest.raises(AssertionError) as err:
        with SimulatedDeviceServer(handler, name="sim") as server:
            with _client(server) as sock:
                sock.sendall(b"x\n")
                assert _read_line(sock) == b"ok\n"
    assert any("its handler raised KeyError" in note for note in err.value.__notes__)


def test_a_message_without_end_stops_the_server_naming_the_limit():
    server = SimulatedDeviceServer(lambda line: b"ok\n", max_message_bytes=100).start()
    with _client(server) as sock:
        sock.sendall(b"x" * 200)
        assert _read_line(sock) == b""
    with pytest.raises(DeviceError, match=r"200 bytes received without a whole message \(more than "
                                          r"max_message_bytes = 100\)"):
        server.stop()


def test_send_pushes_unasked_and_disconnect_drops_the_client():
    connected = threading.Event()
    server = SimulatedDeviceServer(None, on_connect=connected.set).start()
    try:
        with pytest.raises(DeviceError, match="no client connected to send to"):
            server.send(b"frame\n")
        with _client(server) as sock:
            assert connected.wait(2.0)
            server.send(b"frame 1\n")
            assert _read_line(sock) == b"frame 1\n"
            server.disconnect()
            assert _read_line(sock) == b""
    finally:
        server.stop()


def test_udp_server_replies_to_the_sender_and_sends_to_the_last_one():
    with SimulatedDeviceServer(lambda d: b"re:" + d, transport="udp", name="udp device") as server:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(2.0)
            sock.sendto(b"hello", server.address)
            data, sender = sock.recvfrom(100)
            assert data == b"re:hello" and sender == server.address
            server.send(b"sample 1")  # to the last sender
            assert sock.recvfrom(100)[0] == b"sample 1"


def test_bad_transport_and_a_taken_port_are_refused():
    with pytest.raises(ValueError, match="transport must be 'tcp' or 'udp', got 'serial'"):
        SimulatedDeviceServer(None, transport="serial")
    with SimulatedDeviceServer(None) as first:
        with pytest.raises(DeviceError, match=rf"second: cannot bind 127.0.0.1:{first.port}"):
            SimulatedDeviceServer(None, name="second", port=first.port).start()
