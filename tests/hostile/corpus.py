"""Hostile inputs, built from the shared logs: seeded truncations, byte flips, splices,
duplicated and reordered sections, random bytes after a valid header, and targeted
corruptions of one timestamp. Used by ``tests/hostile`` and ``benchmarks/hostile_sweep.py``.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from conftest import shared_logs_dir


def logs_dir() -> Path:
    """The shared logs: tests/conftest.py's ``shared_logs_dir`` (``$UAVEST_LOGS`` or
    ``repo_root/../shared/logs``); tests/ is on the path in pytest and in
    benchmarks/hostile_sweep.py, which imports this module outside pytest."""
    return shared_logs_dir()


def tlog_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, length, msgid) of each record of a tlog: 8-byte BE time + MAVLink frame."""
    out = []
    pos, n = 0, len(data)
    while pos + 8 + 8 <= n:
        stx = data[pos + 8]
        if stx == 0xFE:
            ln = 8 + 6 + data[pos + 9] + 2
            mid = data[pos + 13]
        elif stx == 0xFD:
            sig = 13 if data[pos + 10] & 1 else 0
            ln = 8 + 10 + data[pos + 9] + 2 + sig
            mid = data[pos + 15] | data[pos + 16] << 8 | data[pos + 17] << 16
        else:  # not at a record: resync byte by byte
            pos += 1
            continue
        out.append((pos, ln, mid))
        pos += ln
    return out


def drop_tlog_records(src: Path, dst: Path, msgids, start: float,
                      end: float = float("inf")) -> int:
    """Write the tlog ``src`` to ``dst`` without the records of ``msgids`` received in
    [``start``, ``end``) s after the first record (the bytes between records kept).
    Returns how many were dropped."""
    data = src.read_bytes()
    recs = tlog_records(data)
    (t0,) = struct.unpack(">Q", data[recs[0][0]:recs[0][0] + 8])
    out, last, n = bytearray(), 0, 0
    for off, ln, mid in recs:
        out += data[last:off]
        last = off + ln
        (t,) = struct.unpack(">Q", data[off:off + 8])
        if mid in msgids and start <= (t - t0) * 1e-6 < end:
            n += 1
            continue
        out += data[off:off + ln]
    out += data[last:]
    dst.write_bytes(bytes(out))
    return n


def flip_tlog_rx_top_bit(data: bytes, msgid: int = 30, which: int = 100) -> bytes:
    """Set the top bit of the 8-byte receive time of the ``which``-th record of ``msgid``
    (30 = ATTITUDE)."""
    recs = [r for r in tlog_records(data) if r[2] == msgid]
    off = recs[which][0]
    b = bytearray(data)
    b[off] |= 0x80
    return bytes(b)


def flip_bits(data: bytes, rate: float, seed: int, skip: int = 0) -> bytes:
    """Flip one random bit in a fraction ``rate`` of the bytes after the first ``skip``."""
    rng = np.random.default_rng(seed)
    a = np.frombuffer(data, dtype=np.uint8).copy()
    n = a.size - skip
    k = max(1, int(round(rate * n)))
    idx = skip + rng.choice(n, size=k, replace=False)
    a[idx] ^= (1 << rng.integers(0, 8, size=k)).astype(np.uint8)
    return a.tobytes()


def truncate(data: bytes, frac: float) -> bytes:
    return data[: int(len(data) * frac)]


def splice(a: bytes, b: bytes, cut_a: float, cut_b: float) -> bytes:
    """The first ``cut_a`` of ``a`` then ``b`` from ``cut_b`` on (a cut mid-record)."""
    return a[: int(len(a) * cut_a)] + b[int(len(b) * cut_b):]


def duplicate_section(data: bytes, lo: float, hi: float) -> bytes:
    i, j = int(len(data) * lo), int(len(data) * hi)
    return data[:j] + data[i:j] + data[j:]


def swap_sections(data: bytes, lo: float, mid: float, hi: float) -> bytes:
    i, m, j = (int(len(data) * f) for f in (lo, mid, hi))
    return data[:i] + data[m:j] + data[i:m] + data[j:]


def random_after_header(data: bytes, header: int, size: int, seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    return data[:header] + rng.integers(0, 256, size=size, dtype=np.uint8).tobytes()


def ulog_data_start(data: bytes) -> int:
    """Offset of the first data-section record of a ULog (after definitions)."""
    pos = 16
    while pos + 3 <= len(data):
        size, typ = struct.unpack_from("<HB", data, pos)
        if typ in (ord("A"), ord("D"), ord("L"), ord("C"), ord("S"), ord("O")):
            return pos
        pos += 3 + size
    return pos


def ulog_records(data: bytes):
    """(offset, size, type) of each ULog record after the 16-byte header."""
    pos, out = 16, []
    while pos + 3 <= len(data):
        size, typ = struct.unpack_from("<HB", data, pos)
        out.append((pos, size, typ))
        pos += 3 + size
    return out


def ulog_msg_ids(data: bytes) -> dict[int, str]:
    """msg_id -> topic name from the 'A' (add logged message) records."""
    out = {}
    for pos, size, typ in ulog_records(data):
        if typ == ord("A"):
            _multi, mid = struct.unpack_from("<BH", data, pos + 3)
            out[mid] = data[pos + 6: pos + 3 + size].decode("ascii", "replace")
    return out


def ulog_set_timestamp(data: bytes, topic: str, which: int, value: int) -> bytes:
    """Set the 8-byte ``timestamp`` (first field) of the ``which``-th message of ``topic``."""
    ids = {m for m, n in ulog_msg_ids(data).items() if n == topic}
    recs = [r for r in ulog_records(data)
            if r[2] == ord("D") and struct.unpack_from("<H", data, r[0] + 3)[0] in ids]
    pos = recs[which][0] + 5
    b = bytearray(data)
    struct.pack_into("<Q", b, pos, value)
    return bytes(b)


def ulog_timestamp(data: bytes, topic: str, which: int) -> int:
    ids = {m for m, n in ulog_msg_ids(data).items() if n == topic}
    recs = [r for r in ulog_records(data)
            if r[2] == ord("D") and struct.unpack_from("<H", data, r[0] + 3)[0] in ids]
    return struct.unpack_from("<Q", data, recs[which][0] + 5)[0]


def df_records(data: bytes) -> list[tuple[int, int, str]]:
    """(offset, length, name) of each DataFlash record (A3 95 id + payload, FMT lengths)."""
    fmts: dict[int, tuple[int, str]] = {128: (89, "FMT")}
    out, pos, n = [], 0, len(data)
    while pos + 3 <= n:
        if data[pos] != 0xA3 or data[pos + 1] != 0x95 or data[pos + 2] not in fmts:
            pos += 1
            continue
        ln, name = fmts[data[pos + 2]]
        if data[pos + 2] == 128 and pos + 89 <= n:
            typ, length = data[pos + 3], data[pos + 4]
            fmts[typ] = (length, data[pos + 5: pos + 9].rstrip(b"\0").decode("ascii", "replace"))
        out.append((pos, ln, name))
        pos += ln
    return out


def df_set_time(data: bytes, name: str, which: int, value: int) -> bytes:
    """Set the TimeUS (first field, uint64) of the ``which``-th ``name`` record."""
    recs = [r for r in df_records(data) if r[2] == name]
    b = bytearray(data)
    struct.pack_into("<Q", b, recs[which][0] + 3, value)
    return bytes(b)


def df_time(data: bytes, name: str, which: int) -> int:
    recs = [r for r in df_records(data) if r[2] == name]
    return struct.unpack_from("<Q", data, recs[which][0] + 3)[0]


def ulog_corrupt_param(data: bytes, which: int = 0) -> bytes:
    """Make the ``which``-th parameter record's type unreadable ('float' -> 'flXat'):
    pyulog then returns its value as raw bytes."""
    recs = [r for r in ulog_records(data) if r[2] == ord("P")]
    pos = recs[which][0] + 3
    b = bytearray(data)
    key_len = b[pos]
    key = bytes(b[pos + 1: pos + 1 + key_len])
    i = key.find(b"float")
    if i < 0:
        i = key.find(b"int32_t")
    b[pos + 1 + i + 2] = ord("X")
    return bytes(b)


def ulog_set_all_timestamps(data: bytes, topic: str, value: int) -> bytes:
    """Set the ``timestamp`` of every message of ``topic`` to ``value``."""
    ids = {m for m, n in ulog_msg_ids(data).items() if n == topic}
    b = bytearray(data)
    for pos, _size, typ in ulog_records(data):
        if typ == ord("D") and struct.unpack_from("<H", data, pos + 3)[0] in ids:
            struct.pack_into("<Q", b, pos + 5, value)
    return bytes(b)
