"""Unit and frame conversions from log records to SI measurements.

Pure functions, no I/O.  Each ``convert_*`` returns a list of :class:`Raw`
items (values in SI, explicit frames) still without a vehicle-clock time;
the sources attach the time, check plausibility and build the dataclasses.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass

import numpy as np

from ..geometry.rotation import G0, euler_to_quat_f, quat_canonical

MG_TO_MS2 = G0 * 1e-3  # milli-g -> m/s^2
MRAD_TO_RAD = 1e-3  # milli-rad/s -> rad/s
MGAUSS_TO_GAUSS = 1e-3  # milli-gauss -> gauss
DEG = math.pi / 180.0

# Plausibility limits (see docs/ingest.md)
MAX_GYRO = 35.0  # rad/s (|w|, ~2000 deg/s)
MAX_ACCEL = 32.0 * G0  # m/s^2 (|a|, 32 g)
MAX_MAG = 10.0  # gauss (|B|; Earth ~0.25..0.65)
QUAT_NORM_TOL = 1e-3 + 1e-6  # |norm(q) - 1| tolerance (float32 precision included)
MAX_POS = 1e7  # m, |NED|
MAX_VEL = 1e3  # m/s, |v|


@dataclass(slots=True)
class Raw:
    """A converted value waiting for a timestamp.

    cat: "imu" | "mag" | "ref" | "pos" | "gnss" | "baro" | "det" | "adsb".  values: tuple
    of arrays (imu: gyro, accel; mag: field; ref: q; pos: ned, vel_ned, lat_lon_alt, each
    may be None; gnss: lat_lon_alt, vel_ned (NaN where absent), :func:`gnss_acc` vector,
    with ``meta["fix_type"]``; baro: ``[pressure Pa, temperature C, alt m]``).
    """

    cat: str
    source: str
    instance: int
    values: tuple
    kind: str = ""  # reference kind for cat == "ref"
    primary: bool = True  # False for the mag part of an IMU message (time faults counted once)
    meta: dict | None = None  # extra fields of "det" / "adsb" items (not compared by the gate)


def stat_key(raw: Raw) -> str:
    """Name under which an item is counted in IngestStats (mag of an IMU message: '<src>.mag')."""
    if raw.cat == "mag" and not raw.source.startswith("MAG"):
        return raw.source + ".mag"
    return raw.source


def normalize_quat(q) -> np.ndarray:
    """Normalise (and make w >= 0); caller must have checked the norm is close to 1."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return quat_canonical(q / n)


# --------------------------------------------------------------------------- checks


_F64 = np.dtype(np.float64)


def _floats(v: object, n: int) -> tuple[float, ...] | None:
    """The components of a float64 array (n,) as Python floats, else None (other types
    take the reference: a float32 norm rounds at the limits as float32)."""
    if type(v) is np.ndarray and v.shape == (n,) and v.dtype == _F64:
        return tuple(v.tolist())
    return None


def _check_vectors(cat: str, vs: list[tuple[float, ...]]) -> str | None:
    """:func:`check` of an IMU or magnetometer item from its 3-vectors' components ``vs``
    (:func:`_floats`), on Python floats (numpy's reductions on 3-vectors were a third of
    the check, the check a quarter of decoding a log). The same kinds in the same order as
    :func:`check_any`: ``nan``, ``empty``, ``out_of_range``. (The norms first: all finite
    means every component is (a NaN or infinite one makes its norm NaN or infinite), and a
    norm is 0 exactly when every component is; a norm that overflowed is out of range.)"""
    hs = [math.hypot(*v) for v in vs]
    if all(math.isfinite(h) for h in hs):
        if not any(hs):
            return "empty"
        lim = (MAX_GYRO, MAX_ACCEL) if cat == "imu" else (MAX_MAG,)
        return "out_of_range" if any(h > m for h, m in zip(hs, lim, strict=True)) else None
    # a NaN or infinite component, or finite components whose norm overflowed
    return "out_of_range" if all(math.isfinite(c) for v in vs for c in v) else "nan"


def _check_quat(q: tuple[float, ...]) -> str | None:
    """:func:`check` of an attitude reference's quaternion from its components ``q``
    (:func:`_floats`), on Python floats (the same kinds as :func:`check_any`)."""
    if not all(math.isfinite(c) for c in q):
        return "nan"
    if abs(math.sqrt(sum(c * c for c in q)) - 1.0) > QUAT_NORM_TOL:
        return "out_of_range"
    return None


def check(raw: Raw) -> str | None:
    """Return the bad-data kind for a converted item, or None if it is plausible. Float64
    vectors take the float checks, everything else the numpy reference, :func:`check_any`."""
    if raw.cat == "imu" or raw.cat == "mag":
        vs = [f for v in raw.values if (f := _floats(v, 3)) is not None]
        if len(vs) == len(raw.values):
            return _check_vectors(raw.cat, vs)
    elif raw.cat == "ref" and len(raw.values) == 1:
        q = _floats(raw.values[0], 4)
        if q is not None:
            return _check_quat(q)
    elif raw.cat == "pos" and len(raw.values) == 3:
        fs = [None if v is None else _floats(v, 3) for v in raw.values]
        if all(f is not None or v is None for f, v in zip(fs, raw.values, strict=True)):
            return _check_pos(*fs)
    return check_any(raw)


def _check_pos(ned: tuple[float, ...] | None, vel: tuple[float, ...] | None,
               lla: tuple[float, ...] | None) -> str | None:
    """:func:`check` of a position item (a simulator's truth at the IMU's rate, the
    autopilot's fused position) from its vectors' components (:func:`_floats`; None when
    absent), on Python floats: the same kinds in the same order as :func:`check_any`."""
    present = [v for v in (ned, vel, lla) if v is not None]
    if not all(math.isfinite(c) for v in present for c in v):
        return "nan"
    if ned is not None and math.hypot(*ned) > MAX_POS:
        return "out_of_range"
    if vel is not None and math.hypot(*vel) > MAX_VEL:
        return "out_of_range"
    return None if lla is None else _lla_kind(lla)


def _lla_kind(lla) -> str | None:
    """The lat/lon/alt part (deg, deg, m) of a position item's check: out of range, or
    0/0 (no fix: ``empty``)."""
    if abs(lla[0]) > 90 or abs(lla[1]) > 180 or abs(lla[2]) > 1e5:
        return "out_of_range"
    if lla[0] == 0 and lla[1] == 0:
        return "empty"
    return None


def check_any(raw: Raw) -> str | None:
    """:func:`check` in numpy for every kind of item (the reference of its fast path)."""
    if raw.cat == "gnss":
        return check_gnss(raw)
    if raw.cat == "baro":
        return check_baro(raw)
    vals = [v for v in raw.values if v is not None]
    for v in vals:
        if not np.all(np.isfinite(v)):
            return "nan"
    if raw.cat == "imu":
        gyro, accel = raw.values
        if not (np.any(gyro) or np.any(accel)):
            return "empty"
        if np.linalg.norm(gyro) > MAX_GYRO or np.linalg.norm(accel) > MAX_ACCEL:
            return "out_of_range"
    elif raw.cat == "mag":
        (f,) = raw.values
        if not np.any(f):
            return "empty"
        if np.linalg.norm(f) > MAX_MAG:
            return "out_of_range"
    elif raw.cat == "ref":
        (q,) = raw.values
        if abs(np.linalg.norm(q) - 1.0) > QUAT_NORM_TOL:
            return "out_of_range"
    elif raw.cat == "det":
        return check_detection(raw)
    elif raw.cat == "adsb":
        lla, vel = raw.values
        if not (raw.meta or {}).get("valid_coords", True):
            return "empty"
        if abs(lla[0]) > 90 or abs(lla[1]) > 180 or not -1e3 < lla[2] < 1e5:
            return "out_of_range"
        if vel is not None and np.linalg.norm(vel) > MAX_VEL:
            return "out_of_range"
    elif raw.cat == "pos":
        ned, vel, lla = raw.values
        if ned is not None and np.linalg.norm(ned) > MAX_POS:
            return "out_of_range"
        if vel is not None and np.linalg.norm(vel) > MAX_VEL:
            return "out_of_range"
        if lla is not None:
            return _lla_kind(lla)
    return None


MIN_PRESSURE, MAX_PRESSURE = 1.0e3, 1.2e5  # Pa, plausible absolute pressure (~31 km..-1.5 km)
MIN_FIX = 2  # GPS_FIX_TYPE below which a GNSS record carries no position (0 no GPS, 1 no fix)


def check_gnss(raw: Raw) -> str | None:
    """Bad-data kind of a GNSS item, or None: ``nan`` for a non-finite lat/lon/alt,
    ``empty`` (counted ``no_fix``, or ``absent_sensor`` for an instance that never had a
    fix) when fix_type < :data:`MIN_FIX` or lat = lon = 0, ``out_of_range`` for an
    impossible position or a speed above :data:`MAX_VEL`. NaN velocity components and
    accuracies are allowed (the message lacks them)."""
    lla, vel, _acc = raw.values
    meta = raw.meta or {}
    if int(meta.get("fix_type", 0)) < MIN_FIX:
        return "empty"
    if not (np.all(np.isfinite(lla[:2])) and (math.isfinite(lla[2]) or meta.get("no_alt"))):
        return "nan"
    if lla[0] == 0 and lla[1] == 0:
        return "empty"
    if abs(lla[0]) > 90 or abs(lla[1]) > 180 or abs(lla[2]) > 1e5:
        return "out_of_range"
    v = vel[np.isfinite(vel)]
    if v.size and np.linalg.norm(v) > MAX_VEL:
        return "out_of_range"
    return None


def check_baro(raw: Raw) -> str | None:
    """Bad-data kind of a barometer item ``(pressure Pa, temperature C, alt m)``, or None:
    ``empty`` for a zero pressure (an unfitted sensor), ``nan``, ``out_of_range`` outside
    [:data:`MIN_PRESSURE`, :data:`MAX_PRESSURE`]."""
    (v,) = raw.values
    p = float(v[0])
    if p == 0.0:
        return "empty"
    if not math.isfinite(p):
        return "nan"
    if not MIN_PRESSURE <= p <= MAX_PRESSURE:
        return "out_of_range"
    return None


MAX_DETECTION_RANGE = 1e6  # m, |xyz| of an OBSTACLE_DISTANCE_3D beyond which it is nonsense
_RANGE_TOL = 1e-3  # m, slack on min/max_distance (float32 fields)


def check_detection(raw: Raw) -> str | None:
    """Bad-data kind of a converted OBSTACLE_DISTANCE_3D item, or None.

    ``unknown_frame`` for a frame this layer cannot interpret, ``nan`` for a non-finite
    x/y/z/min/max, ``out_of_range`` when min/max are negative or min > max, or the
    distance of a vehicle-centred detection is outside [min_distance, max_distance].
    """
    (xyz,) = raw.values
    meta = raw.meta or {}
    if meta.get("frame") is None:
        return "unknown_frame"
    lo, hi = meta.get("min_distance", 0.0), meta.get("max_distance", math.inf)
    if not (np.all(np.isfinite(xyz)) and math.isfinite(lo) and math.isfinite(hi)):
        return "nan"
    if lo < 0 or hi <= 0 or lo > hi:
        return "out_of_range"
    d = float(np.linalg.norm(xyz))
    if d > MAX_DETECTION_RANGE:
        return "out_of_range"
    if meta["frame"] != "LOCAL_NED" and not (lo - _RANGE_TOL <= d <= hi + _RANGE_TOL):
        return "out_of_range"
    return None


def _euler_ok(roll: float, pitch: float, yaw: float) -> bool:
    e = 1e-3
    return (
        abs(roll) <= math.pi + e and abs(pitch) <= math.pi / 2 + e and abs(yaw) <= 2 * math.pi + e
    )


def _ref_from_euler(source: str, kind: str, roll: float, pitch: float, yaw: float) -> Raw:
    """An attitude reference from ZYX Euler angles (rad), on Python floats (numpy's
    per-call cost made this a sixth of decoding a log with ATTITUDE, AHRS2 and SIMSTATE)."""
    r, p, y = float(roll), float(pitch), float(yaw)
    if not (math.isfinite(r) and math.isfinite(p) and math.isfinite(y)):
        return Raw("ref", source, 0, (np.full(4, np.nan),), kind)
    if not _euler_ok(r, p, y):
        # encode as a deliberately non-unit quaternion so check() flags out_of_range
        return Raw("ref", source, 0, (np.zeros(4),), kind)
    return Raw("ref", source, 0, (np.array(euler_to_quat_f(r, p, y)),), kind)


def _ref_from_quat(source: str, kind: str, w, x, y, z) -> Raw:
    """An attitude reference from a quaternion (w, x, y, z; body FRD -> NED): normalised
    with w >= 0 when it is finite and of norm within :data:`QUAT_NORM_TOL` of 1 (else as
    it came, for :func:`check`). On Python floats: :func:`normalize_quat`'s numbers (the
    squares summed in order, each component divided by the norm, the sign flipped after),
    without numpy's per-call cost (a tenth of reading a log with a simulator's truth)."""
    c = (float(w), float(x), float(y), float(z))
    if all(math.isfinite(v) for v in c):
        n = math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + c[3] * c[3])
        if abs(n - 1.0) <= QUAT_NORM_TOL:
            c = tuple(v / n for v in c)
            if c[0] < 0.0:
                c = tuple(-v for v in c)
    return Raw("ref", source, 0, (np.array(c),), kind)


# --------------------------------------------------------------------------- MAVLink


def _instance_field(m) -> int:
    """The MAVLink2 extension field ``id`` (IMU instance), 0 if absent.

    Careful: every pymavlink message object also has a class attribute ``id``
    (the message id, e.g. 27 for RAW_IMU), so ``getattr(m, "id")`` is wrong.
    """
    if "id" in m.get_fieldnames():
        return int(m.__dict__.get("id", 0) or 0)
    return 0


_MILLI_IMU = {"RAW_IMU": 0, "SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}


def count_middle(n: float) -> float:
    """The middle of the interval an integer count ``n`` of a truncated field stands for:
    ``n + 0.5`` above zero, ``n - 0.5`` below, 0 for 0 (which stands for (-1, 1)).

    ArduPilot's ``GCS_MAVLINK::send_raw_imu`` / ``send_scaled_imu`` and PX4's SCALED_IMU
    stream pass float milli-units to the int16 fields, a C conversion that truncates
    towards zero: a reading of n (n > 0) is a value in [n, n + 1). Read as n, every
    non-zero reading is half a unit short of its value on average, towards zero: on an
    ArduCopter SITL's RAW_IMU (mrad/s) a rate error of 0.5 mrad/s whose sign follows the
    rate's, which a gyro bias state cannot absorb (docs/ingest.md). A NaN stays NaN."""
    return n + 0.5 if n > 0.0 else n - 0.5 if n < 0.0 else n


def _milli_imu(m, name: str) -> list[Raw]:
    # ArduPilot fills RAW_IMU with the same calibrated, scaled units as SCALED_IMU
    # (milli-g, milli-rad/s, milli-gauss), truncated towards zero (each count read as the
    # middle of its unit, :func:`count_middle`); see docs/ingest.md.
    # (on Python floats, the same products as numpy's: a third of decoding a tlog was
    # numpy's per-call cost on these 3-vectors)
    inst = _MILLI_IMU[name]
    if name == "RAW_IMU":
        inst = _instance_field(m)
    g, a, c = MRAD_TO_RAD, MG_TO_MS2, count_middle
    gyro = np.array([c(float(m.xgyro)) * g, c(float(m.ygyro)) * g, c(float(m.zgyro)) * g])
    accel = np.array([c(float(m.xacc)) * a, c(float(m.yacc)) * a, c(float(m.zacc)) * a])
    out = [Raw("imu", name, inst, (gyro, accel))]
    mx, my, mz = float(m.xmag), float(m.ymag), float(m.zmag)
    if mx or my or mz:  # (a NaN is true: counted as bad by check)
        k = MGAUSS_TO_GAUSS
        out.append(Raw("mag", name, inst, (np.array([c(mx) * k, c(my) * k, c(mz) * k]),),
                       primary=False))
    return out


def _highres_imu(m, name: str) -> list[Raw]:
    inst = _instance_field(m)
    upd = int(getattr(m, "fields_updated", 0) or 0)
    gyro = np.array([m.xgyro, m.ygyro, m.zgyro], dtype=float)
    accel = np.array([m.xacc, m.yacc, m.zacc], dtype=float)
    mag = np.array([m.xmag, m.ymag, m.zmag], dtype=float)
    out = []
    if upd == 0 or upd & 0x3F:
        out.append(Raw("imu", name, inst, (gyro, accel)))
    if upd == 0 or upd & 0x1C0:
        if np.any(mag) or not np.all(np.isfinite(mag)):
            out.append(Raw("mag", name, inst, (mag,), primary=bool(not out)))
    return out


def _attitude(m, name: str) -> list[Raw]:
    return [_ref_from_euler(name, "autopilot", m.roll, m.pitch, m.yaw)]


def _attitude_q(m, name: str) -> list[Raw]:
    return [_ref_from_quat(name, "autopilot", m.q1, m.q2, m.q3, m.q4)]


def _simstate(m, name: str) -> list[Raw]:
    return [_ref_from_euler(name, "truth", m.roll, m.pitch, m.yaw)]


def _sim_state(m, name: str) -> list[Raw]:
    """SIM_STATE (a simulator's truth, ArduPilot SITL): the attitude quaternion q1..q4
    (body FRD -> NED) and the position (lat_int/lon_int degE7 when the MAVLink 2
    extension is there, else the float lat/lon, which ArduPilot fills in degE7 and the
    message definition in deg; alt m AMSL) and velocity (vn, ve, vd m/s NED), both
    truth."""
    lat_i, lon_i = getattr(m, "lat_int", 0) or 0, getattr(m, "lon_int", 0) or 0
    if lat_i or lon_i:
        lat, lon = lat_i * 1e-7, lon_i * 1e-7
    else:
        lat, lon = float(m.lat), float(m.lon)
        if abs(lat) > 90.0 or abs(lon) > 180.0:  # degE7 in a float field
            lat, lon = lat * 1e-7, lon * 1e-7
    lla = np.array([lat, lon, float(m.alt)])
    vel = np.array([m.vn, m.ve, m.vd], dtype=float)
    return _truth_state(name, (m.q1, m.q2, m.q3, m.q4), lla, vel)


def _truth_state(name: str, q, lla: np.ndarray, vel: np.ndarray) -> list[Raw]:
    """A simulator's true state: its attitude ``q`` (w, x, y, z; body FRD -> NED) as a
    truth reference, its position ``lla`` (deg, deg, m) and NED velocity ``vel`` (m/s) as
    a position reference (never a measurement)."""
    return [_ref_from_quat(name, "truth", *q), Raw("pos", name, 0, (None, vel, lla),
                                                   primary=False)]


def _hil_state_q(m, name: str) -> list[Raw]:
    """HIL_STATE_QUATERNION (a simulator's true state: PX4 SITL streams its ground truth
    so, uavest's simulator too): the attitude quaternion (body FRD -> NED), the position
    (lat/lon degE7, alt mm AMSL) and the NED velocity (vx, vy, vz cm/s), all truth."""
    lla = np.array([m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3])
    vel = np.array([m.vx, m.vy, m.vz], dtype=float) * 1e-2
    return _truth_state(name, [float(v) for v in m.attitude_quaternion], lla, vel)


def _ahrs2(m, name: str) -> list[Raw]:
    return [_ref_from_euler(name, "ahrs2", m.roll, m.pitch, m.yaw)]


def _global_pos(m, name: str) -> list[Raw]:
    lla = np.array([m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3])
    vel = np.array([m.vx, m.vy, m.vz], dtype=float) * 1e-2
    return [Raw("pos", name, 0, (None, vel, lla))]


def _local_pos(m, name: str) -> list[Raw]:
    ned = np.array([m.x, m.y, m.z], dtype=float)
    vel = np.array([m.vx, m.vy, m.vz], dtype=float)
    return [Raw("pos", name, 0, (ned, vel, None))]


def _gps_raw(m, name: str) -> list[Raw]:
    # the raw fix as a GNSS measurement (primary) and, as before, a position (3-D fixes)
    out = _gnss_raw_int(m, name)
    # GPS_RAW_INT carries no vertical velocity: vel_ned stays None (use GLOBAL_POSITION_INT)
    if int(m.fix_type) < 3:  # no 3D fix
        out.append(Raw("pos", name, 0, (None, None, np.zeros(3)), primary=False))
        return out
    lla = np.array([m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3])
    out.append(Raw("pos", name, 0, (None, None, lla), primary=False))
    return out


_U16_UNKNOWN = 65535  # eph/epv/vel/cog "unknown"
_SATS_UNKNOWN = 255


def _opt(m, field: str, scale: float, unknown: float | None = None) -> float:
    """Optional MAVLink field (an extension may be absent) times ``scale``; NaN when absent,
    zero (MAVLink's "not reported" for h_acc/v_acc/vel_acc) or ``unknown``."""
    v = getattr(m, field, None)
    if v is None or v == 0 or (unknown is not None and v == unknown):
        return math.nan
    return float(v) * scale


def gnss_acc(h_acc=math.nan, v_acc=math.nan, s_acc=math.nan, hdop=math.nan, vdop=math.nan,
             sats=-1) -> np.ndarray:
    """The accuracy vector of a GNSS item: [h_acc m, v_acc m, s_acc m/s, hdop, vdop, sats]."""
    return np.array([h_acc, v_acc, s_acc, hdop, vdop, sats], dtype=float)


def _gnss_raw_int(m, name: str) -> list[Raw]:
    """GPS_RAW_INT / GPS2_RAW: lat/lon degE7, alt mm AMSL, vel cm/s (truncated: read as
    the middle of its centimetre) and cog cdeg (ground
    speed and course: NED north/east, vertical NaN), eph/epv HDOP/VDOP x100, h_acc/v_acc
    mm, vel_acc mm/s (MAVLink 2 extensions; absent or 0 = unknown -> NaN)."""
    inst = 1 if name == "GPS2_RAW" else 0
    lla = np.array([m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3], dtype=float)
    vel = np.full(3, np.nan)
    if m.vel != _U16_UNKNOWN and m.cog != _U16_UNKNOWN:
        # ArduPilot and PX4 truncate the ground speed to whole cm/s (a float cast to
        # uint16): a speed of n cm/s is one in [n, n + 1), n + 0.5 on average (an
        # ArduCopter SITL: 0.005 m/s under its true speed, which a navigation filter
        # trusting the velocity integrates into an along-track position error)
        spd = count_middle(float(m.vel)) * 1e-2
        crs = m.cog * 1e-2 * DEG
        vel[:2] = spd * math.cos(crs), spd * math.sin(crs)
    sats = int(m.satellites_visible)
    acc = gnss_acc(_opt(m, "h_acc", 1e-3), _opt(m, "v_acc", 1e-3), _opt(m, "vel_acc", 1e-3),
                   _opt(m, "eph", 1e-2, _U16_UNKNOWN), _opt(m, "epv", 1e-2, _U16_UNKNOWN),
                   -1 if sats == _SATS_UNKNOWN else sats)
    return [Raw("gnss", name, inst, (lla, vel, acc), meta={"fix_type": int(m.fix_type)})]


# GPS_INPUT_IGNORE_FLAGS
_GI_ALT, _GI_HDOP, _GI_VDOP, _GI_VH, _GI_VV, _GI_SACC, _GI_HACC, _GI_VACC = (
    1, 2, 4, 8, 16, 32, 64, 128)


def _gps_input(m, name: str) -> list[Raw]:
    """GPS_INPUT (a companion computer's receiver): lat/lon degE7, alt m, vn/ve/vd m/s,
    hdop/vdop, speed/horiz/vert accuracy m(/s); fields flagged in ignore_flags -> NaN."""
    ign = int(m.ignore_flags)
    inst = int(m.gps_id)

    def f(v, flag):
        return math.nan if ign & flag else float(v)

    lla = np.array([m.lat * 1e-7, m.lon * 1e-7, f(m.alt, _GI_ALT)], dtype=float)
    vel = np.array([f(m.vn, _GI_VH), f(m.ve, _GI_VH), f(m.vd, _GI_VV)])
    sats = int(m.satellites_visible)
    acc = gnss_acc(f(m.horiz_accuracy, _GI_HACC), f(m.vert_accuracy, _GI_VACC),
                   f(m.speed_accuracy, _GI_SACC), f(m.hdop, _GI_HDOP), f(m.vdop, _GI_VDOP),
                   -1 if sats == _SATS_UNKNOWN else sats)
    src = name if inst == 0 else f"{name}[{inst}]"
    meta = {"fix_type": int(m.fix_type), "no_alt": bool(ign & _GI_ALT)}
    return [Raw("gnss", src, inst, (lla, vel, acc), meta=meta)]


_PRESSURE_INST = {"SCALED_PRESSURE": 0, "SCALED_PRESSURE2": 1, "SCALED_PRESSURE3": 2}


def _scaled_pressure(m, name: str) -> list[Raw]:
    """SCALED_PRESSURE/2/3: press_abs hPa -> Pa, temperature cdegC -> degC; no altitude."""
    v = np.array([float(m.press_abs) * 100.0, float(m.temperature) * 1e-2, math.nan])
    return [Raw("baro", name, _PRESSURE_INST[name], (v,))]


#: MAV_FRAME value -> frame name of a DetectionSample (others: ``unknown_frame``).
DETECTION_FRAMES = {
    12: "BODY_FRD",  # MAV_FRAME_BODY_FRD
    9: "BODY_FRD",  # MAV_FRAME_BODY_OFFSET_NED (deprecated; "same as MAV_FRAME_BODY_FRD")
    8: "BODY_NED",  # MAV_FRAME_BODY_NED: vehicle-carried NED
    7: "BODY_NED",  # MAV_FRAME_LOCAL_OFFSET_NED: offset from the vehicle, NED axes
    1: "LOCAL_NED",  # MAV_FRAME_LOCAL_NED: autopilot local origin
}


def _obstacle_3d(m, name: str) -> list[Raw]:
    xyz = np.array([m.x, m.y, m.z], dtype=float)
    meta = {
        "frame": DETECTION_FRAMES.get(int(m.frame)),
        "mav_frame": int(m.frame),
        "obstacle_id": int(m.obstacle_id),
        "min_distance": float(m.min_distance),
        "max_distance": float(m.max_distance),
        "sensor_type": int(m.sensor_type),
    }
    return [Raw("det", name, int(m.obstacle_id), (xyz,), meta=meta)]


_ADSB_COORDS, _ADSB_ALT, _ADSB_HDG, _ADSB_VEL, _ADSB_CALL = 1, 2, 4, 8, 16
_ADSB_VVEL = 0x100  # ADSB_FLAGS_VERTICAL_VELOCITY_VALID


def _adsb(m, name: str) -> list[Raw]:
    flags = int(m.flags)
    lla = np.array([m.lat * 1e-7, m.lon * 1e-7, m.altitude * 1e-3], dtype=float)
    vel = None
    if flags & _ADSB_VEL and flags & _ADSB_HDG:
        h, hd = m.hor_velocity * 1e-2, m.heading * 1e-2 * DEG
        vz = -m.ver_velocity * 1e-2  # ver_velocity is positive up
        vel = np.array([h * math.cos(hd), h * math.sin(hd), vz])
    cs = m.callsign
    if isinstance(cs, bytes):
        cs = cs.decode("ascii", "replace")
    meta = {
        "icao": int(m.ICAO_address),
        "altitude_type": "geometric" if int(m.altitude_type) == 1 else "pressure_qnh",
        "callsign": str(cs).rstrip("\x00").strip(),
        "flags": flags,
        "tslc": float(m.tslc),
        "squawk": int(m.squawk),
        "emitter_type": int(m.emitter_type),
        "valid_coords": bool(flags & _ADSB_COORDS),
    }
    return [Raw("adsb", name, int(m.ICAO_address), (lla, vel), meta=meta)]


MAVLINK_CONVERTERS = {
    "RAW_IMU": _milli_imu,
    "SCALED_IMU": _milli_imu,
    "SCALED_IMU2": _milli_imu,
    "SCALED_IMU3": _milli_imu,
    "HIGHRES_IMU": _highres_imu,
    "ATTITUDE": _attitude,
    "ATTITUDE_QUATERNION": _attitude_q,
    "SIMSTATE": _simstate,
    "SIM_STATE": _sim_state,
    "HIL_STATE_QUATERNION": _hil_state_q,
    "AHRS2": _ahrs2,
    "GLOBAL_POSITION_INT": _global_pos,
    "LOCAL_POSITION_NED": _local_pos,
    "GPS_RAW_INT": _gps_raw,
    "GPS2_RAW": _gnss_raw_int,
    "GPS_INPUT": _gps_input,
    "SCALED_PRESSURE": _scaled_pressure,
    "SCALED_PRESSURE2": _scaled_pressure,
    "SCALED_PRESSURE3": _scaled_pressure,
    "OBSTACLE_DISTANCE_3D": _obstacle_3d,
    "ADSB_VEHICLE": _adsb,
}


def convert_mavlink(msg) -> list[Raw]:
    """Convert one pymavlink MAVLink message to SI items (empty list if not used)."""
    name = msg.get_type()
    f = MAVLINK_CONVERTERS.get(name)
    return f(msg, name) if f is not None else []


# --------------------------------------------------------------------------- DataFlash

_SUFFIX = re.compile(r"^([A-Z]+?)(\d)$")


def _df_instance(m, name: str, base: str) -> int:
    i = getattr(m, "I", None)
    if i is not None:
        return int(i)
    mo = _SUFFIX.match(name)
    if mo and mo.group(1) == base:
        return int(mo.group(2)) - 1
    return 0


def _df_imu(m, name: str) -> list[Raw]:
    inst = _df_instance(m, name, "IMU")
    gyro = np.array([m.GyrX, m.GyrY, m.GyrZ], dtype=float)
    accel = np.array([m.AccX, m.AccY, m.AccZ], dtype=float)
    return [Raw("imu", f"IMU[{inst}]", inst, (gyro, accel))]


def _df_mag(m, name: str) -> list[Raw]:
    inst = _df_instance(m, name, "MAG")
    # MagX.. are the calibrated field (offsets already applied) in milligauss.
    fld = np.array([m.MagX, m.MagY, m.MagZ], dtype=float) * MGAUSS_TO_GAUSS
    return [Raw("mag", f"MAG[{inst}]", inst, (fld,))]


def _df_euler_deg(m, name: str, kind: str) -> Raw:
    yaw = float(m.Yaw)
    if yaw > 180.0:
        yaw -= 360.0
    return _ref_from_euler(name, kind, float(m.Roll) * DEG, float(m.Pitch) * DEG, yaw * DEG)


def _df_att(m, name: str) -> list[Raw]:
    return [_df_euler_deg(m, name, "autopilot")]


def _df_quat_or_euler(m, name: str, kind: str) -> list[Raw]:
    if all(hasattr(m, k) for k in ("Q1", "Q2", "Q3", "Q4")):
        return [_ref_from_quat(name, kind, m.Q1, m.Q2, m.Q3, m.Q4)]
    return [_df_euler_deg(m, name, kind)]


def _df_ahr2(m, name: str) -> list[Raw]:
    return _df_quat_or_euler(m, name, "ahrs2")


def _df_sim(m, name: str) -> list[Raw]:
    return _df_quat_or_euler(m, name, "truth")


def _df_pos(m, name: str) -> list[Raw]:
    lla = np.array([m.Lat, m.Lng, m.Alt], dtype=float)
    return [Raw("pos", name, 0, (None, None, lla))]


def _df_gps(m, name: str) -> list[Raw]:
    if int(getattr(m, "Status", 3)) < 3:  # no 3D fix
        return [Raw("pos", name, 0, (None, None, np.zeros(3)))]
    lla = np.array([m.Lat, m.Lng, m.Alt], dtype=float)
    spd, crs = float(m.Spd), float(m.GCrs) * DEG
    vel = np.array([spd * math.cos(crs), spd * math.sin(crs), float(m.VZ)])
    return [Raw("pos", name, 0, (None, vel, lla))]


def _df_gnss(m, name: str) -> list[Raw]:
    """DataFlash GPS (Status = GPS_FIX_TYPE, Lat/Lng deg, Alt m AMSL, Spd m/s, GCrs deg,
    VZ m/s down, HDop, NSats) with the accuracies of its GPA record when the reader found
    it (``m._gpa``: VDop, HAcc m, VAcc m, SAcc m/s, VV = vertical velocity valid)."""
    inst = _df_instance(m, name, "GPS")
    lla = np.array([m.Lat, m.Lng, m.Alt], dtype=float)
    spd, crs = float(m.Spd), float(m.GCrs) * DEG
    vel = np.array([spd * math.cos(crs), spd * math.sin(crs), float(m.VZ)])
    gpa = getattr(m, "_gpa", None)
    h_acc = v_acc = s_acc = vdop = math.nan
    if gpa is not None:
        h_acc, v_acc = float(gpa.HAcc), float(gpa.VAcc)
        s_acc, vdop = float(gpa.SAcc), float(gpa.VDop)
        if not int(getattr(gpa, "VV", 1)):
            vel[2] = math.nan
    acc = gnss_acc(h_acc, v_acc, s_acc, float(m.HDop), vdop, int(m.NSats))
    meta = {"fix_type": int(m.Status)}
    return [Raw("gnss", f"GPS[{inst}]", inst, (lla, vel, acc), meta=meta)]


def _df_gps_all(m, name: str) -> list[Raw]:
    """A DataFlash GPS record: its GNSS measurement (primary) and, as before, the
    position of the first receiver (``"GPS"``)."""
    out = _df_gnss(m, name)
    if out[0].instance == 0:
        out += [dataclasses.replace(r, primary=False) for r in _df_gps(m, name)]
    return out


def _df_baro(m, name: str) -> list[Raw]:
    """DataFlash BARO/BAR2/BAR3: Press Pa, Temp deg C, Alt m (relative to its ground zero)."""
    inst = _df_instance(m, name, "BAR")
    v = np.array([float(m.Press), float(m.Temp), float(m.Alt)])
    return [Raw("baro", f"BARO[{inst}]", inst, (v,))]


DATAFLASH_CONVERTERS = {
    "IMU": _df_imu,
    "IMU2": _df_imu,
    "IMU3": _df_imu,
    "MAG": _df_mag,
    "MAG2": _df_mag,
    "MAG3": _df_mag,
    "ATT": _df_att,
    "AHR2": _df_ahr2,
    "SIM": _df_sim,
    "POS": _df_pos,
    "GPS": _df_gps_all,
    "GPS2": _df_gps_all,
    "GPA": lambda m, name: [],  # merged into its GPS record by the reader (GPS._gpa)
    "GPA2": lambda m, name: [],
    "BARO": _df_baro,
    "BAR2": _df_baro,
    "BAR3": _df_baro,
}


def convert_dataflash(msg) -> list[Raw]:
    """Convert one pymavlink DataFlash record to SI items (empty list if not used)."""
    name = msg.get_type()
    f = DATAFLASH_CONVERTERS.get(name)
    if f is None:
        return []
    try:
        return f(msg, name)
    except AttributeError:  # an unexpected column layout for a known name
        return []
