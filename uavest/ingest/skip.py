"""Skip, without decoding, the log records of types no converter uses (docs/ingest.md,
"What is decoded").

pymavlink decodes every record of a tlog or DataFlash log into a message object; about two
thirds of a typical telemetry log are types :mod:`uavest.ingest.convert` never looks at. The
skippers here look at a record's header in a memory map of the file *before* pymavlink's
parser would see it and, when the record is of an unused type **and** pymavlink's parser is
certain to accept it as a good record (complete, right marker, known id, good CRC...), step
over it and return a :class:`Skipped` stand-in (type name, system id, receive time). Anything
else (a record of a used type, a bad CRC, garbage between records, a cut end, an unknown
id, a parser holding buffered bytes) is left to pymavlink exactly as before, so the bad-data
counts of a damaged log do not change: a corrupt record of an unused type still reaches the
parser, which reports it as before.
"""

from __future__ import annotations

import mmap
import os
import struct
import sys

from .convert import DATAFLASH_CONVERTERS, MAVLINK_CONVERTERS

#: MAVLink messages decoded from a tlog: the converters' and those the reader itself reads
#: (PARAM_VALUE: parameters; SYSTEM_TIME: the UNIX-to-boot time offset). HEARTBEAT is not
#: needed by the file reader (a live link decodes everything: its own parser, not this).
TLOG_DECODED = frozenset(MAVLINK_CONVERTERS) | {"PARAM_VALUE", "SYSTEM_TIME"}

#: DataFlash records decoded: the converters', PARM (parameters), FMT/FMTU (formats: the
#: parser must see them) and the few pymavlink's own bookkeeping reads fields of (flight
#: mode, vehicle type, PX4 time base), so that an exception there is reported as before.
DATAFLASH_DECODED = frozenset(DATAFLASH_CONVERTERS) | {
    "PARM", "FMT", "FMTU", "MODE", "MSG", "VER", "STAT", "TIME"}

_T = struct.Struct(">Q")


class Skipped:
    """A record that was framed (and, for MAVLink, CRC-checked) but not decoded.

    Stands in for a pymavlink message in the reader: ``get_type()`` (message or DataFlash
    type name), ``get_srcSystem()`` (MAVLink system id; 0 for DataFlash) and ``rx`` (tlog
    receive time, s UNIX; None for DataFlash).
    """

    __slots__ = ("name", "sysid", "rx")

    def __init__(self, name: str, sysid: int, rx: float | None) -> None:
        self.name = name
        self.sysid = sysid
        self.rx = rx

    def get_type(self) -> str:
        """Message type name."""
        return self.name

    def get_srcSystem(self) -> int:  # noqa: N802 - pymavlink's name
        """MAVLink source system id (0 for DataFlash)."""
        return self.sysid


def _map(path: str | os.PathLike) -> tuple[mmap.mmap | None, int]:
    size = os.path.getsize(path)
    if size == 0:
        return None, 0
    with open(path, "rb") as f:
        return mmap.mmap(f.fileno(), size, access=mmap.ACCESS_READ), size


class TlogSkipper:
    """Steps over the tlog records of unused types for a ``pymavlink.mavutil.mavlogfile``.

    Call :meth:`next` before each ``conn.recv_msg()``: it returns a :class:`Skipped` (the
    file position moved past the record) or None (read the next record with pymavlink;
    the file position is where pymavlink expects it). Only used while pymavlink's parser is
    idle (no buffered bytes, the previous record good, past the first record), and for a
    record exactly as long as its header says that ends inside the file, so what pymavlink
    would have read and decided is known: the reader state it keeps (the expected header
    length of the next frame, the last good receive time) is updated as pymavlink would.
    """

    def __init__(self, path: str | os.PathLike, decoded: frozenset[str] = TLOG_DECODED) -> None:
        self.mm, self.size = _map(path)
        self.decoded = decoded
        self.pos: int | None = None  # file offset after the last skipped record
        self._mavtype: type | None = None
        self._mod = None
        self._ignore_crc = False
        self._crc = None
        self._skip: dict[int, tuple[str, bytes]] = {}

    def _table(self, mav) -> None:
        """The unused types for parser ``mav``: msgid -> (name, crc_extra byte)."""
        self._mavtype = type(mav)
        mod = self._mod = sys.modules[type(mav).__module__]
        self._ignore_crc = bool(mod.MAVLINK_IGNORE_CRC)
        fast = getattr(mod, "mcrf4xx", None)
        self._crc = ((lambda b: fast(b, 0xFFFF)) if fast is not None
                     else (lambda b: mod.x25crc(b).crc))
        # the MAVLink 2 parser (the one uavest.ingest selects); another: decode all
        self._skip = {} if getattr(mod, "WIRE_PROTOCOL_VERSION", "") != "2.0" else {
            mid: (cls.msgname, bytes((cls.crc_extra,)))
            for mid, cls in mod.mavlink_map.items() if cls.msgname not in self.decoded}

    def sync(self, conn) -> None:
        """Put the file position where the skipped records end (before pymavlink reads)."""
        if self.pos is not None:
            conn.f.seek(self.pos)
            self.pos = None

    def next(self, conn, at: int = -1) -> Skipped | None:
        """The next record as :class:`Skipped` if it is a good record of an unused type;
        ``at``: the file position if known (after a record pymavlink read), else -1."""
        o = self.pos
        if o is None:
            o = at if at >= 0 else conn.f.tell()
        mm = self.mm
        # the shortest record (MAVLink 1, empty payload) is 16 bytes with its time
        if mm is None or o + 18 > self.size:
            return self.sync(conn)
        mk = mm[o + 8]
        if mk == 0xFD:
            mid = mm[o + 15] | mm[o + 16] << 8 | mm[o + 17] << 16
        elif mk == 0xFE:
            mid = mm[o + 13]
        else:
            return self.sync(conn)
        mav = conn.mav
        if type(mav) is not self._mavtype:
            self._table(mav)
        info = self._skip.get(mid)
        if info is None:  # a used type, or one pymavlink does not know: pymavlink reads it
            if self.pos is not None:
                self.sync(conn)
            return None
        if conn.first_byte or len(mav.buf) != mav.buf_index:
            return self.sync(conn)  # pymavlink's parser is not idle
        last = conn._last_message
        if last is None or last.get_type() == "BAD_DATA":
            return self.sync(conn)  # pymavlink may rescan the next record's time
        if mk == 0xFD:
            inc = mm[o + 10]
            if inc & 0xFE:
                return self.sync(conn)  # pymavlink: "invalid incompat_flags" (BAD_DATA)
            sig = 13 if inc & 1 else 0
            if sig and mav.signing.secret_key is not None:
                return self.sync(conn)
            flen = mm[o + 9] + 12 + sig
            sysid = mm[o + 13]
            expect = 12
        else:
            sig = 0
            flen = mm[o + 9] + 8
            sysid = mm[o + 11]
            expect = 8
        end = o + 8 + flen
        # a frame shorter than the header pymavlink reads first makes it read into the next
        # record (its own quirk): left to pymavlink, as is a frame cut by the end of file
        if flen < mav.expected_length or end > self.size:
            return self.sync(conn)
        if not self._ignore_crc:
            c = end - 2 - sig
            if self._crc(mm[o + 9:c] + info[1]) != (mm[c] | mm[c + 1] << 8):
                return self.sync(conn)  # pymavlink: "invalid MAVLink CRC" (BAD_DATA)
        rx = _T.unpack_from(mm, o)[0] * 1.0e-6
        conn._last_timestamp = rx  # pymavlink's post_message would set it
        mav.expected_length = expect  # pymavlink's parser after a frame with this marker
        self.pos = end
        return Skipped(info[0], sysid, rx)

    def close(self) -> None:
        """Release the memory map."""
        if self.mm is not None:
            self.mm.close()
            self.mm = None


_NUMERIC = set("bBghHiIfcCeELdMqQ")


class DataflashSkipper:
    """Steps over the DataFlash records of unused types for a ``DFReader_binary``.

    Call :meth:`next` before each ``conn.recv_msg()``: a :class:`Skipped` (``conn.offset``
    moved past the record) or None (let pymavlink read it). Only a record starting exactly
    at ``conn.offset`` with a known format whose layout pymavlink unpacks without error is
    skipped; a skipped record is not handed to pymavlink's per-message bookkeeping (its
    "latest message" table and log clock, which the reader does not use).
    """

    def __init__(self, decoded: frozenset[str] = DATAFLASH_DECODED) -> None:
        self.decoded = decoded
        self._ok: dict = {}  # DFFormat object -> skippable (FMT records replace them)

    def _skippable(self, fmt) -> bool:
        ok = self._ok.get(fmt)
        if ok is None:
            ok = fmt.name not in self.decoded
            try:
                ok = ok and struct.calcsize(fmt.msg_struct) == fmt.len - 3
            except struct.error:
                ok = False
            cols, fmts = fmt.columns, fmt.msg_fmts
            if ok and cols and cols[0] in ("TimeUS", "TimeMS"):
                ok = bool(fmts) and fmts[0] in _NUMERIC  # the log clock reads it
            if ok and fmt.instance_field is not None:
                ok = fmt.colhash.get(fmt.instance_field, len(fmts)) < len(fmts)
            self._ok[fmt] = ok
        return ok

    def next(self, conn, at: int = -1) -> Skipped | None:
        """The record at ``conn.offset`` as :class:`Skipped` if it is of an unused type
        (``at``: not needed, the reader keeps ``conn.offset``)."""
        o = conn.offset
        n = conn.data_len
        if o + 3 > n:
            return None
        mm = conn.data_map
        if mm[o] != 0xA3 or mm[o + 1] != 0x95:
            return None
        t = mm[o + 2]
        fmt = conn.formats.get(t)
        if fmt is None or n - o < fmt.len or not self._skippable(fmt):
            return None
        conn.offset = o + fmt.len
        conn.remaining = n - conn.offset
        conn.prev_type = t
        return Skipped(fmt.name, 0, None)
