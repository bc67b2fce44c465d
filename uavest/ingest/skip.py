"""Skip, without decoding, the log records of types no converter uses (docs/ingest.md,
"What is decoded"), and find a tlog's good records whatever lies between them.

pymavlink decodes every record of a tlog or DataFlash log into a message object; about two
thirds of a typical telemetry log are types :mod:`uavest.ingest.convert` never looks at.

* tlog: :class:`TlogFramer` is the one resync/validity routine of the reader: it finds each
  good record (complete frame, valid marker and flags, good CRC) in a memory map of the
  file, classifies what lies between (console text, bad-CRC frames, cut frames, junk) and
  hands the reader the record; the reader decodes it with pymavlink's ``decode`` (used
  types, or every type with ``_decode_all``) or yields a :class:`Skipped` stand-in. Both
  paths see the same records and the same skipped bytes, so they count the same.
* DataFlash: :class:`DataflashSkipper` looks at a record's header *before* pymavlink's
  parser would see it and steps over it only when it is of an unused type and pymavlink
  would certainly accept it; anything else is left to pymavlink exactly as before.
"""

from __future__ import annotations

import mmap
import operator
import os
import struct
from collections.abc import Iterator

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


_PRINTABLE = frozenset(range(0x20, 0x7F)) | {0x09, 0x0A, 0x0D}
_TEXT_RUN = 4  # printable bytes in a row (without record times) that count as text
_RX_SPAN = 3 * 24 * 3600.0  # s, record times this close to a good record's are plausible
# (pymavlink's own bound when it scans for a record time)
_JUNK_UNIT = 271  # bytes: junk is counted ``corrupt`` in frames' worth (the largest record)

#: What :class:`TlogFramer` steps over, by kind (``IngestStats.skipped``): ``text_bytes``
#: (printable bytes between frames, one per record in a SITL console banner),
#: ``bad_crc`` (whole frames whose checksum is wrong), ``partial_frame`` (a frame header
#: whose frame is cut by the next good record), ``unknown_id`` (a frame of an id the
#: dialect lacks), ``junk_bytes`` (anything else), ``truncated_bytes`` (a cut last record).
SKIP_KINDS = ("text_bytes", "bad_crc", "partial_frame", "unknown_id", "junk_bytes",
              "truncated_bytes")


class TlogFramer:
    """The one resync/validity routine of the tlog reader (both the skipping and the
    decode-everything paths use it, so they count the same).

    A tlog is a sequence of records: an 8-byte big-endian receive time (us UNIX) and one
    MAVLink 1 or 2 frame. :meth:`next` returns the next good record at or after a file
    offset: a frame that is complete, has a valid marker and incompat flags, and (known
    id) a good CRC with the dialect's CRC extra byte, or (an id the dialect lacks, whose
    CRC cannot be checked) is followed by a good record or the end of the file. Whatever
    lies between is classified (:data:`SKIP_KINDS`): records of console text, whole frames
    with a bad CRC, frames cut by the next record, junk. This is what pymavlink's parser
    accepts, found without ever losing step: a good frame is never missed because of the
    bytes before it (pymavlink's own stream parser can stay out of step after text).
    """

    def __init__(self, data, mod) -> None:
        self.mm = data
        self.size = len(data)
        self.ignore_crc = bool(getattr(mod, "MAVLINK_IGNORE_CRC", 0))
        fast = getattr(mod, "mcrf4xx", None)
        self.crc = ((lambda b: fast(b, 0xFFFF)) if fast is not None
                    else (lambda b: mod.x25crc(b).crc))
        self.extra = {mid: bytes((cls.crc_extra,)) for mid, cls in mod.mavlink_map.items()}

    # ------------------------------------------------------------------ one frame
    def frame(self, o: int) -> tuple[str, int, int]:
        """(verdict, end, msgid) of a record assumed at ``o`` (its frame at ``o + 8``):
        verdict ``ok`` | ``bad_crc`` | ``unknown`` (id not in the dialect) | ``cut`` (ends
        past the file) | ``none`` (no frame header there); ``end``: where it ends."""
        mm, n = self.mm, self.size
        if o + 9 > n:
            return "none", o, -1
        mk = mm[o + 8]
        if mk == 0xFD:
            if o + 18 > n:
                return "cut", o + 18, -1
            inc = mm[o + 10]
            if inc & 0xFE:
                return "none", o, -1
            sig = 13 if inc & 1 else 0
            end = o + 8 + mm[o + 9] + 12 + sig
            mid = mm[o + 15] | mm[o + 16] << 8 | mm[o + 17] << 16
        elif mk == 0xFE:
            if o + 14 > n:
                return "cut", o + 16, -1
            sig = 0
            end = o + 8 + mm[o + 9] + 8
            mid = mm[o + 13]
        else:
            return "none", o, -1
        if end > n:
            return "cut", end, mid
        extra = self.extra.get(mid)
        if extra is None:
            return "unknown", end, mid
        if not self.ignore_crc:
            c = end - 2 - sig
            if self.crc(mm[o + 9:c] + extra) != (mm[c] | mm[c + 1] << 8):
                return "bad_crc", end, mid
        return "ok", end, mid

    def good(self, o: int) -> tuple[str, int, int] | None:
        """The frame at ``o`` if it is a good record (see the class), else None."""
        v = self.frame(o)
        if v[0] == "ok":
            return v
        if v[0] == "unknown" and (v[1] == self.size or self.frame(v[1])[0] == "ok"):
            return v
        return None

    def rx(self, o: int) -> float:
        """Receive time (s UNIX) of the record at ``o``."""
        return _T.unpack_from(self.mm, o)[0] * 1.0e-6

    def records(self) -> Iterator[tuple[int, int, int]]:
        """``(start of the frame, end, msgid)`` of every good record of a known type, in
        file order, what lies between stepped over uncounted (the reader counts it:
        :meth:`next`); for tests and benchmarks of the decoding."""
        o, last = 0, None
        while o < self.size:
            o, verdict, end, mid, _ = self.next(o, last)
            if verdict == "eof":
                return
            last = self.rx(o)
            if verdict == "ok":
                yield o + 8, end, mid
            o = end

    # ------------------------------------------------------------------ resync
    def next(self, o: int, last_rx: float | None = None):
        """``(start, verdict, end, msgid, skipped)`` of the first good record at or after
        ``o`` (start = ``size`` and verdict ``eof`` if none); ``skipped``: {kind: count}
        of what lies between (empty when the record is at ``o``). ``last_rx``: the
        receive time of the previous good record (to judge record times in the gap)."""
        v = self.good(o)
        if v is not None:
            return o, v[0], v[1], v[2], {}
        p = self._search(o + 1)
        if p < self.size:
            v = self.good(p)
            ref = self.rx(p)
        else:
            v = ("eof", self.size, -1)
            ref = last_rx
        return p, v[0], v[1], v[2], self._classify(o, p, ref)

    def _search(self, q: int) -> int:
        """First offset >= q holding a good record (``size`` if none)."""
        mm, n = self.mm, self.size
        while q + 8 < n:
            a, b = mm.find(b"\xfd", q + 8), mm.find(b"\xfe", q + 8)
            m = min(x for x in (a, b, n) if x >= 0)
            if m >= n:
                break
            q = m - 8
            if self.good(q) is not None:
                return q
            q += 1
        return n

    def _classify(self, o: int, p: int, ref: float | None) -> dict[str, int]:
        """What the bytes [o, p) are, by kind (:data:`SKIP_KINDS`)."""
        mm = self.mm
        out: dict[str, int] = {}

        def add(k: str, v: int = 1) -> None:
            out[k] = out.get(k, 0) + v

        q = o
        while q < p:
            plausible = (q + 9 <= p and ref is not None
                         and abs(self.rx(q) - ref) <= _RX_SPAN)
            if plausible:
                verdict, end, _ = self.frame(q)
                if verdict != "none":
                    if p == self.size and verdict == "cut":
                        add("truncated_bytes", p - q)
                        break
                    if end <= p:
                        add({"bad_crc": "bad_crc", "unknown": "unknown_id"}.get(
                            verdict, "partial_frame"))
                        q = end
                        continue
                    add("partial_frame")  # cut by the next good record
                    break
                if mm[q + 8] in _PRINTABLE:  # a record of console text
                    add("text_bytes")
                    q += 9
                    continue
            r = q
            while r < p and mm[r] in _PRINTABLE:
                r += 1
            if r - q >= _TEXT_RUN:  # text without record times
                add("text_bytes", r - q)
                q = r
                continue
            if p == self.size and p - q < 9 and not out.get("junk_bytes"):
                add("truncated_bytes", p - q)  # a cut after (part of) a record time
                break
            add("junk_bytes")
            q += 1
        return out


class FrameDecoder:
    """pymavlink's ``MAVLink.decode`` for a frame :class:`TlogFramer` has accepted (marker,
    flags, length and CRC checked), without decode's second CRC pass and per-field loops:
    the message types of scalar fields only (no arrays, strings or chars: RAW_IMU,
    SIMSTATE, ATTITUDE, GPS_RAW_INT...) are unpacked with the message class's own
    ``unpacker`` (the payload zero-padded when MAVLink 2 truncated it, as decode does) and
    reordered with its own ``orders``, and the message object is built by the class with
    the attributes decode sets. Signed frames and every other type go to pymavlink's
    ``decode``. The same objects as decode's (``tests/unit/test_frame_decoder.py`` compares
    every record of the logs), about half its time (decode was a fifth of reading a tlog).
    """

    def __init__(self, mod, mav) -> None:
        self.mav = mav
        self.header = mod.MAVLink_header
        self.plan: dict[int, tuple] = {}
        for mid, cls in mod.mavlink_map.items():
            u, orders = cls.unpacker, cls.orders
            if (len(orders) > 1 and sum(cls.lengths) == len(cls.lengths)
                    and not any(ch in u.format for ch in "sc")):
                self.plan[mid] = (cls, u, u.size, operator.itemgetter(*orders))

    def __call__(self, mm, o: int, end: int, mid: int):
        """The message of the frame ``mm[o:end]`` (its marker at ``o``), id ``mid``."""
        p = self.plan.get(mid)
        v2 = mm[o] == 0xFD
        if p is None or (v2 and mm[o + 2] & 1):
            return self.mav.decode(bytearray(mm[o:end]))
        cls, unpacker, size, get = p
        if v2:
            hl, inc, cf, seq, src, comp = 10, mm[o + 2], mm[o + 3], mm[o + 4], mm[o + 5], mm[o + 6]
        else:
            hl, inc, cf, seq, src, comp = 6, 0, 0, mm[o + 2], mm[o + 3], mm[o + 4]
        mlen = mm[o + 1]
        if mlen >= size:
            t = unpacker.unpack_from(mm, o + hl)
        else:
            t = unpacker.unpack(mm[o + hl:o + hl + mlen] + bytes(size - mlen))
        m = cls(*get(t))
        buf = bytearray(mm[o:end])
        m._signed = False
        m._msgbuf = buf
        m._payload = buf[6:-2]
        m._crc = buf[-2] | buf[-1] << 8
        m._header = self.header(mid, inc, cf, mlen, seq, src, comp)
        return m


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
