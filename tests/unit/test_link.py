"""``uavest.link``: the transport's two UDP-server behaviours (answer the last sender: the
live link; answer every sender: the simulator, as pymavlink), a TCP server's connected
state, the tlog writer's whole records, and the parser's leftovers classified. Real
loopback sockets and files."""

from __future__ import annotations

import socket
import time

import pytest

from uavest.link import FrameEncoder, TlogWriter, Transport, reset_parser, tlog_record
from uavest.link.framing import bad_data_kind


def _client() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(0.5)
    return s


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("reply_all", [False, True])
def test_udp_server_answers_the_last_sender_or_every_sender(reply_all):
    port = _free_port()
    tr = Transport(f"udpin:127.0.0.1:{port}", 115200, reply_all=reply_all, blocking=False)
    a, b = _client(), _client()
    try:
        for c in (a, b):
            c.sendto(b"hello", ("127.0.0.1", port))
            deadline = time.monotonic() + 2.0
            while tr.recv(0.05) != b"hello":
                assert time.monotonic() < deadline
        tr.write(b"reply")
        assert b.recvfrom(100)[0] == b"reply"
        if reply_all:
            assert a.recvfrom(100)[0] == b"reply"
        else:
            with pytest.raises(TimeoutError):
                a.recvfrom(100)
    finally:
        tr.close()
        a.close()
        b.close()


def test_tcp_server_is_connected_once_a_client_is_accepted():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    tr = Transport(f"tcpin:127.0.0.1:{port}", 115200, blocking=False)
    try:
        assert not tr.connected
        tr.write(b"nobody")  # no client: dropped, no error
        with socket.create_connection(("127.0.0.1", port), timeout=2.0) as c:
            deadline = time.monotonic() + 2.0
            while not tr.connected:
                tr.recv(0.05)
                assert time.monotonic() < deadline
            tr.write(b"frame")
            assert c.recv(100) == b"frame"
    finally:
        tr.close()


def test_tlog_writer_writes_whole_records(tmp_path):
    enc = FrameEncoder(1, 1)
    frames = [enc.encode(enc.mav.heartbeat_encode(2, 3, 0, 0, 4)) for _ in range(3)]
    p = tmp_path / "x.tlog"
    w = TlogWriter(p, flush_s=3600.0)
    w.add(10, frames[0])
    w.flush(force=True)
    w.add(20, frames[1])
    w.add(30, frames[2])
    w.flush()  # not due (flushed just now): buffered
    assert p.read_bytes() == tlog_record(10, frames[0])
    w.close()
    assert p.read_bytes() == b"".join(tlog_record(t, f) for t, f in zip((10, 20, 30), frames,
                                                                       strict=True))
    assert (frames[0][4], frames[1][4]) == (0, 1)  # the sequence number (MAVLink 2 byte 4)


class _Parser:
    def __init__(self, left: bytes) -> None:
        self.buf = bytearray(b"xx" + left)
        self.buf_index = 2
        self.expected_length = 99


@pytest.mark.parametrize(("left", "kind"), [
    (b"", None), (b"\xfd\x09\x00", "truncated"), (b"APM boot\r\n", "non_mavlink"),
    (b"\x01\x02\xff", "corrupt")])
def test_parser_leftovers_are_classified_and_forgotten(left, kind):
    p = _Parser(left)
    assert reset_parser(p) == kind
    assert p.buf == bytearray() and p.buf_index == 0 and p.expected_length == 8


class _Bad:
    def __init__(self, reason: str, data: bytes) -> None:
        self.reason, self.data = reason, data


def test_bad_packets_are_counted_by_kind():
    assert bad_data_kind(_Bad("invalid signature", b"\xfd\x09\x01")) == "bad_signature"
    assert bad_data_kind(_Bad("Invalid signature", b"\xfd\x09\x00")) == "unsigned"
    assert bad_data_kind(_Bad("bad header", b"SITL boot")) == "non_mavlink"
    assert bad_data_kind(_Bad("invalid MAVLink CRC", b"\x00\xff")) == "corrupt"
