"""MAVLink 2 frames as bytes: the encoder's buffer, the tlog record, the parser's leftovers.

A tlog (MAVProxy's telemetry log) is a sequence of records: an 8-byte big-endian UNIX time
in microseconds, then one frame as sent or received.
"""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["FrameEncoder", "PRINTABLE", "reset_parser", "tlog_record"]

#: Bytes of text (a boot banner, a shell prompt): what is not MAVLink on a serial/TCP port.
PRINTABLE = frozenset(range(0x20, 0x7F)) | {0x09, 0x0A, 0x0D}

_TLOG_TIME = struct.Struct(">Q")


def tlog_record(t_us: int, frame: bytes) -> bytes:
    """One tlog record: ``t_us`` (UNIX us, 8 bytes big-endian) then the frame."""
    return _TLOG_TIME.pack(t_us) + frame


class _Buffer:
    """File-like object the pymavlink encoder writes packed frames into."""

    def __init__(self) -> None:
        self.buf = b""

    def write(self, b: bytes) -> None:
        self.buf += b


class FrameEncoder:
    """Messages to MAVLink 2 frames (bytes) under one identity, without a link:
    ``encode(msg)`` packs a message built by :attr:`mav`'s ``*_encode`` methods (the
    sequence number advances as a send would)."""

    def __init__(self, src_system: int, src_component: int) -> None:
        self.mav = mavlink.MAVLink(_Buffer(), srcSystem=src_system, srcComponent=src_component)

    def encode(self, msg) -> bytes:
        """The frame of ``msg`` (packed and counted by the encoder)."""
        f = self.mav.file
        f.buf = b""
        self.mav.send(msg)
        return f.buf


def reset_parser(mav) -> str | None:
    """Forget the bytes a pymavlink parser holds; what they were: ``truncated`` (a frame
    cut short), ``non_mavlink`` (text), ``corrupt``, or None if there were none."""
    left = bytes(mav.buf[mav.buf_index:])
    kind = None
    if left:
        if left[0] in (0xFD, 0xFE):
            kind = "truncated"
        elif all(b in PRINTABLE for b in left):
            kind = "non_mavlink"
        else:
            kind = "corrupt"
    mav.buf = bytearray()
    mav.buf_index = 0
    mav.expected_length = mavlink.HEADER_LEN_V1 + 2
    return kind
