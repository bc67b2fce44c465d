"""PX4 ULog source (pyulog), vectorised."""

from __future__ import annotations

import contextlib
import heapq
import io
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..geometry.rotation import quat_canonical
from .convert import (
    MAX_ACCEL,
    MAX_GYRO,
    MAX_MAG,
    MAX_POS,
    MAX_PRESSURE,
    MAX_VEL,
    MIN_FIX,
    MIN_PRESSURE,
    QUAT_NORM_TOL,
)
from .types import (
    AttitudeRef,
    BaroSample,
    GnssSample,
    ImuSample,
    IngestError,
    IngestStats,
    LogParams,
    MagSample,
    PositionSample,
    Sample,
)

ULOG_MAGIC = b"ULog\x01\x12\x35"
_TOPICS = [
    "sensor_combined",
    "vehicle_magnetometer",
    "sensor_mag",
    "vehicle_attitude",
    "vehicle_attitude_groundtruth",
    "vehicle_local_position",
    "vehicle_global_position",
    "vehicle_gps_position",  # raw GNSS (the selected receiver) + the first dated fix
    "sensor_gps",  # raw GNSS per receiver
    "sensor_baro",  # barometers
]
_REF_TOPICS = {"vehicle_attitude": "autopilot", "vehicle_attitude_groundtruth": "truth"}
_INVALID_REL = 0x7FFFFFFF  # PX4 RELATIVE_TIMESTAMP_INVALID
_VALID_TYPES = set(b"BFIMPQARDLCSO")


def _walk_ok(path: Path) -> tuple[bool, bool]:
    """Walk the ULog record headers: (ends exactly at EOF, saw an invalid record type)."""
    data = path.read_bytes()
    n = len(data)
    pos = 16
    unpack = struct.Struct("<HB").unpack_from
    while pos + 3 <= n:
        size, typ = unpack(data, pos)
        if typ not in _VALID_TYPES:
            return True, True  # corruption; pyulog resyncs on its own
        pos += 3 + size
    return pos == n, False


OUTLIER_MIN_S = 1.0  # s, a time this far from its neighbours' median may be an outlier
OUTLIER_DT = 50.0  # ... and more than this many typical sample intervals away


def time_outliers(t: np.ndarray) -> np.ndarray:
    """Mask of times that are outliers against their neighbours: farther than
    max(:data:`OUTLIER_MIN_S`, :data:`OUTLIER_DT` x the median interval) from the median
    of the 5 samples around them. One or two corrupted stamps in a row are caught; a real
    step of the clock (every later sample moved) is not, since the running median
    follows it."""
    n = t.shape[0]
    if n < 5:
        return np.zeros(n, dtype=bool)
    from numpy.lib.stride_tricks import sliding_window_view

    pad = np.concatenate([t[:1].repeat(2), t, t[-1:].repeat(2)])
    med = np.median(sliding_window_view(pad, 5), axis=1)
    d = np.diff(t)
    d = d[np.isfinite(d) & (d > 0)]
    typ = float(np.median(d)) if d.size else 0.0
    return np.abs(t - med) > max(OUTLIER_MIN_S, OUTLIER_DT * typ)


class ULogData:
    """All measurements of a ULog as numpy arrays (see ``read_log``)."""

    def __init__(self, path: Path, stats: IngestStats) -> None:
        from pyulog import ULog

        self.path = path
        self.stats = stats
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                ul = ULog(str(path), _TOPICS)
        except Exception as e:  # noqa: BLE001 - pyulog raises many kinds on garbage
            raise IngestError(f"{path}: not a readable PX4 ULog file ({e})".splitlines()[0]) from e
        ends_ok, corrupt = _walk_ok(path)
        if not ends_ok:
            stats.bad("truncated")
        if corrupt or getattr(ul, "file_corruption", False):
            stats.bad("corrupt")
        self.params = LogParams()
        for k, v in ul.initial_parameters.items():
            try:
                if np.isfinite(float(v)):
                    self.params[k] = float(v)
            except (TypeError, ValueError):  # an unreadable parameter: the rest is kept
                stats.bad("corrupt", "parameter")
        self.imu: dict[str, tuple] = {}
        self.mag: dict[str, tuple] = {}
        self.refs: dict[str, tuple] = {}
        self.pos: dict[str, tuple] = {}
        self.gnss: dict[str, dict] = {}  # source -> GnssSeries fields (api.gnss_arrays)
        self.baro: dict[str, dict] = {}  # source -> BaroSeries fields
        for d in ul.data_list:
            stats.messages[d.name] += len(d.data["timestamp"])
            try:
                self._topic(d)
            except KeyError:  # unexpected field layout for a known topic
                stats.bad("unknown_message", d.name, len(d.data["timestamp"]))
        # magnetometer preference: vehicle_magnetometer > sensor_combined (old PX4) > sensor_mag
        for pref in ("vehicle_magnetometer", "sensor_combined", "sensor_mag"):
            if any(k.startswith(pref) for k in self.mag):
                self.mag = {k: v for k, v in self.mag.items() if k.startswith(pref)}
                break

    # ------------------------------------------------------------------ helpers
    def _filter(self, src: str, t: np.ndarray, vals: list, bad_rows: dict) -> np.ndarray:
        """Mask of rows to keep; counts nan/out_of_range/duplicate/time_backwards."""
        st = self.stats
        keep = np.ones(t.shape[0], dtype=bool)
        nan = ~np.isfinite(t)
        for v in vals:
            nan |= ~np.all(np.isfinite(v), axis=-1) if v.ndim > 1 else ~np.isfinite(v)
        st.bad("nan", src, int(nan.sum()))
        keep &= ~nan
        for mask in bad_rows.values():
            m = mask & keep
            st.bad("out_of_range", src, int(m.sum()))
            keep &= ~mask
        idx = np.flatnonzero(keep)
        if idx.size:
            tk = t[idx]
            prev_max = np.concatenate([[-np.inf], np.maximum.accumulate(tk)[:-1]])
            bad = tk <= prev_max
            if bad.any():
                eq = bad & (tk == prev_max)
                same = np.zeros_like(bad)
                j = np.flatnonzero(eq)
                for i in j:  # rare: compare content with the previous kept row
                    same[i] = all(np.array_equal(v[idx[i]], v[idx[i - 1]]) for v in vals)
                st.bad("duplicate", src, int(same.sum()))
                st.bad("time_backwards", src, int((bad & ~same).sum()))
                keep[idx[bad]] = False
        st.accepted[src] += int(keep.sum())
        return keep

    def _gps(self, data: dict) -> None:
        with contextlib.suppress(KeyError, TypeError, ValueError):
            fix = _first_fix(data)
            if fix is not None:
                self.params.set_geo(*fix)
            fix = _first_fix(data, dated=False)  # a fix without GNSS time: still a place
            if fix is not None:
                self.params.set_fix(*fix[:3])

    def _gnss(self, src: str, data: dict, inst: int) -> None:
        """``vehicle_gps_position`` / ``sensor_gps`` rows -> GNSS arrays: lat/lon (degE7
        ``lat``/``lon`` and mm ``alt`` in older PX4, ``latitude_deg``/``altitude_msl_m``
        since v1.14), vel_n/e/d_m_s (NaN where ``vel_ned_valid`` is 0), eph/epv m as
        h_acc/v_acc, s_variance_m_s (m/s: PX4's speed accuracy despite the name) as s_acc,
        hdop/vdop (0 = not reported -> NaN), satellites_used. Rows without a fix
        (fix_type < 2, lat = lon = 0) counted ``no_fix``."""
        n = len(data["timestamp"])
        t = self._time(data, src)
        if "latitude_deg" in data:
            lla = np.stack([np.asarray(data[c], dtype=float) for c in
                            ("latitude_deg", "longitude_deg", "altitude_msl_m")], axis=1)
        else:
            lla = np.stack([np.asarray(data[c], dtype=float) for c in ("lat", "lon", "alt")],
                           axis=1) * np.array([1e-7, 1e-7, 1e-3])
        vel = np.stack([np.asarray(data[f"vel_{c}_m_s"], dtype=float) for c in "ned"], axis=1)
        valid = np.asarray(data.get("vel_ned_valid", np.ones(n)), dtype=bool)
        vel[~valid] = np.nan

        def col(name: str, zero_unknown: bool = True) -> np.ndarray:
            v = np.asarray(data.get(name, np.full(n, np.nan)), dtype=float)
            return np.where(zero_unknown & (v == 0), np.nan, v)

        fix = np.asarray(data["fix_type"], dtype=int)
        nofix = (fix < MIN_FIX) | ((lla[:, 0] == 0) & (lla[:, 1] == 0))
        self.stats.no_fix += int(nofix.sum())
        k0 = ~nofix
        oor = {"l": (np.abs(lla[k0, 0]) > 90) | (np.abs(lla[k0, 1]) > 180)
               | (np.abs(lla[k0, 2]) > 1e5),
               "v": np.linalg.norm(np.nan_to_num(vel[k0]), axis=1) > MAX_VEL}
        k = np.flatnonzero(k0)[self._filter(src, t[k0], [lla[k0]], oor)]
        sats = np.asarray(data.get("satellites_used", np.full(n, -1)), dtype=int)
        self.gnss[src] = {
            "t": t[k], "lat_lon_alt": lla[k], "vel_ned": vel[k], "fix_type": fix[k],
            "h_acc": col("eph")[k], "v_acc": col("epv")[k], "s_acc": col("s_variance_m_s")[k],
            "hdop": col("hdop")[k], "vdop": col("vdop")[k], "satellites": sats[k],
            "instance": inst,
        }

    def _baro(self, src: str, data: dict, inst: int) -> None:
        """``sensor_baro`` rows: pressure Pa, temperature deg C; no altitude (NaN). All-zero
        pressure of an instance counted ``absent_sensor``, a zero among real ones
        ``empty``."""
        t = self._time(data, src)
        p = np.asarray(data["pressure"], dtype=float)
        temp = np.asarray(data.get("temperature", np.full(p.size, np.nan)), dtype=float)
        zero = p == 0
        if zero.all():
            self.stats.absent_sensor += int(p.size)
            self.stats.absent[src] += int(p.size)
            return
        self.stats.bad("empty", src, int(zero.sum()))
        nz = ~zero
        oor = {"p": (p[nz] < MIN_PRESSURE) | (p[nz] > MAX_PRESSURE)}
        k = np.flatnonzero(nz)[self._filter(src, t[nz], [p[nz]], oor)]
        self.baro[src] = {"t": t[k], "pressure": p[k], "temperature": temp[k],
                          "alt": np.full(k.size, np.nan), "instance": inst}

    @staticmethod
    def _vec(data: dict, fmt: str, n: int = 3) -> np.ndarray:
        return np.stack([np.asarray(data[fmt.format(i)], dtype=float) for i in range(n)], axis=1)

    def _time(self, data: dict, src: str = "") -> np.ndarray:
        """Sample time (s): ``timestamp_sample``, where it is set (> 0), else
        ``timestamp`` (SITL ground truth logs ``timestamp_sample = 0``); outliers
        against the neighbours repaired (:meth:`_robust`)."""
        ts = np.asarray(data["timestamp"], dtype=np.int64)
        if "timestamp_sample" in data:
            smp = np.asarray(data["timestamp_sample"], dtype=np.int64)
            ts = np.where(smp > 0, smp, ts)
        return self._robust(ts * 1e-6, src)

    def _robust(self, t: np.ndarray, src: str) -> np.ndarray:
        """``t`` with its outliers (:func:`time_outliers`) repaired: interpolated between
        the good neighbours (the sample's data are intact; only its stamp was bad)."""
        bad = time_outliers(t)
        n = int(bad.sum())
        if n:
            self.stats.bad("time_outlier", src, n)
            t = t.copy()
            good = np.flatnonzero(~bad)
            t[bad] = np.interp(np.flatnonzero(bad), good, t[good])
        return t

    def _topic(self, d) -> None:
        name, data, inst = d.name, d.data, int(d.multi_id)
        src = name if inst == 0 else f"{name}[{inst}]"
        if name == "sensor_combined":
            t_us = np.asarray(data["timestamp"], dtype=np.int64)
            t = self._robust(t_us * 1e-6, src)
            gyro = self._vec(data, "gyro_rad[{}]")
            acc = self._vec(data, "accelerometer_m_s2[{}]")
            oor = {
                "g": np.linalg.norm(gyro, axis=1) > MAX_GYRO,
                "a": np.linalg.norm(acc, axis=1) > MAX_ACCEL,
            }
            k = self._filter(src, t, [gyro, acc], oor)
            self.imu[src] = (t[k], gyro[k], acc[k], inst)
            if "magnetometer_ga[0]" in data:
                rel = np.asarray(data["magnetometer_timestamp_relative"], dtype=np.int64)
                fld = self._vec(data, "magnetometer_ga[{}]")
                valid = rel != _INVALID_REL
                tm_us = t_us + rel  # integer microseconds: exact repeats stay equal
                # sensor_combined repeats the latest mag sample: keep new ones only
                newer = np.concatenate([[True], np.diff(tm_us) != 0]) & valid
                tm, fld = self._robust(tm_us[newer] * 1e-6, src + ".mag"), fld[newer]
                k = self._filter(
                    src + ".mag", tm, [fld], {"m": np.linalg.norm(fld, axis=1) > MAX_MAG}
                )
                self.mag[src] = (tm[k], fld[k], inst)
        elif name in ("vehicle_magnetometer", "sensor_mag"):
            t = self._time(data, src)
            fmt = "magnetometer_ga[{}]" if name == "vehicle_magnetometer" else None
            fld = (
                self._vec(data, fmt)
                if fmt
                else np.stack([np.asarray(data[c], dtype=float) for c in "xyz"], axis=1)
            )
            k = self._filter(src, t, [fld], {"m": np.linalg.norm(fld, axis=1) > MAX_MAG})
            self.mag[src] = (t[k], fld[k], inst)
        elif name in _REF_TOPICS:
            t = self._time(data, src)
            q = self._vec(data, "q[{}]", 4)
            nrm = np.linalg.norm(q, axis=1)
            k = self._filter(src, t, [q], {"q": np.abs(nrm - 1.0) > QUAT_NORM_TOL})
            q = quat_canonical(q[k] / nrm[k, None])
            self.refs[src] = (t[k], q, _REF_TOPICS[name])
        elif name == "vehicle_local_position":
            t = self._time(data, src)
            ned = np.stack([np.asarray(data[c], dtype=float) for c in "xyz"], axis=1)
            vel = np.stack([np.asarray(data[c], dtype=float) for c in ("vx", "vy", "vz")], axis=1)
            oor = {
                "p": np.linalg.norm(ned, axis=1) > MAX_POS,
                "v": np.linalg.norm(vel, axis=1) > MAX_VEL,
            }
            k = self._filter(src, t, [ned, vel], oor)
            self.pos[src] = (t[k], ned[k], vel[k], np.full((int(k.sum()), 3), np.nan))
        elif name in ("vehicle_gps_position", "sensor_gps"):
            if name == "vehicle_gps_position":
                self._gps(data)
            self._gnss(src, data, inst)
        elif name == "sensor_baro":
            self._baro(src, data, inst)
        elif name == "vehicle_global_position":
            t = self._time(data, src)
            lla = np.stack(
                [np.asarray(data[c], dtype=float) for c in ("lat", "lon", "alt")], axis=1
            )
            oor = {"l": (np.abs(lla[:, 0]) > 90) | (np.abs(lla[:, 1]) > 180)}
            k = self._filter(src, t, [lla], oor)
            nan3 = np.full((int(k.sum()), 3), np.nan)
            self.pos[src] = (t[k], nan3, nan3.copy(), lla[k])


def _first_fix(data: dict, dated: bool = True):
    """(lat deg, lon deg, alt m, UNIX s) of the first 3-D fix with a date (``dated``
    False: with or without one; UNIX s then NaN if it has none), or None."""
    fix = np.asarray(data.get("fix_type", []))
    utc = np.asarray(data.get("time_utc_usec", np.full(fix.size, np.nan)), dtype=float)
    if fix.size == 0 or utc.size != fix.size:
        return None
    if "latitude_deg" in data:
        lat, lon = np.asarray(data["latitude_deg"], float), np.asarray(data["longitude_deg"], float)
        alt = np.asarray(data.get("altitude_msl_m", np.zeros(fix.size)), float)
    elif "lat" in data:
        lat, lon = np.asarray(data["lat"], float) * 1e-7, np.asarray(data["lon"], float) * 1e-7
        alt = np.asarray(data.get("alt", np.zeros(fix.size)), float) * 1e-3
    else:
        return None
    dated_ok = (utc > 1e15) if dated else np.ones(fix.size, bool)
    ok = np.flatnonzero((fix >= 3) & dated_ok & np.isfinite(lat) & (np.abs(lat) <= 90))
    if ok.size == 0:
        return None
    i = ok[0]
    return lat[i], lon[i], alt[i], (utc[i] * 1e-6 if utc[i] > 1e15 else np.nan)


class ULogSource:
    """Streaming view of a ULog: yields measurements merged in time order."""

    format = "ulog"

    def __init__(self, path: Path, *, imu: str | None = None) -> None:
        self.path = path
        self.imu = imu
        self.stats = IngestStats()
        self._data = ULogData(path, self.stats)
        self.params = self._data.params

    def __iter__(self) -> Iterator[Sample]:
        d = self._data
        gens = []
        # one generator function per topic: a generator expression would bind the loop
        # variable late and give every topic the last topic's name
        for s, (t, g, a, i) in d.imu.items():
            if self.imu is None or self.imu == s:
                gens.append(_imu_gen(s, t, g, a, i))
        for s, (t, f, i) in d.mag.items():
            gens.append(_mag_gen(s, t, f, i))
        for s, (t, q, kind) in d.refs.items():
            gens.append(_ref_gen(s, t, q, kind))
        for s, (t, n, v, lla) in d.pos.items():
            gens.append(_pos_gen(s, t, n, v, lla))
        for s, g in d.gnss.items():
            gens.append(_gnss_gen(s, g))
        for s, b in d.baro.items():
            gens.append(_baro_gen(s, b))
        yield from heapq.merge(*gens, key=lambda m: m.t)


def _imu_gen(s, t, g, a, i) -> Iterator[ImuSample]:
    for r in zip(t.tolist(), g, a, strict=True):
        yield ImuSample(*r, s, i)


def _mag_gen(s, t, f, i) -> Iterator[MagSample]:
    for r in zip(t.tolist(), f, strict=True):
        yield MagSample(*r, s, i)


def _ref_gen(s, t, q, kind) -> Iterator[AttitudeRef]:
    for tt, qq in zip(t.tolist(), q, strict=True):
        yield AttitudeRef(tt, qq, kind, s)


def _pos_gen(s, t, n, v, lla) -> Iterator[PositionSample]:
    for tt, nn, vv, ll in zip(t.tolist(), n, v, lla, strict=True):
        yield PositionSample(
            tt,
            None if np.isnan(nn[0]) else nn,
            None if np.isnan(vv[0]) else vv,
            None if np.isnan(ll[0]) else ll,
            s,
        )


def _gnss_gen(s: str, g: dict) -> Iterator[GnssSample]:
    for i, tt in enumerate(g["t"].tolist()):
        yield GnssSample(tt, g["lat_lon_alt"][i], g["vel_ned"][i], int(g["fix_type"][i]),
                         float(g["h_acc"][i]), float(g["v_acc"][i]), float(g["s_acc"][i]),
                         float(g["hdop"][i]), float(g["vdop"][i]), int(g["satellites"][i]),
                         s, g["instance"])


def _baro_gen(s: str, b: dict) -> Iterator[BaroSample]:
    for i, tt in enumerate(b["t"].tolist()):
        yield BaroSample(tt, float(b["pressure"][i]), float(b["temperature"][i]),
                         float(b["alt"][i]), s, b["instance"])
