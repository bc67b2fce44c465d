"""Public entry points: :func:`open_source` (streaming) and :func:`read_log` (arrays)."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from .mavlink import MavlinkSource
from .types import (
    AttitudeRef,
    BaroSample,
    BaroSeries,
    GnssSample,
    GnssSeries,
    ImuSample,
    ImuSeries,
    IngestError,
    LogData,
    MagSample,
    MagSeries,
    PositionSample,
    PositionSeries,
    RefSeries,
)
from .ulog import ULOG_MAGIC, ULogData, ULogSource

Source = MavlinkSource | ULogSource

_LIVE_RE = re.compile(r"^(udp|udpin|udpout|udpbcast|tcp|tcpin|serial|mcast|com\d+|/dev/)", re.I)
_DF_MAGIC = b"\xa3\x95\x80"  # DataFlash header + FMT message id 128
_SNIFF = 64 * 1024


def detect_format(path: str | Path) -> str:
    """Format of a log file by content: "ulog" | "dataflash" | "dataflash-text" | "tlog".

    Raises :class:`IngestError` if the file is missing, empty or none of these.
    """
    import os
    import stat as st

    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        raise IngestError(f"{p}: no such file (expected a .tlog, .bin or .ulg log)") from None
    except OSError as e:
        raise IngestError(f"{p}: cannot be read ({e.strerror})") from None
    if st.S_ISDIR(mode):
        raise IngestError(f"{p}: is a directory, not a log file (expected a .tlog, .bin or .ulg)")
    if not st.S_ISREG(mode):
        kind = ("a FIFO (named pipe)" if st.S_ISFIFO(mode) else
                "a character device" if st.S_ISCHR(mode) else
                "a block device" if st.S_ISBLK(mode) else
                "a socket" if st.S_ISSOCK(mode) else "not a regular file")
        raise IngestError(f"{p}: is {kind}, not a log file: logs are read from regular "
                          "files (.tlog, .bin, .ulg); live links take a connection string "
                          "such as udpin:0.0.0.0:14550")
    with open(p, "rb") as f:
        head = f.read(_SNIFF)
    if not head:
        raise IngestError(f"{p}: empty file (expected a .tlog, .bin or .ulg log)")
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(_DF_MAGIC):
        return "dataflash"
    if head.startswith(b"FMT,"):
        return "dataflash-text"
    if _looks_like_tlog(head):
        return "tlog"
    ext = p.suffix.lower()
    expected = {".ulg": "a PX4 ULog (magic 'ULog')", ".bin": "an ArduPilot DataFlash log"}.get(
        ext, "a MAVLink telemetry log (.tlog: 8-byte timestamp + MAVLink frame records)"
    )
    raise IngestError(f"{p}: not {expected}; no valid header or MAVLink frames in the first 64 KiB")


def _looks_like_tlog(head: bytes) -> bool:
    """True if ``head`` holds at least 3 good tlog records of known message ids, framed as
    the reader frames them (:class:`~uavest.ingest.skip.TlogFramer`: an 8-byte record time,
    then a complete frame with a good CRC), the first with a plausible record time.

    Not a MAVLink stream parse from the first byte: the record times share their high
    bytes for minutes (byte 4 of a UNIX time in us for 16.8 s, byte 3 for 71.6 min), and
    when one of those is a frame marker (0xFD, 0xFE) a stream parser takes every record
    time for a frame start and swallows the real frame behind it. Frames of ids the
    dialect lacks do not count: their CRC cannot be checked (random bytes give them).
    """
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from .skip import TlogFramer

    framer = TlogFramer(head, mavlink)
    o, good, first = 0, 0, None
    while good < 3:
        start, verdict, end, _mid, _skipped = framer.next(o)
        if verdict == "eof":
            return False
        if verdict == "ok":
            good += 1
            first = start if first is None else first
        o = end
    (tus,) = struct.unpack_from(">Q", head, first)
    return 0 <= tus < 2**62


def open_source(
    path_or_url: str | Path,
    *,
    imu: str | None = None,
    reorder_window: float | None = None,
    sysid: int | None = None,
    **live_options,
) -> Source:
    """Open a log file or live MAVLink connection string as a measurement stream.

    Files: ``.tlog`` (MAVLink telemetry), ArduPilot DataFlash ``.bin`` (binary or
    text), PX4 ``.ulg``; the format is detected from the content.  Live links:
    pymavlink connection strings (``udpin:0.0.0.0:14550``, ``tcp:host:5760``,
    ``/dev/ttyACM0``...), format ``"mavlink-live"``.

    The returned source is iterable; it yields :class:`ImuSample` (rad/s, m/s^2,
    body FRD), :class:`MagSample` (gauss, body FRD), :class:`AttitudeRef`
    (quaternion [w,x,y,z] body FRD -> NED), :class:`PositionSample`, the raw
    :class:`GnssSample` / :class:`BaroSample` aiding measurements (docs/ingest.md "Raw
    GNSS and barometer"), detections and ADS-B reports in vehicle-time order (s).
    ``imu`` restricts IMU samples to that source (e.g. ``"RAW_IMU"``, ``"IMU[1]"``); None
    yields every IMU source.
    ``.stats``, ``.params`` (name -> float) and ``.format`` are attributes.
    ``reorder_window`` (s of vehicle time; default 1.0 for files, 0.2 live) and ``sysid``
    (MAVLink: only that system) apply to MAVLink sources.  A live link is a
    :class:`uavest.ingest.live.LiveLink` (started on first iteration); ``live_options`` go
    to it (``streams``, ``signing_key``, ``tlog``, ``gap_timeout``...).  To replay a tlog a
    live link recorded exactly as it ran, pass the link's ``reorder_window`` and ``sysid``.
    """
    s = str(path_or_url)
    if _LIVE_RE.match(s) and not Path(s).is_file():
        from .live import LiveLink

        return LiveLink(s, imu=imu, sysid=sysid,
                        reorder_window=0.2 if reorder_window is None else reorder_window,
                        **live_options)
    if live_options:
        raise TypeError(f"options {sorted(live_options)} apply to live links only")
    fmt = detect_format(s)
    if fmt == "ulog":
        return ULogSource(Path(s), imu=imu)
    return MavlinkSource(Path(s), fmt, imu=imu, sysid=sysid,
                         reorder_window=1.0 if reorder_window is None else reorder_window)


# ---------------------------------------------------------------------- read_log

_IMU_PREF = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "IMU[0]", "sensor_combined")


def choose_source(counts: dict[str, int], slack: int = 0) -> str | None:
    """The IMU (or magnetometer) source to use among ``counts`` (name -> samples): most
    samples wins; within 2 % of the best (and ``slack`` samples more, for short windows
    such as the streaming engine's alignment) the primary sources by preference win.
    None when ``counts`` is empty."""
    if not counts:
        return None
    best = max(counts.values())

    def rank(name: str) -> tuple:
        near = counts[name] >= 0.98 * best - slack
        pref = _IMU_PREF.index(name) if name in _IMU_PREF else len(_IMU_PREF)
        return (not near, pref, -counts[name], name)

    return min(counts, key=rank)


def _sort_dedup(t: np.ndarray, *arrays: np.ndarray):
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.ones(0, bool)
    return (t[keep],) + tuple(a[order][keep] for a in arrays)


def _window(t: np.ndarray, start: float | None, end: float | None) -> np.ndarray:
    k = np.ones(t.shape[0], dtype=bool)
    if start is not None:
        k &= t >= start
    if end is not None:
        k &= t <= end
    return k


def _collect_stream(src: MavlinkSource):
    imu: dict[str, list] = {}
    mag: dict[str, list] = {}
    refs: dict[str, list] = {}
    pos: dict[str, list] = {}
    gnss: dict[str, list] = {}
    baro: dict[str, list] = {}
    for m in src:
        if isinstance(m, ImuSample):
            imu.setdefault(m.source, []).append(m)
        elif isinstance(m, MagSample):
            mag.setdefault(m.source, []).append(m)
        elif isinstance(m, AttitudeRef):
            refs.setdefault(m.source, []).append(m)
        elif isinstance(m, PositionSample):
            pos.setdefault(m.source, []).append(m)
        elif isinstance(m, GnssSample):
            gnss.setdefault(m.source, []).append(m)
        elif isinstance(m, BaroSample):
            baro.setdefault(m.source, []).append(m)
    nan3 = np.full(3, np.nan)
    out_imu = {
        s: (
            np.array([x.t for x in v]),
            np.array([x.gyro for x in v]),
            np.array([x.accel for x in v]),
            v[0].instance,
        )
        for s, v in imu.items()
    }
    out_mag = {
        s: (np.array([x.t for x in v]), np.array([x.field for x in v]), v[0].instance)
        for s, v in mag.items()
    }
    out_refs = {
        s: (np.array([x.t for x in v]), np.array([x.q for x in v]), v[0].kind)
        for s, v in refs.items()
    }
    out_pos = {
        s: (
            np.array([x.t for x in v]),
            np.array([nan3 if x.ned is None else x.ned for x in v]),
            np.array([nan3 if x.vel_ned is None else x.vel_ned for x in v]),
            np.array([nan3 if x.lat_lon_alt is None else x.lat_lon_alt for x in v]),
        )
        for s, v in pos.items()
    }
    return out_imu, out_mag, out_refs, out_pos, gnss_arrays(gnss), baro_arrays(baro)


def gnss_arrays(gnss: dict[str, list]) -> dict[str, dict]:
    """Source -> the :class:`GnssSeries` fields as arrays, from lists of :class:`GnssSample`."""
    out = {}
    for s, v in gnss.items():
        out[s] = {
            "t": np.array([x.t for x in v]),
            "lat_lon_alt": np.array([x.lat_lon_alt for x in v]).reshape(-1, 3),
            "vel_ned": np.array([x.vel_ned for x in v]).reshape(-1, 3),
            "fix_type": np.array([x.fix_type for x in v], dtype=int),
            **{k: np.array([getattr(x, k) for x in v], dtype=float)
               for k in ("h_acc", "v_acc", "s_acc", "hdop", "vdop")},
            "satellites": np.array([x.satellites for x in v], dtype=int),
            "instance": v[0].instance,
        }
    return out


def baro_arrays(baro: dict[str, list]) -> dict[str, dict]:
    """Source -> the :class:`BaroSeries` fields as arrays, from lists of :class:`BaroSample`."""
    return {s: {"t": np.array([x.t for x in v]),
                **{k: np.array([getattr(x, k) for x in v], dtype=float)
                   for k in ("pressure", "temperature", "alt")},
                "instance": v[0].instance} for s, v in baro.items()}


def _series(cls, arrays: dict[str, dict], start, end) -> dict:
    """Time-sorted, de-duplicated, windowed series of ``cls`` from :func:`gnss_arrays` /
    :func:`baro_arrays`-style dicts."""
    out = {}
    for s, d in arrays.items():
        names = [k for k in d if k not in ("t", "instance")]
        t, *cols = _sort_dedup(d["t"], *(d[k] for k in names))
        k = _window(t, start, end)
        out[s] = cls(t=t[k], **{n: c[k] for n, c in zip(names, cols, strict=True)},
                     source=s, instance=int(d["instance"]))
    return out


def read_log(
    path: str | Path,
    *,
    imu: str | None = None,
    start: float | None = None,
    end: float | None = None,
) -> LogData:
    """Read a whole log into time-sorted, de-duplicated numpy arrays.

    ``imu`` selects an IMU source by name (``"RAW_IMU"``, ``"SCALED_IMU2"``,
    ``"HIGHRES_IMU"``, ``"IMU[1]"``, ``"sensor_combined"``); by default the source
    with the most samples is chosen (near-ties within 2 % go to the primary
    instance).  ``start``/``end`` clip all series to that vehicle-clock window (s,
    same scale as the ``t`` arrays).  Units/frames as in :mod:`uavest.ingest.types`.
    Raises :class:`IngestError` for unreadable files or an unknown ``imu`` name.
    """
    p = Path(path)
    fmt = detect_format(p)
    imu_d, mag_d, ref_d, pos_d, gnss_d, baro_d, stats, params = _read_raw(p, fmt)
    counts = {s: int(v[0].shape[0]) for s, v in imu_d.items()}
    if imu is not None:
        if imu not in imu_d:
            raise IngestError(f"{p}: IMU source {imu!r} not in log (available: {sorted(counts)})")
        chosen = imu
    else:
        chosen = choose_source(counts)
    mag_counts = {s: int(v[0].shape[0]) for s, v in mag_d.items()}
    return LogData(
        path=p,
        format=fmt if fmt != "dataflash-text" else "dataflash",
        imu=_imu_series(imu_d, chosen, start, end),
        mag=_mag_series(mag_d, mag_counts, chosen, start, end),
        references=_ref_series(ref_d, start, end),
        positions=_position_series(pos_d, start, end),
        params=dict(params),
        stats=stats,
        imu_sources=counts,
        mag_sources=mag_counts,
        gnss=_series(GnssSeries, gnss_d, start, end),
        baro=_series(BaroSeries, baro_d, start, end),
    )


def _read_raw(p: Path, fmt: str) -> tuple:
    """The raw per-source arrays of the log ``p`` in format ``fmt``: ``(imu, mag, refs,
    positions, gnss, baro, stats, params)`` as :func:`_collect_stream` gives them (a ULog
    through :class:`ULogData`, the MAVLink formats through :class:`MavlinkSource`)."""
    if fmt == "ulog":
        from .types import IngestStats

        stats = IngestStats()
        d = ULogData(p, stats)
        return d.imu, d.mag, d.refs, d.pos, d.gnss, d.baro, stats, d.params
    src = MavlinkSource(p, fmt)
    imu_d, mag_d, ref_d, pos_d, gnss_d, baro_d = _collect_stream(src)
    return imu_d, mag_d, ref_d, pos_d, gnss_d, baro_d, src.stats, src.params


def _imu_series(imu_d: dict, chosen: str | None, start: float | None,
                end: float | None) -> ImuSeries:
    """The sorted, de-duplicated, windowed series of IMU source ``chosen`` (empty when
    the log has none); ``start``/``end`` in s of the vehicle clock."""
    if chosen is None:
        z3 = np.zeros((0, 3))
        return ImuSeries(np.zeros(0), z3, z3.copy(), "", 0)
    t, g, a, inst = imu_d[chosen]
    t, g, a = _sort_dedup(t, g, a)
    k = _window(t, start, end)
    return ImuSeries(t[k], g[k], a[k], chosen, inst)


def _mag_series(mag_d: dict, mag_counts: dict[str, int], chosen: str | None,
                start: float | None, end: float | None) -> MagSeries | None:
    """The magnetometer series: the IMU's own source ``chosen`` when it has one, else the
    one with most samples (:func:`choose_source`); None without a magnetometer."""
    if not mag_counts:
        return None
    mname = chosen if chosen in mag_counts else choose_source(mag_counts)
    t, f, inst = mag_d[mname]
    t, f = _sort_dedup(t, f)
    k = _window(t, start, end)
    return MagSeries(t[k], f[k], mname, inst)


def _ref_series(ref_d: dict, start: float | None, end: float | None) -> dict[str, RefSeries]:
    """Every attitude reference (truth or autopilot) as a sorted, windowed series."""
    refs = {}
    for s, (t, q, kind) in ref_d.items():
        t, q = _sort_dedup(t, q)
        k = _window(t, start, end)
        refs[s] = RefSeries(t[k], q[k], kind, s)
    return refs


def _position_series(pos_d: dict, start: float | None,
                     end: float | None) -> dict[str, PositionSeries]:
    """Every position/velocity source as a sorted, windowed series."""
    positions = {}
    for s, (t, n, v, lla) in pos_d.items():
        t, n, v, lla = _sort_dedup(t, n, v, lla)
        k = _window(t, start, end)
        positions[s] = PositionSeries(t[k], n[k], v[k], lla[k], s)
    return positions


__all__ = ["open_source", "read_log", "detect_format", "Source"]
