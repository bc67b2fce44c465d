"""Sources read through pymavlink: telemetry logs (.tlog), DataFlash (.bin) and live links."""

from __future__ import annotations

import contextlib
import dataclasses
import heapq
import io
import logging
import math
import os
import re
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..link.framing import param_name
from .convert import Raw, check, convert_dataflash, convert_mavlink, stat_key
from .skip import TLOG_DECODED, DataflashSkipper, FrameDecoder, Skipped, TlogFramer, _map
from .timebase import UNIX_US_MIN, RxFilter, StreamGate, VehicleClock, retime_unix
from .types import (
    AdsbSample,
    AttitudeRef,
    BaroSample,
    DetectionSample,
    GnssSample,
    ImuSample,
    IngestError,
    IngestStats,
    LogParams,
    MagSample,
    PositionSample,
    Sample,
    arrival_order,
)

# categories whose all-zero records may mean "not fitted"
_SENSOR_CATS = ("imu", "mag", "baro", "gnss")

# Messages without a time field: timed from receive time (see docs/ingest.md).
_UNTIMED = {"SIMSTATE", "SIM_STATE", "AHRS2", "ADSB_VEHICLE"}
_GNSS_MESSAGES = {"GPS_RAW_INT", "GPS2_RAW", "GPS_INPUT"}  # time_usec 0: no GNSS time yet
_MAX_STALL = 1000  # reads without file progress before giving up (hang guard)
_SKIPPED_RE = re.compile(r"Skipped (\d+) bad bytes")
_BADHDR_RE = re.compile(r"bad header 0x[0-9a-f]+ 0x[0-9a-f]+ at (\d+)")
_log = logging.getLogger("uavest.ingest")


def _chatter(text: str, stats: IngestStats, what: str) -> int:
    """Count what pymavlink printed (kept off the terminal; shown with -v through
    ``logging``): runs of "bad header" bytes and "Skipped N bad bytes" as corrupt, "unknown
    msg type" as unknown_message. Returns the corrupt runs counted."""
    if not text:
        return 0
    runs, last = 0, None
    for m in _BADHDR_RE.finditer(text):
        o = int(m.group(1))
        if last is None or o != last + 1:
            runs += 1
        last = o
    runs += len(_SKIPPED_RE.findall(text)) + text.count("Failed to parse")
    runs += text.count("bad msg at offset")
    stats.bad("corrupt", n=runs)
    stats.bad("unknown_message", n=text.count("unknown msg type"))
    lines = [ln for ln in text.splitlines() if ln.strip() and "dfindexer" not in ln
             and "PYMAVLINK_FAST_INDEX" not in ln]
    for ln in lines[:5]:
        _log.info("%s: pymavlink: %s", what, ln[:200])
    if len(lines) > 5:
        _log.info("%s: pymavlink: ... %d more lines", what, len(lines) - 5)
    return runs


@contextlib.contextmanager
def _quiet():
    """pymavlink's prints (stdout and stderr, Python's and its C indexer's at the file
    descriptor level) into a buffer."""
    import sys
    import tempfile

    buf = io.StringIO()
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        saved = []
        try:
            for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
                with contextlib.suppress(Exception):
                    stream.flush()
                try:
                    saved.append((fd, os.dup(fd)))
                    os.dup2(tmp.fileno(), fd)
                except OSError:
                    pass
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                yield buf
        finally:
            for fd, old in saved:
                os.dup2(old, fd)
                os.close(old)
            tmp.seek(0)
            buf.write(tmp.read(1 << 20).decode("utf-8", "replace"))


def build(raw: Raw, t: float) -> Sample:
    """Attach time ``t`` (s, vehicle clock) to a converted item."""
    v = raw.values
    if raw.cat == "imu":
        return ImuSample(t, v[0], v[1], raw.source, raw.instance)
    if raw.cat == "mag":
        return MagSample(t, v[0], raw.source, raw.instance)
    if raw.cat == "ref":
        return AttitudeRef(t, v[0], raw.kind, raw.source)
    if raw.cat == "det":
        from .detections import rae_from_frd

        m = raw.meta
        xyz = v[0]
        rae = rae_from_frd(xyz) if m["frame"] == "BODY_FRD" else None
        return DetectionSample(
            t, m["obstacle_id"], xyz, m["frame"], rae, m["min_distance"], m["max_distance"],
            raw.source, m["sensor_type"],
        )
    if raw.cat == "adsb":
        m = raw.meta
        return AdsbSample(
            t, m["icao"], v[0], v[1], m["altitude_type"], m["callsign"], m["flags"], m["tslc"],
            raw.source, m["squawk"], m["emitter_type"],
        )
    if raw.cat == "gnss":
        a = v[2]
        return GnssSample(t, v[0], v[1], int(raw.meta["fix_type"]), float(a[0]), float(a[1]),
                          float(a[2]), float(a[3]), float(a[4]), int(a[5]), raw.source,
                          raw.instance)
    if raw.cat == "baro":
        b = v[0]
        return BaroSample(t, float(b[0]), float(b[1]), float(b[2]), raw.source, raw.instance)
    return PositionSample(t, v[0], v[1], v[2], raw.source)


def _all_zero_gnss(raw) -> bool:
    """A GNSS record of a receiver that is not there: no GPS (fix 0) and lat = lon = 0."""
    return int(raw.meta.get("fix_type", 0)) == 0 and not np.any(raw.values[0][:2])


def gate_time(raw: Raw, t: float) -> float:
    """Time (s) under which the stream gate orders an item: ADS-B by its position time."""
    if raw.cat == "adsb":
        return t - raw.meta["tslc"]
    return t


#: A live link's mark after the messages of one read of its connection (one receive
#: burst, one receive time): ``(None, BURST_END)`` from ``_messages``.
BURST_END = object()


class _Reorder:
    """Small heap that releases measurements in time order once older than ``window`` s.

    ``window`` <= 0 is **on arrival**: nothing waits for newer samples. The items of one
    receive burst (the messages of one read of the connection, which share their receive
    time: a tlog replays the same bursts) are released together as soon as the burst is
    complete (at the link's end-of-read mark, or when a message of another receive time
    comes; without receive times each message is a burst), in time order within the
    burst, an IMU sample after the other items of its time (a step that ends at it is
    then complete when it arrives: the magnetometer of its message or of another message
    read with it). An item older than one released before is not ``late`` here: ordering
    across bursts is the consumer's (the engine's bounded history,
    :mod:`uavest.engine.history`)."""

    def __init__(self, window: float, stats: IngestStats) -> None:
        self.window = window
        self.stats = stats
        self.on_arrival = not window > 0
        self.heap: list = []
        self.ready: list[Sample] = []  # on arrival: the items of the message being read
        self.seq = 0
        self.newest = -math.inf
        self.last_out = -math.inf

    @property
    def floor(self) -> float:
        """The time (s) below which an item would be ``late`` (-inf on arrival)."""
        return -math.inf if self.on_arrival else self.last_out

    def push(self, m: Sample) -> None:
        if self.on_arrival:
            self.ready.append(m)
            return
        if m.t < self.last_out:
            self.stats.bad("late", sample_key(m))
            return
        heapq.heappush(self.heap, (m.t, self.seq, m))
        self.seq += 1
        self.newest = max(self.newest, m.t)

    def pop_ready(self, flush: bool = False) -> Iterator[Sample]:
        if self.on_arrival:
            if flush and self.ready:  # the end of a burst
                out, self.ready = self.ready, []
                if len(out) > 1:
                    out.sort(key=arrival_order)
                for m in out:
                    if m.t > self.last_out:
                        self.last_out = m.t
                    yield m
            return
        limit = math.inf if flush else self.newest - self.window
        while self.heap and self.heap[0][0] <= limit:
            t, _, m = heapq.heappop(self.heap)
            self.last_out = t
            yield m


def sample_key(m: Sample) -> str:
    """The name a sample is counted under in :class:`IngestStats` (``late``...): its
    source, ``<source>.mag`` for the magnetometer of an IMU message (as
    :func:`~uavest.ingest.convert.stat_key` counts the converted items)."""
    if isinstance(m, MagSample) and not m.source.startswith("MAG"):
        return m.source + ".mag"
    return m.source


_GPS_EPOCH = 315964800.0  # UNIX time of the GPS epoch (1980-01-06)
_LEAP_S = 18.0  # GPS - UTC since 2017


def _gps_geo(msg, params: LogParams, unix_offset: float | None) -> None:
    """Record the first 3-D GPS fix with a date (MAVLink GPS_RAW_INT, DataFlash GPS)."""
    with contextlib.suppress(Exception):
        if msg.get_type() == "GPS_RAW_INT":
            if msg.fix_type < 3:
                return
            params.set_fix(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)
            tu = float(msg.time_usec)
            utc = tu * 1e-6 if tu > 1e15 else (
                None if unix_offset is None else unix_offset + tu * 1e-6)
            if utc is not None:
                params.set_geo(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3, utc)
            return
        if getattr(msg, "Status", 0) < 3:
            return
        params.set_fix(msg.Lat, msg.Lng, getattr(msg, "Alt", 0.0))
        if not getattr(msg, "GWk", 0):
            return
        utc = _GPS_EPOCH + msg.GWk * 604800.0 + msg.GMS * 1e-3 - _LEAP_S
        params.set_geo(msg.Lat, msg.Lng, getattr(msg, "Alt", 0.0), utc)


GPA_LOOKAHEAD = 8  # DataFlash records after a GPS searched for its GPA (written next)


def _gps_instance(msg) -> int:
    i = getattr(msg, "I", None)
    return int(i) if i is not None else (1 if msg.get_type().endswith("2") else 0)


def merge_gpa(pairs):
    """DataFlash ``(record, None)`` pairs with each GPS record given its GPA record (same
    TimeUS and instance, ArduPilot writes it right after) as ``gps._gpa``: the receiver's
    accuracies belong to the fix. A GPS is held until its GPA or :data:`GPA_LOOKAHEAD`
    records later (then it goes on without); the records in between keep their order."""
    held = None  # [gps message, records seen after it]
    for msg, rx in pairs:
        name = msg.get_type() if msg is not None else ""
        if held is not None:
            gps, after = held
            if (name in ("GPA", "GPA2") and getattr(msg, "TimeUS", None) == gps.TimeUS
                    and _gps_instance(msg) == _gps_instance(gps)):
                gps._gpa = msg
                held = None
                yield gps, None
                yield from after
                yield msg, rx
                continue
            if name not in ("GPS", "GPS2") and len(after) < GPA_LOOKAHEAD:
                after.append((msg, rx))
                continue
            held = None
            yield gps, None
            yield from after
        if name in ("GPS", "GPS2") and hasattr(msg, "TimeUS"):
            held = [msg, []]
            continue
        yield msg, rx
    if held is not None:
        yield held[0], None
        yield from held[1]


@dataclasses.dataclass
class _Pass:
    """The state of one pass of :meth:`MavlinkSource.__iter__` over the messages: the
    stream gate, the reorder buffer, one vehicle clock per system, each system's UNIX
    offset from SYSTEM_TIME (``systime``: sysid -> unix - boot s) and the sensor
    instances that sent a non-zero record (``fitted``)."""

    stats: IngestStats
    gate: StreamGate
    reorder: _Reorder
    clocks: dict[int, VehicleClock] = dataclasses.field(default_factory=dict)
    systime: dict[int, float] = dataclasses.field(default_factory=dict)
    fitted: set[str] = dataclasses.field(default_factory=set)

    def finish(self, items) -> None:
        """Items the clock let through, ``(t, (sysid, the converted items of one
        message))`` (one message is one clock push, so the IMU and mag parts of a message
        do not confirm a reset twice): each through the stream gate (detections may share
        a time, ADS-B repeats, ADS-B at its position time), then into the reorder
        buffer."""
        gate, st = self.gate, self.stats
        special = {"det": gate.admit_multi, "adsb": gate.admit_repeat}
        for t, (sysid, raws) in items:
            for raw in raws:
                key = (sysid, raw.cat, raw.source, raw.instance)
                admit = special.get(raw.cat, gate.admit)
                tg = gate_time(raw, t)
                if not admit(key, tg, raw.values, stat_key(raw), count=raw.primary):
                    continue
                st.accepted[stat_key(raw)] += 1
                self.reorder.push(build(raw, t))

    def drain(self, clock: VehicleClock) -> None:
        """Count the messages ``clock`` rejected (time faults: once per message)."""
        for kind, (_sysid, raws) in clock.take_rejected():
            for raw in raws:
                if raw.primary:
                    self.stats.bad(kind, stat_key(raw))


class MavlinkSource:
    """Iterable of measurements from a tlog or a DataFlash log (live links: ``LiveLink``).

    Yields :class:`ImuSample`, :class:`MagSample`, :class:`AttitudeRef`,
    :class:`PositionSample`, :class:`GnssSample` and :class:`BaroSample` (and detections,
    ADS-B) in vehicle-time order (a ``reorder_window`` second
    buffer absorbs the small disorder between message types).  ``stats`` and
    ``params`` fill while iterating; ``params`` is complete after the iteration.
    Records of types no converter uses are stepped over undecoded when they are certainly
    good (``undecoded`` counts them; docs/ingest.md "What is decoded").
    Iterating twice re-reads the file.  :class:`uavest.ingest.live.LiveLink` subclasses
    this and replaces :meth:`_messages` with its reader queue (same conversion path).
    """

    def __init__(
        self,
        target: str | Path,
        fmt: str,
        *,
        imu: str | None = None,
        reorder_window: float = 1.0,
        sysid: int | None = None,
    ) -> None:
        self.path = target
        self.format = fmt
        self.imu = imu
        self.reorder_window = reorder_window
        self.sysid = sysid  # MAVLink: only this system (others counted wrong_sysid)
        self.stats = IngestStats()
        self.params = LogParams()
        self.bytes_read = 0  # file position of the reader (progress while reading)
        # records of types no converter uses stepped over without decoding (skip.py); they
        # are counted in stats.messages like the decoded ones
        self.undecoded = 0
        # True: pymavlink decodes every record (the former path; for tests and benchmarks)
        self._decode_all = False

    # ----------------------------------------------------------------- readers
    def _open(self):
        from pymavlink import DFReader

        try:
            with _quiet() as buf:
                if self.format == "dataflash":
                    conn = DFReader.DFReader_binary(str(self.path), zero_time_base=False)
                else:
                    conn = DFReader.DFReader_text(str(self.path), zero_time_base=False)
            _chatter(buf.getvalue(), self.stats, str(self.path))
            return conn
        except Exception as e:  # pymavlink raises many kinds on garbage
            raise IngestError(
                f"{self.path}: cannot open as {self.format} ({type(e).__name__}: {e})"
            ) from e

    def _messages(self) -> Iterator[tuple[object, float | None]]:
        """Yield (message, receive time or None) with bad frames counted, never hanging;
        tlog receive times checked against their neighbours (:class:`RxFilter`)."""
        if self.format == "tlog":
            return RxFilter(self.stats).filter(self._read())
        return merge_gpa(self._read())

    def _skipper(self, conn):
        """The skipper of unused DataFlash records for ``conn`` (None: decode every
        record; tlogs: :meth:`_read_tlog`)."""
        if self._decode_all:
            return None
        from pymavlink import DFReader

        if isinstance(conn, DFReader.DFReader_binary):
            return DataflashSkipper()
        return None  # DataFlash text: decoded as before

    def _read_tlog(self) -> Iterator[tuple[object, float | None]]:
        """The records of a tlog, found by :class:`uavest.ingest.skip.TlogFramer` (the one
        resync/validity routine of both paths): good frames of used types decoded by
        pymavlink's parser, of unused types stepped over as :class:`Skipped` (every one
        decoded with ``_decode_all``); what lies between counted by kind
        (``stats.skipped``; text as ``non_mavlink``, the rest ``corrupt``/``truncated``).

        Frames are decoded with the MAVLink 2 ``ardupilotmega`` dialect named here, not
        with ``pymavlink.mavutil``'s process-wide one: that is chosen once, when mavutil is
        first imported, and is MAVLink 1 unless ``MAVLINK20`` was set then, so a program
        that imported mavutil before uavest lost every message id above 255
        (OBSTACLE_DISTANCE_3D) and every extension field (GNSS accuracies)."""
        from pymavlink.dialects.v20 import ardupilotmega as mod

        st = self.stats
        mm = None
        mav = mod.MAVLink(None)
        mav.robust_parsing = True
        try:
            mm, size = _map(self.path)
            if mm is None:
                return
            fr = TlogFramer(mm, mod)
            decode_frame = FrameDecoder(mod, mav)
            names = {mid: cls.msgname for mid, cls in mod.mavlink_map.items()}
            decode = set(names) if self._decode_all else {
                mid for mid, nm in names.items() if nm in TLOG_DECODED}
            o, last_rx = 0, None
            while o < size:
                o, verdict, end, mid, skipped = fr.next(o, last_rx)
                if skipped:
                    self._count_skipped(skipped)
                self.bytes_read = min(end, size) if verdict != "eof" else size
                if verdict == "eof":
                    break
                rx = fr.rx(o)
                frame = o
                o = end
                self._good_end = end
                if verdict == "unknown":
                    st.bad("unknown_message")
                    continue
                last_rx = rx
                if mid not in decode:
                    fm = mm[frame + 8]
                    sysid = mm[frame + 13] if fm == 0xFD else mm[frame + 11]
                    st.messages[names[mid]] += 1
                    self.undecoded += 1
                    yield Skipped(names[mid], sysid, rx), rx
                    continue
                try:
                    msg = decode_frame(mm, frame + 8, end, mid)
                except Exception:  # noqa: BLE001 - the framer checked it; never crash
                    st.bad("corrupt")
                    self._count_skipped({"bad_frame": 1})
                    continue
                msg._timestamp = rx
                st.messages[msg.get_type()] += 1
                yield msg, rx
        finally:
            if mm is not None:
                mm.close()

    def _count_skipped(self, skipped: dict[str, int]) -> None:
        """Count what the framer stepped over: text as ``non_mavlink`` (one per run: not
        bad data), junk ``corrupt`` in frames' worth, a cut last record ``truncated``, bad
        frames ``corrupt`` one each; every kind also in ``stats.skipped``."""
        st = self.stats
        for k, v in skipped.items():
            st.skipped[k] += v
        if skipped.get("text_bytes"):
            st.non_mavlink += 1
        st.bad("corrupt", n=skipped.get("bad_crc", 0) + skipped.get("partial_frame", 0))
        st.bad("unknown_message", n=skipped.get("unknown_id", 0))
        st.bad("corrupt", "skipped_bytes", -(-skipped.get("junk_bytes", 0) // 271))
        if skipped.get("truncated_bytes"):
            st.bad("truncated")

    def _read(self) -> Iterator[tuple[object, float | None]]:
        """The records of the log as ``(message, receive time or None)``: a tlog's from
        :meth:`_read_tlog`, a DataFlash log's from :meth:`_read_records` (the file checked
        for a cut last record and closed at the end, also when the reading stops early)."""
        if self.format == "tlog":
            yield from self._read_tlog()
            return
        conn = self._open()
        try:
            yield from self._read_records(conn)
        finally:
            self._check_truncated(conn)
            with contextlib.suppress(Exception):
                conn.close()

    def _read_records(self, conn) -> Iterator[tuple[object, float | None]]:
        """The records of the DataFlash log ``conn`` (binary or text; a tlog is read by
        :meth:`_read_tlog`) one by one, without receive times: good records of unused types
        stepped over undecoded (:meth:`_skipper`), the others decoded by pymavlink
        (:meth:`_recv`), BAD_DATA and unknown types counted (:meth:`_bad_record`); stops
        at the end of the file or after :data:`_MAX_STALL` reads without progress
        (``corrupt``)."""
        st = self.stats
        stall = 0
        last_pos = -1
        skip = self._skipper(conn)
        while True:
            if skip is not None:
                rec = skip.next(conn, last_pos)
                if rec is not None:  # a good record of an unused type, not decoded
                    pos = conn.offset
                    self.bytes_read = pos
                    stall, last_pos = 0, pos
                    st.messages[rec.name] += 1
                    self.undecoded += 1
                    self._good_end = pos
                    yield rec, rec.rx
                    continue
            msg = self._recv(conn)
            pos = self._position(conn)
            self.bytes_read = pos
            if pos == last_pos:
                stall += 1
                if stall > _MAX_STALL:
                    st.bad("corrupt")
                    break
            else:
                stall, last_pos = 0, pos
            if msg is None:
                if not self._at_eof(conn):
                    continue
                break
            if self._bad_record(msg):
                continue
            st.messages[msg.get_type()] += 1
            self._good_end = pos
            yield msg, None

    def _recv(self, conn):
        """The next message from pymavlink's DataFlash reader, or None: an exception on
        corrupt bytes counted ``corrupt``, what the reader printed counted
        (:func:`_chatter`)."""
        buf = io.StringIO()
        try:
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                msg = conn.recv_msg()
        except Exception:  # noqa: BLE001 - corrupt bytes must not crash us
            self.stats.bad("corrupt")
            msg = None
        if buf.tell():
            _chatter(buf.getvalue(), self.stats, str(self.path))
        return msg

    def _bad_record(self, msg) -> bool:
        """Whether ``msg`` is pymavlink's BAD_DATA (counted ``corrupt``, or
        ``unknown_message`` for an unknown type) or an UNKNOWN_* (``unknown_message``)."""
        name = msg.get_type()
        if name == "BAD_DATA":
            reason = str(getattr(msg, "reason", ""))
            self.stats.bad("unknown_message" if "unknown" in reason.lower() else "corrupt")
            return True
        if name.startswith("UNKNOWN"):
            self.stats.bad("unknown_message")
            return True
        return False

    @staticmethod
    def _position(conn) -> int:
        if hasattr(conn, "offset"):
            return int(conn.offset)
        with contextlib.suppress(Exception):
            return int(conn.f.tell())
        return 0

    def _at_eof(self, conn) -> bool:
        size = getattr(conn, "data_len", None)
        if size is None:
            try:
                size = os.fstat(conn.f.fileno()).st_size
            except Exception:  # noqa: BLE001
                return True
        return self._position(conn) >= size

    def _check_truncated(self, conn) -> None:
        """Count ``truncated`` when the DataFlash reader stopped before the end of the file
        or a few bytes after the last good record are left (a cut inside it)."""
        left = getattr(conn, "data_len", 0) - getattr(conn, "offset", 0)
        if left <= 0:
            # a cut inside the last record: a few bytes after the end of the last good one
            # that the reader skipped silently (less than one record, so not 'corrupt')
            with contextlib.suppress(Exception):
                size = os.path.getsize(self.path)
                tail = size - getattr(self, "_good_end", size)
                if 0 < tail < 512 and self.stats.corrupt == 0:
                    left = tail
        if left > 0:
            self.stats.bad("truncated")

    # ----------------------------------------------------------------- main loop
    def __iter__(self) -> Iterator[Sample]:
        """One message's path: a live link event (:meth:`_link_event`) or a message that is
        converted and checked (:meth:`_convert`), timed (:meth:`_assign_time`: a receiver's
        UNIX time or the vehicle clock), gated and buffered (:meth:`_Pass.finish`) and
        released in order (``_Reorder.pop_ready``); the clocks' held items at the end."""
        st = self.stats
        run = _Pass(st, StreamGate(st), _Reorder(self.reorder_window, st))
        reorder = self._reorder = run.reorder
        arrival = reorder.on_arrival
        burst_rx: float | None = None  # receive time of the burst being read (on arrival)
        for msg, rx in self._messages():
            if msg is None:  # live: a link event (rx holds it)
                yield from self._link_event(reorder, rx)
                continue
            if arrival and rx != burst_rx:  # a new burst: the one before is complete
                yield from reorder.pop_ready(flush=True)
                burst_rx = rx
            if rx is not None and self.params.date is None:  # the log's own date
                self.params.set_date(rx, "tlog's receive times")
            converted = self._convert(msg, run)
            if converted is None:
                continue
            sysid, good = converted
            items = self._assign_time(msg, sysid, good, rx, run)
            if items is None:
                continue
            run.finish(items)
            yield from reorder.pop_ready(flush=arrival and rx is None)
        for clock in run.clocks.values():
            run.finish(clock.flush())
            run.drain(clock)
        yield from reorder.pop_ready(flush=True)

    @staticmethod
    def _link_event(reorder: _Reorder, event) -> Iterator[Sample]:
        """A live link's mark: :data:`BURST_END` completes the burst being read (released
        on arrival); a :class:`~uavest.ingest.types.LinkEvent` (or None) flushes what is
        buffered first, then the event goes out timed at the newest sample released."""
        if event is BURST_END:
            yield from reorder.pop_ready(flush=reorder.on_arrival)
            return
        yield from reorder.pop_ready(flush=True)
        if event is not None:
            t_ev = reorder.last_out if math.isfinite(reorder.last_out) else 0.0
            yield dataclasses.replace(event, t=t_ev)

    def _convert(self, msg, run: _Pass) -> tuple[int, list[Raw]] | None:
        """``(sysid, the message's good converted items)``, or None when nothing of it goes
        on: a record no converter uses, a parameter (into ``params``), another system's
        message (``wrong_sysid``), SYSTEM_TIME (the UNIX offset of its system), a message
        with no good item. Records the first dated GPS fix (``params.geo``)."""
        is_df = self.format.startswith("dataflash")
        if type(msg) is Skipped:  # a record no converter uses: only its system counts
            if self.sysid is not None and not is_df and msg.sysid != self.sysid:
                self.stats.bad("wrong_sysid", msg.name)
            return None
        name = msg.get_type()
        if name in ("GPS", "GPS_RAW_INT") and self.params.geo is None:
            _gps_geo(msg, self.params, run.systime.get(0 if is_df else msg.get_srcSystem()))
        if is_df:
            if name == "PARM":
                self._param(getattr(msg, "Name", None), getattr(msg, "Value", None))
                return None
            raws = convert_dataflash(msg)
            sysid = 0
        else:
            if name == "PARAM_VALUE":
                self._param(getattr(msg, "param_id", None), getattr(msg, "param_value", None))
                return None
            sysid = int(msg.get_srcSystem())
            if self.sysid is not None and sysid != self.sysid:
                self.stats.bad("wrong_sysid", name)
                return None
            if name == "SYSTEM_TIME" and msg.time_boot_ms and msg.time_unix_usec:
                run.systime[sysid] = msg.time_unix_usec * 1e-6 - msg.time_boot_ms * 1e-3
                return None
            raws = convert_mavlink(msg)
        if not raws:
            return None
        good = self._checked(raws, run.fitted)
        return (sysid, good) if good else None

    def _checked(self, raws: list[Raw], fitted: set[str]) -> list[Raw]:
        """The items of the chosen IMU (``imu``; every other kind) that pass
        :func:`~uavest.ingest.convert.check`; the others counted by why: a sensor that is
        not fitted (all zeros from an instance never seen otherwise: ``absent``), a
        magnetometer that never sent a field in range (``unusable``), no GNSS
        fix yet (``no_fix``), or bad data of the kind ``check`` names. ``fitted`` gathers
        the sensor instances that sent a good record."""
        st = self.stats
        if self.imu is not None:
            raws = [r for r in raws if r.cat != "imu" or r.source == self.imu]
        good = []
        for r in raws:
            bad = check(r)
            if bad is None:
                good.append(r)
                if r.cat in _SENSOR_CATS:
                    fitted.add(stat_key(r))
            elif (bad == "empty" and r.cat in _SENSOR_CATS and stat_key(r) not in fitted
                  and (r.cat != "gnss" or _all_zero_gnss(r))):
                # all zeros from an instance that never sent anything else: a sensor
                # that is not fitted, not bad data (one info line at the end)
                st.absent_sensor += 1
                st.absent[stat_key(r)] += 1
            elif bad == "out_of_range" and r.cat == "mag" and stat_key(r) not in fitted:
                # a field out of range from an instance never in range: a unit the
                # sender gets wrong (the ArduCopter SITL's HIGHRES_IMU, 10^6 too large),
                # not bad data; the record's IMU part is used (one info line at the end)
                st.unusable_sensor += 1
                st.unusable[stat_key(r)] += 1
            elif r.cat == "pos" and not r.primary:
                pass  # GPS_RAW_INT's position: counted once, as its GNSS item
            elif bad == "empty" and r.cat in ("pos", "gnss"):
                st.no_fix += 1  # no GNSS fix yet (lat/lon 0): not bad data
            else:
                st.bad(bad, stat_key(r))
        return good

    def _assign_time(self, msg, sysid: int, good: list[Raw], rx: float | None,
                     run: _Pass) -> list | None:
        """The ``(t, (sysid, items))`` of the message that its system's vehicle clock lets
        through now (``t`` s, vehicle clock), or None without a time (``no_time``).

        A receiver's UNIX time (ArduPilot's GPS_RAW_INT; ``time_usec`` 0 from a GNSS
        message: a fix without GNSS time yet) goes onto the vehicle clock without moving
        it (:func:`~uavest.ingest.timebase.retime_unix`, counted ``retimed``, never
        ``late``); a message without a time field by its receive time (``map_rx``); any
        other through the clock (``push``: resets, wraps and faults, which it may hold
        back or reject: rejections are counted here)."""
        clock = run.clocks.get(sysid)
        if clock is None:
            clock = run.clocks[sysid] = VehicleClock(self.stats)
        name = msg.get_type()
        tu = getattr(msg, "time_usec", None)
        gnss_no_time = tu == 0 and name in _GNSS_MESSAGES
        if tu is not None and (tu >= UNIX_US_MIN or gnss_no_time) and name not in _UNTIMED:
            t = retime_unix(tu * 1e-6, rx, clock, None if gnss_no_time else
                            run.systime.get(sysid), run.reorder.floor)
            if t is not None:
                self.stats.retimed += 1
        else:
            raw_t = self._vehicle_time(msg, clock)
            if raw_t is not None:
                accepted = clock.push(raw_t, rx, (sysid, good))
                run.drain(clock)
                return accepted
            t = clock.map_rx(rx)
        if t is None:
            self.stats.bad("no_time", stat_key(good[0]))
            return None
        return [(t, (sysid, good))]

    def prescan_geo(self, max_messages: int = 100_000) -> None:
        """Find the first GPS fix with its date before the replay (``params.geo``): a
        DataFlash log records its boot parameters (``COMPASS_DEC`` 0 with auto-declination)
        long before the GPS lock. Reads at most ``max_messages`` messages; counts nothing."""
        systime: dict[int, float] = {}

        def visit(msg, rx) -> bool:
            if rx is not None and self.params.date is None:
                self.params.set_date(rx, "tlog's receive times")
            name = msg.get_type()
            if name == "SYSTEM_TIME" and msg.time_boot_ms and msg.time_unix_usec:
                systime[msg.get_srcSystem()] = (msg.time_unix_usec * 1e-6
                                                - msg.time_boot_ms * 1e-3)
            elif name in ("GPS", "GPS_RAW_INT"):
                sysid = 0 if self.format.startswith("dataflash") else msg.get_srcSystem()
                _gps_geo(msg, self.params, systime.get(sysid))
            return self.params.geo is not None

        self._prescan(visit, max_messages)

    def prescan_params(self, names: Iterable[str], max_messages: int) -> None:
        """Read the parameters ``names`` from the start of the log into ``params`` before
        the replay (a live session's tlog holds the vehicle's answers to the parameters the
        run asked for at its start: :mod:`uavest.link.spec`), up to ``max_messages``
        messages or until all are found; counts nothing."""
        want = set(names) - set(self.params)

        def visit(msg, rx) -> bool:
            name = msg.get_type()
            if name in ("PARAM_VALUE", "PARM"):
                pid, value = ((msg.param_id, msg.param_value) if name == "PARAM_VALUE"
                              else (getattr(msg, "Name", None), getattr(msg, "Value", None)))
                if (pid := param_name(pid)) in want:
                    self._param(pid, value)
                    want.discard(pid)
            return not want

        if want:
            self._prescan(visit, max_messages)

    def _prescan(self, visit: Callable[[Any, float | None], bool], max_messages: int) -> None:
        """``visit(msg, receive time)`` each message from the start until it returns True
        or ``max_messages`` were read; the reader's counts are left as they were, and a
        damaged log only ends the pre-scan."""
        keep, keep_undecoded = self.stats, self.undecoded
        self.stats = IngestStats()
        try:
            for i, (msg, rx) in enumerate(self._read()):
                if msg is None or i >= max_messages or visit(msg, rx):
                    break
        except Exception:  # noqa: BLE001 - a pre-scan never fails the replay
            pass
        finally:
            self.stats, self.undecoded = keep, keep_undecoded

    def _param(self, name, value) -> None:
        name = param_name(name)
        if not name or value is None:
            return
        try:
            v = float(value)
        except (TypeError, ValueError):
            return
        if np.isfinite(v):
            self.params[name] = v

    @staticmethod
    def _vehicle_time(msg, clock: VehicleClock) -> float | None:
        """Raw vehicle time (s since boot) of a message, or None if it has none."""
        if msg.get_type() in _UNTIMED:
            return None
        v = getattr(msg, "TimeUS", None)
        if v is not None:
            return v * 1e-6
        v = getattr(msg, "time_usec", None)
        if v is not None:  # boot time (UNIX time was retimed before: timebase.retime_unix)
            return v * 1e-6
        v = getattr(msg, "time_boot_ms", None)
        if v is None:
            v = getattr(msg, "TimeMS", None)
        if v is not None:
            return clock.unwrap_ms32(v * 1e-3)
        return None
