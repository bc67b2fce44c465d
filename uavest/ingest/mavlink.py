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
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .convert import Raw, check, convert_dataflash, convert_mavlink, stat_key
from .skip import TLOG_DECODED, DataflashSkipper, Skipped, TlogFramer, _map
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


class _Reorder:
    """Small heap that releases measurements in time order once older than ``window`` s."""

    def __init__(self, window: float, stats: IngestStats) -> None:
        self.window = window
        self.stats = stats
        self.heap: list = []
        self.seq = 0
        self.newest = -math.inf
        self.last_out = -math.inf

    def push(self, m: Sample) -> None:
        if m.t < self.last_out:
            self.stats.bad("late", _source_key(m))
            return
        heapq.heappush(self.heap, (m.t, self.seq, m))
        self.seq += 1
        self.newest = max(self.newest, m.t)

    def pop_ready(self, flush: bool = False) -> Iterator[Sample]:
        limit = math.inf if flush else self.newest - self.window
        while self.heap and self.heap[0][0] <= limit:
            t, _, m = heapq.heappop(self.heap)
            self.last_out = t
            yield m


def _source_key(m) -> str:
    return m.source + (".mag" if isinstance(m, MagSample) else "")


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
        from pymavlink import DFReader, mavutil

        try:
            if self.format == "tlog":
                return mavutil.mavlogfile(str(self.path), robust_parsing=True)
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
        (``stats.skipped``; text as ``non_mavlink``, the rest ``corrupt``/``truncated``)."""
        conn = self._open()
        st = self.stats
        mm = None
        try:
            mav = conn.mav
            mod = sys.modules[type(mav).__module__]
            mm, size = _map(self.path)
            if mm is None:
                return
            fr = TlogFramer(mm, mod)
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
                    msg = mav.decode(bytearray(mm[frame + 8:end]))
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
            with contextlib.suppress(Exception):
                conn.close()

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
        if self.format == "tlog":
            yield from self._read_tlog()
            return
        conn = self._open()
        st = self.stats
        is_df = self.format.startswith("dataflash")
        stall = 0
        last_pos = -1
        skip = None
        try:
            skip = self._skipper(conn)
            while True:
                if skip is not None:
                    rec = skip.next(conn, last_pos)
                    if rec is not None:  # a good record of an unused type, not decoded
                        pos = skip.pos if not is_df else conn.offset
                        self.bytes_read = pos
                        stall, last_pos = 0, pos
                        st.messages[rec.name] += 1
                        self.undecoded += 1
                        self._good_end = pos
                        yield rec, rec.rx
                        continue
                buf = io.StringIO()
                try:
                    if is_df:
                        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                            msg = conn.recv_msg()
                    else:
                        msg = conn.recv_msg()
                except Exception:  # noqa: BLE001 - corrupt bytes must not crash us
                    st.bad("corrupt")
                    msg = None
                    if not is_df and self._at_eof(conn):
                        break
                if is_df and buf.tell():
                    _chatter(buf.getvalue(), st, str(self.path))
                pos = self._position(conn)
                self.bytes_read = pos
                if not is_df and last_pos >= 0 and not (msg is not None
                                                        and msg.get_type() == "BAD_DATA"):
                    # bytes the parser skipped without a frame (random runs) are counted
                    # in frames' worth (271 bytes: the largest tlog record), which pymavlink
                    # itself does not report
                    size = 0
                    if msg is not None:
                        with contextlib.suppress(Exception):
                            size = len(msg.get_msgbuf()) + 8
                    skipped = pos - last_pos - size
                    if skipped > 8:
                        st.bad("corrupt", "skipped_bytes", -(-skipped // 271))
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
                name = msg.get_type()
                if name == "BAD_DATA":
                    reason = str(getattr(msg, "reason", ""))
                    st.bad("unknown_message" if "unknown" in reason.lower() else "corrupt")
                    continue
                if name.startswith("UNKNOWN"):
                    st.bad("unknown_message")
                    continue
                st.messages[name] += 1
                if is_df:
                    rx = None
                else:
                    rx = getattr(msg, "_timestamp", None)
                    if rx is not None and not math.isfinite(rx):
                        rx = None
                self._good_end = pos
                yield msg, rx
        finally:
            self._check_truncated(conn)
            with contextlib.suppress(Exception):
                conn.close()

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
        if self.format.startswith("dataflash"):
            left = getattr(conn, "data_len", 0) - getattr(conn, "offset", 0)
        else:
            mav = getattr(conn, "mav", None)
            left = len(getattr(mav, "buf", b"")) - getattr(mav, "buf_index", 0) if mav else 0
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
        st = self.stats
        is_df = self.format.startswith("dataflash")
        clocks: dict[int, VehicleClock] = {}
        gate = StreamGate(st)
        reorder = _Reorder(self.reorder_window, st)
        systime: dict[int, float] = {}  # sysid -> unix_us - boot_us offset (s)
        fitted: set[str] = set()  # sensor instances that sent a non-zero record

        # clock payloads are (sysid, the converted items of one message): one message is
        # one push, so the IMU and mag parts of a message do not confirm a reset twice
        def finish(items) -> None:
            for t, (sysid, raws) in items:
                for raw in raws:
                    key = (sysid, raw.cat, raw.source, raw.instance)
                    admit = {"det": gate.admit_multi, "adsb": gate.admit_repeat}.get(
                        raw.cat, gate.admit)
                    tg = gate_time(raw, t)
                    if not admit(key, tg, raw.values, stat_key(raw), count=raw.primary):
                        continue
                    st.accepted[stat_key(raw)] += 1
                    reorder.push(build(raw, t))

        def drain(clock: VehicleClock) -> None:
            for kind, (_sysid, raws) in clock.take_rejected():
                for raw in raws:
                    if raw.primary:  # time faults are counted once per message
                        st.bad(kind, stat_key(raw))

        self._reorder = reorder
        for msg, rx in self._messages():
            if msg is None:  # live: a link event (rx holds it); flush what is buffered first
                yield from reorder.pop_ready(flush=True)
                if rx is not None:
                    t_ev = reorder.last_out if math.isfinite(reorder.last_out) else 0.0
                    yield dataclasses.replace(rx, t=t_ev)
                continue
            if rx is not None and self.params.date is None:  # the log's own date
                self.params.set_date(rx, "tlog's receive times")
            if type(msg) is Skipped:  # a record no converter uses: only its system counts
                if self.sysid is not None and not is_df and msg.sysid != self.sysid:
                    st.bad("wrong_sysid", msg.name)
                continue
            name = msg.get_type()
            if name in ("GPS", "GPS_RAW_INT") and self.params.geo is None:
                _gps_geo(msg, self.params, systime.get(0 if is_df else msg.get_srcSystem()))
            if is_df:
                if name == "PARM":
                    self._param(getattr(msg, "Name", None), getattr(msg, "Value", None))
                    continue
                raws = convert_dataflash(msg)
                sysid = 0
            else:
                if name == "PARAM_VALUE":
                    self._param(getattr(msg, "param_id", None), getattr(msg, "param_value", None))
                    continue
                sysid = int(msg.get_srcSystem())
                if self.sysid is not None and sysid != self.sysid:
                    st.bad("wrong_sysid", name)
                    continue
                if name == "SYSTEM_TIME" and msg.time_boot_ms and msg.time_unix_usec:
                    systime[sysid] = msg.time_unix_usec * 1e-6 - msg.time_boot_ms * 1e-3
                    continue
                raws = convert_mavlink(msg)
            if not raws:
                continue
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
                elif r.cat == "pos" and not r.primary:
                    pass  # GPS_RAW_INT's position: counted once, as its GNSS item
                elif bad == "empty" and r.cat in ("pos", "gnss"):
                    st.no_fix += 1  # no GNSS fix yet (lat/lon 0): not bad data
                else:
                    st.bad(bad, stat_key(r))
            if not good:
                continue
            clock = clocks.get(sysid)
            if clock is None:
                clock = clocks[sysid] = VehicleClock(st)
            tu = getattr(msg, "time_usec", None)
            gnss_no_time = tu == 0 and name in _GNSS_MESSAGES
            if tu is not None and (tu >= UNIX_US_MIN or gnss_no_time) and name not in _UNTIMED:
                # a receiver's UNIX time (ArduPilot's GPS_RAW_INT; 0: a fix without GNSS
                # time yet): onto the vehicle clock without moving it
                # (timebase.retime_unix), never "late"
                t = retime_unix(tu * 1e-6, rx, clock, None if gnss_no_time else
                                systime.get(sysid), reorder.last_out)
                if t is None:
                    st.bad("no_time", stat_key(good[0]))
                    continue
                st.retimed += 1
                finish([(t, (sysid, good))])
                yield from reorder.pop_ready()
                continue
            raw_t = self._vehicle_time(msg, clock)
            if raw_t is None:
                t = clock.map_rx(rx)
                if t is None:
                    st.bad("no_time", stat_key(good[0]))
                    continue
                finish([(t, (sysid, good))])
            else:
                accepted = clock.push(raw_t, rx, (sysid, good))
                drain(clock)
                finish(accepted)
            yield from reorder.pop_ready()
        for clock in clocks.values():
            finish(clock.flush())
            drain(clock)
        yield from reorder.pop_ready(flush=True)

    def prescan_geo(self, max_messages: int = 100_000) -> None:
        """Find the first GPS fix with its date before the replay (``params.geo``): a
        DataFlash log records its boot parameters (``COMPASS_DEC`` 0 with auto-declination)
        long before the GPS lock. Reads at most ``max_messages`` messages; counts nothing."""
        keep, keep_undecoded = self.stats, self.undecoded
        self.stats = IngestStats()
        systime: dict[int, float] = {}
        try:
            for i, (msg, rx) in enumerate(self._read()):
                if msg is None or i >= max_messages or self.params.geo is not None:
                    break
                if rx is not None and self.params.date is None:
                    self.params.set_date(rx, "tlog's receive times")
                name = msg.get_type()
                if name == "SYSTEM_TIME" and msg.time_boot_ms and msg.time_unix_usec:
                    systime[msg.get_srcSystem()] = (msg.time_unix_usec * 1e-6
                                                    - msg.time_boot_ms * 1e-3)
                elif name in ("GPS", "GPS_RAW_INT"):
                    sysid = 0 if self.format.startswith("dataflash") else msg.get_srcSystem()
                    _gps_geo(msg, self.params, systime.get(sysid))
        except Exception:  # noqa: BLE001 - a pre-scan never fails the replay
            pass
        finally:
            self.stats, self.undecoded = keep, keep_undecoded

    def _param(self, name, value) -> None:
        if isinstance(name, bytes):
            name = name.decode("ascii", "replace")
        if not name or value is None:
            return
        name = str(name).rstrip("\x00")
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
