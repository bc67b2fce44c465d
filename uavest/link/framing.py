"""MAVLink 2 frames as bytes: the encoder's buffer, the tlog record, the parser's leftovers,
and a parameter's name as a message carries it (:func:`param_name`).

A tlog (MAVProxy's telemetry log) is a sequence of records: an 8-byte big-endian UNIX time
in microseconds, then one frame as sent or received.
"""

from __future__ import annotations

import struct
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["FrameEncoder", "PRINTABLE", "TlogWriter", "bad_data_kind", "param_name",
           "reset_parser", "tlog_record"]

#: Bytes of text (a boot banner, a shell prompt): what is not MAVLink on a serial/TCP port.
PRINTABLE = frozenset(range(0x20, 0x7F)) | {0x09, 0x0A, 0x0D}

_TLOG_TIME = struct.Struct(">Q")


def param_name(raw: object) -> str:
    """A parameter's name as a message holds it (PARAM_VALUE / PARAM_SET /
    PARAM_REQUEST_READ ``param_id``, DataFlash PARM ``Name``: bytes or str, NUL-padded to
    16), as text; undecodable bytes replaced, never an error."""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw or "").rstrip("\x00")


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


class TlogWriter:
    """A tlog written as it is received: :meth:`add` buffers records, :meth:`flush`
    writes them in one unbuffered write of whole records at most every ``flush_s`` s
    (or past 64 KiB), so the file always ends on a record boundary."""

    def __init__(self, path, flush_s: float) -> None:
        self.f = open(path, "wb", buffering=0)  # noqa: SIM115
        self.flush_s = flush_s
        self.buf = bytearray()
        self.last_flush = 0.0

    def add(self, t_us: int, frame: bytes) -> None:
        """Buffer one record (``t_us``: UNIX us)."""
        self.buf += tlog_record(t_us, frame)

    def flush(self, force: bool = False) -> None:
        """Write the buffered records if ``flush_s`` has passed (or ``force``)."""
        now = time.monotonic()
        if not self.buf:
            return
        if force or now - self.last_flush >= self.flush_s or len(self.buf) > 1 << 16:
            # one unbuffered write of whole records: the file always ends on a record
            self.f.write(bytes(self.buf))
            self.buf.clear()
            self.last_flush = now

    def close(self) -> None:
        """Write what is buffered and close the file."""
        self.flush(force=True)
        self.f.close()


def bad_data_kind(m) -> str:
    """What a pymavlink ``BAD_DATA`` message was, as an :class:`uavest.ingest.IngestStats`
    counter: ``bad_signature`` (signed, wrong signature), ``unsigned`` (refused for want
    of a signature), ``non_mavlink`` (text, e.g. a SITL boot banner) or ``corrupt``."""
    reason = str(getattr(m, "reason", ""))
    data = bytes(getattr(m, "data", b"") or b"")
    if "signature" in reason.lower():
        signed = len(data) > 2 and data[0] == 0xFD and data[2] & 0x01
        return "bad_signature" if signed else "unsigned"
    if data and all(b in PRINTABLE for b in data):
        return "non_mavlink"
    return "corrupt"
