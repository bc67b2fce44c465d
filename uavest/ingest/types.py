"""Typed measurements produced by the ingest layer.

Conventions used throughout ``uavest.ingest``:

* time ``t``: seconds on the *vehicle* clock (time since boot of the autopilot,
  made monotonic across 32-bit wraps and reboots, see ``docs/ingest.md``).
* body frame: FRD (x forward, y right, z down).
* navigation frame: NED (x north, y east, z down).
* quaternions: scalar-first ``[w, x, y, z]``, Hamilton convention, rotating
  vectors from body FRD into NED (``v_ned = q * v_body * q^-1``).
* accelerometer: specific force in m/s^2 (level and still reads about (0, 0, -9.81)).
* gyro: rad/s.  magnetometer: gauss (1 gauss = 100 microtesla).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = [
    "IngestError",
    "NoSamplesError",
    "ImuSample",
    "MagSample",
    "AttitudeRef",
    "PositionSample",
    "GnssSample",
    "BaroSample",
    "GnssSeries",
    "BaroSeries",
    "DetectionSample",
    "DetectionScan",
    "AdsbSample",
    "LinkEvent",
    "IngestStats",
    "LogParams",
    "ImuSeries",
    "MagSeries",
    "RefSeries",
    "PositionSeries",
    "LogData",
    "BAD_KINDS",
    "REF_KINDS",
    "Sample",
    "arrival_order",
]


class IngestError(InputError):
    """A file or connection could not be read as any supported log format."""


class NoSamplesError(IngestError):
    """The stream (or the chosen time window) held no usable IMU samples."""


#: Kinds of attitude reference.
REF_KINDS = ("truth", "autopilot", "ahrs2")

#: Kinds of bad data counted (and skipped) by :class:`IngestStats`.
BAD_KINDS = (
    "corrupt",  # bytes that failed framing/CRC, undecodable records
    "truncated",  # file ends in the middle of a record
    "nan",  # NaN / inf in a measured value
    "out_of_range",  # physically implausible value, non-unit quaternion, bad time jump
    "time_backwards",  # vehicle time <= last accepted time of the same stream
    "duplicate",  # same stream, same time, same content
    "unknown_message",  # MAVLink id / DataFlash type not in the dialect
    "empty",  # all-zero sensor payload of a sensor that sent real data
    "no_time",  # no vehicle time could be assigned (no timed message seen yet)
    "late",  # arrived later than the streaming reorder window allows or, processed on
    # arrival, older than the engine's history (uavest.engine.history)
    "unknown_frame",  # OBSTACLE_DISTANCE_3D in a MAV_FRAME this layer cannot interpret
    "wrong_sysid",  # live link: message from another MAVLink system than the vehicle's
    "unsigned",  # live link with signing on: unsigned (or MAVLink 1) packet
    "bad_signature",  # live link with signing on: wrong key, or replayed/old timestamp
    "queue_overflow",  # live link: reader queue full (consumer too slow), message dropped
    "time_outlier",  # one time stamp far from its neighbours' (a corrupted receive or
    # vehicle time): a receive time is repaired (the item kept), a vehicle time dropped
)

#: Events counted by :class:`IngestStats` that are not bad data.
EVENT_KINDS = (
    "time_reset",  # vehicle reboots detected (time continued)
    "time_wrap",  # 32-bit time_boot_ms wraps unwrapped
    "non_mavlink",  # runs of printable text between frames (ArduPilot SITL boot banner)
    "link_gap",  # live link: no message for gap_timeout s (see LinkEvent)
    "reconnect",  # live link: TCP connection re-established
    "pre_heartbeat",  # live link: messages discarded before the vehicle heartbeat
    "absent_sensor",  # all-zero IMU/magnetometer records of an instance that never sent a
    # non-zero one (ArduPilot sends SCALED_IMU3 zeros when there is no third IMU): ignored
    "unusable_sensor",  # magnetometer readings out of range from an instance that never
    # sent one in range (the ArduCopter SITL's HIGHRES_IMU field, 10^6 too large): ignored
    "no_fix",  # GNSS position records without a fix (lat/lon 0, before the lock): skipped
    "retimed",  # records stamped with UNIX time (ArduPilot GPS_RAW_INT) mapped onto the
    # vehicle clock (timebase.retime_unix): kept, not late
)


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU sample.

    t: s, vehicle clock.  gyro: (3,) rad/s, body FRD.  accel: (3,) m/s^2
    specific force, body FRD.  source: message name (``"RAW_IMU"``,
    ``"HIGHRES_IMU"``, ``"SCALED_IMU2"``, ``"IMU[0]"``, ``"sensor_combined"``).
    """

    t: float
    gyro: np.ndarray
    accel: np.ndarray
    source: str
    instance: int = 0


@dataclass(frozen=True, slots=True)
class MagSample:
    """One magnetometer sample: field (3,) in gauss, body FRD, at t (s, vehicle clock)."""

    t: float
    field: np.ndarray
    source: str
    instance: int = 0


@dataclass(frozen=True, slots=True)
class AttitudeRef:
    """An attitude reference (not a measurement the filter should use as input).

    q: (4,) unit quaternion ``[w, x, y, z]``, Hamilton, body FRD -> NED.
    kind: ``"truth"`` (simulator), ``"autopilot"`` (the vehicle's own estimate)
    or ``"ahrs2"`` (secondary AHRS).  source: message name.
    """

    t: float
    q: np.ndarray
    kind: str
    source: str


@dataclass(frozen=True, slots=True)
class PositionSample:
    """Vehicle position/velocity.

    ned: (3,) m relative to the autopilot's local origin, or None.
    vel_ned: (3,) m/s in NED, or None.
    lat_lon_alt: (3,) degrees, degrees, metres above mean sea level, or None.
    """

    t: float
    ned: np.ndarray | None
    vel_ned: np.ndarray | None
    lat_lon_alt: np.ndarray | None
    source: str


@dataclass(frozen=True, slots=True)
class GnssSample:
    """One raw GNSS receiver solution: a measurement, never the autopilot's fused output.

    t: s, vehicle clock of the fix (receivers' own UNIX/GPS time stamps are mapped onto
    the vehicle clock by the reader).  lat_lon_alt: (3,) deg, deg, m above mean sea level.
    vel_ned: (3,) m/s NED, NaN where the message lacks a component (GPS_RAW_INT has ground
    speed and course but no vertical speed).  fix_type: MAVLink GPS_FIX_TYPE (0 no GPS,
    1 no fix, 2 2-D, 3 3-D, 4 DGPS, 5 RTK float, 6 RTK fixed).  h_acc, v_acc: m, 1-sigma
    position accuracy the receiver reports (NaN if it reports none); s_acc: m/s, 1-sigma
    speed accuracy (NaN if none).  hdop, vdop: dimensionless (NaN if none).
    satellites: visible satellites (-1 unknown).  source: ``"GPS_RAW_INT"``,
    ``"GPS2_RAW"``, ``"GPS_INPUT"``, ``"GPS[0]"`` (DataFlash), ``"vehicle_gps_position"``,
    ``"sensor_gps"``.
    """

    t: float
    lat_lon_alt: np.ndarray
    vel_ned: np.ndarray
    fix_type: int
    h_acc: float
    v_acc: float
    s_acc: float
    hdop: float
    vdop: float
    satellites: int
    source: str
    instance: int = 0


@dataclass(frozen=True, slots=True)
class BaroSample:
    """One barometer reading.

    t: s, vehicle clock.  pressure: Pa (absolute).  temperature: deg C (NaN if none).
    alt: m, the pressure altitude the autopilot logged with it (DataFlash ``BARO.Alt``,
    ULog ``sensor_baro`` has none: NaN); relative to its own zero, not AMSL.
    source: ``"SCALED_PRESSURE"``, ``"SCALED_PRESSURE2"``, ``"BARO[0]"``, ``"sensor_baro"``.
    """

    t: float
    pressure: float
    temperature: float
    alt: float
    source: str
    instance: int = 0


@dataclass(frozen=True, slots=True)
class DetectionSample:
    """One radar-like detection (MAVLink ``OBSTACLE_DISTANCE_3D`` or the ADS-B virtual radar).

    t: s, vehicle clock.  obstacle_id: the sensor's id (65535 = unknown).
    xyz: (3,) m, the position as sent, in ``frame``.  frame: ``"BODY_FRD"`` (vehicle
    centred, body axes), ``"BODY_NED"`` (vehicle centred, NED axes) or ``"LOCAL_NED"``
    (autopilot local origin, NED axes).
    rae: (3,) ``[range m, azimuth rad, elevation rad]`` in the sensor frame, with the
    conventions of :mod:`uavest.models.radar` for a sensor whose axes are the body FRD
    axes (:meth:`SensorPose.from_ned_frd`): with ``d`` the line of sight in body FRD,
    ``range = |d|``, ``azimuth = atan2(-d_y, d_x)`` (counter-clockwise from the nose seen
    from above, i.e. *positive to the left*; :attr:`azimuth_frd` is the clockwise one),
    ``elevation = atan2(-d_z, hypot(d_x, d_y))`` (positive up).  None when the frame is
    world-fixed and no attitude/position has been attached yet
    (:func:`uavest.ingest.detections.attach_pose`).
    q: (4,) sensor attitude ``[w,x,y,z]`` body FRD -> NED used for ``rae``, or None.
    sensor_ned: (3,) m, sensor position in the local NED frame used, or None (unknown).
    min_distance, max_distance: m, the sensor's range limits from the message.
    source: ``"OBSTACLE_DISTANCE_3D"`` or ``"adsb_radar"``.  sensor_type: MAV_DISTANCE_SENSOR.
    """

    t: float
    obstacle_id: int
    xyz: np.ndarray
    frame: str
    rae: np.ndarray | None
    min_distance: float
    max_distance: float
    source: str
    sensor_type: int = 3  # MAV_DISTANCE_SENSOR_RADAR
    q: np.ndarray | None = None
    sensor_ned: np.ndarray | None = None

    @property
    def azimuth_frd(self) -> float:
        """Azimuth clockwise from the nose (rad, positive right) = ``-rae[1]``; NaN if no rae."""
        return float("nan") if self.rae is None else float(-self.rae[1])


@dataclass(frozen=True, slots=True)
class DetectionScan:
    """Detections of one scan of one sensor (see ``docs/live.md`` "Scans").

    t: s, vehicle clock of the scan.  detections: the scan's :class:`DetectionSample`
    (possibly empty for the virtual radar, which knows its scans).  origin: for each
    detection the ICAO address of the aircraft that caused it, or None for clutter (only
    the virtual radar knows this; () for MAVLink scans).  truth: ICAO address -> (6,)
    ``[n, e, d, vn, ve, vd]`` m, m/s, in the local NED frame of the stage (virtual radar;
    {} otherwise), every aircraft within range at the scan time, detected or not.
    """

    t: float
    detections: tuple
    source: str
    origin: tuple = ()
    truth: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.detections)


@dataclass(frozen=True, slots=True)
class AdsbSample:
    """One ADS-B report (MAVLink ``ADSB_VEHICLE``).

    t: s, vehicle clock of the *position* (receive time mapped to vehicle time, minus
    ``tslc``).  icao: 24-bit ICAO address.  lat_lon_alt: (3,) deg, deg, m; the altitude
    is AMSL barometric (QNH) or geometric (GNSS) as ``altitude_type`` says
    (``"pressure_qnh"`` | ``"geometric"``).  vel_ned: (3,) m/s NED from
    hor_velocity/heading/ver_velocity, or None when the message flags say they are not
    valid.  callsign: str.  flags: MAV_ADSB_FLAGS bits.  tslc: s since last
    communication (integer seconds in the message).  squawk, emitter_type: as sent.
    """

    t: float
    icao: int
    lat_lon_alt: np.ndarray
    vel_ned: np.ndarray | None
    altitude_type: str
    callsign: str
    flags: int
    tslc: float
    source: str = "ADSB_VEHICLE"
    squawk: int = 0
    emitter_type: int = 0


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """Something that happened to a live link (not data).

    t: s, vehicle clock: the newest sample time yielded before the event.  kind:
    ``"link_lost"`` (no message for ``gap_timeout`` s; ``end`` None), ``"link_restored"``
    (first message after the gap), ``"reconnect"`` (TCP reconnected) or
    ``"streams_requested"``.  start, end: receive (UNIX) times s of the last message
    before and the first after the gap.  count: ordinal of the gap (1, 2...).
    detail: free text.  source: the connection string.
    """

    t: float
    kind: str
    start: float | None = None
    end: float | None = None
    count: int = 0
    detail: str = ""
    source: str = "link"

    @property
    def duration(self) -> float | None:
        """end - start in s, or None while the gap lasts."""
        return None if self.end is None or self.start is None else self.end - self.start


#: One typed, timestamped sample from a source (data, not a measurement *model*).
Sample = (
    ImuSample | MagSample | AttitudeRef | PositionSample | GnssSample | BaroSample
    | DetectionSample | AdsbSample
)


def arrival_order(s: Sample) -> tuple[float, bool]:
    """Sort key of samples released on arrival (a live link, :mod:`uavest.engine.history`):
    time (s), then an IMU sample after the other samples of its time, as the link
    releases the items of one message (a step that ends at the IMU sample is then
    complete when it comes). Sorts are stable: arrival breaks the remaining ties."""
    return (s.t, type(s) is ImuSample)


class LogParams(dict):
    """A log's parameters (name -> float), and ``geo``: the first GPS fix with its date,
    ``{"lat": deg, "lon": deg, "alt": m AMSL, "utc": UNIX s}`` or None, ``fix`` (the first
    fix, dated or not) and ``date`` (the log's own date), which the sources fill as they
    read (for the World Magnetic Model declination when the log's own is
    unknown, :func:`uavest.models.attitude.declination_and_source`)."""

    geo: dict | None = None
    #: the first 3-D fix even without a date ``{"lat", "lon", "alt"}`` (deg, deg, m AMSL)
    fix: dict | None = None
    #: the log's own date when its fixes carry none: ``{"utc": UNIX s, "what": where from}``
    date: dict | None = None

    def set_fix(self, lat, lon, alt) -> None:
        """Keep the first plausible 3-D fix, dated or not (later calls are ignored)."""
        import math

        if self.fix is not None:
            return
        try:
            v = [float(lat), float(lon), float(alt)]
        except (TypeError, ValueError):
            return
        if not all(math.isfinite(x) for x in v) or abs(v[0]) > 90 or abs(v[1]) > 180:
            return
        if (v[0], v[1]) != (0.0, 0.0):
            self.fix = {"lat": v[0], "lon": v[1], "alt": v[2]}

    def set_date(self, utc, what: str) -> None:
        """Keep the first plausible date of the log (UNIX s, 2001-2099) and its origin."""
        import math

        try:
            u = float(utc)
        except (TypeError, ValueError):
            return
        if self.date is None and math.isfinite(u) and 1.0e9 < u < 4.1e9:
            self.date = {"utc": u, "what": what}

    def set_geo(self, lat, lon, alt, utc) -> None:
        """Keep the first plausible fix (later calls are ignored)."""
        import math

        self.set_fix(lat, lon, alt)
        if self.geo is not None:
            return
        try:
            v = [float(lat), float(lon), float(alt), float(utc)]
        except (TypeError, ValueError):
            return
        if not all(math.isfinite(x) for x in v) or abs(v[0]) > 90 or abs(v[1]) > 180:
            return
        if (v[0], v[1]) == (0.0, 0.0) or not 1.0e9 < v[3] < 4.1e9:  # no fix, or no date
            return
        self.geo = {"lat": v[0], "lon": v[1], "alt": v[2], "utc": v[3]}


@dataclass(slots=True)
class IngestStats:
    """Counts of bad data per kind (skipped) and of good data per type.

    Every bad-data kind in :data:`BAD_KINDS` is an attribute.  ``messages`` counts
    records per message/topic type (good framing, before validation; tlog and DataFlash
    records of types no converter uses are counted without being decoded);
    ``accepted`` counts measurements yielded per source; ``rejected`` counts
    skipped measurements per ``"<kind>:<source>"``.
    """

    corrupt: int = 0
    truncated: int = 0
    nan: int = 0
    out_of_range: int = 0
    time_backwards: int = 0
    duplicate: int = 0
    unknown_message: int = 0
    empty: int = 0
    no_time: int = 0
    late: int = 0
    unknown_frame: int = 0
    wrong_sysid: int = 0
    unsigned: int = 0
    bad_signature: int = 0
    queue_overflow: int = 0
    time_outlier: int = 0
    time_reset: int = 0  # vehicle reboots detected (not bad data; time continued)
    time_wrap: int = 0  # 32-bit time_boot_ms wraps unwrapped
    non_mavlink: int = 0  # printable text runs between frames (SITL banner), bytes ignored
    link_gap: int = 0  # live link gaps (no message for gap_timeout s)
    reconnect: int = 0  # live TCP reconnections
    pre_heartbeat: int = 0  # live messages discarded before the vehicle heartbeat
    absent_sensor: int = 0  # all-zero records of a sensor instance that is not fitted
    unusable_sensor: int = 0  # out-of-range magnetometer readings of an instance never in range
    no_fix: int = 0  # GNSS position records without a fix (lat/lon 0): skipped, not bad
    retimed: int = 0  # UNIX-time stamped records mapped onto the vehicle clock (kept)
    #: the absent sensor instances (stat key, e.g. ``"imu:SCALED_IMU3"``) -> records ignored
    absent: Counter = field(default_factory=Counter)
    #: the unusable sensor instances (stat key, e.g. ``"HIGHRES_IMU.mag"``) -> readings ignored
    unusable: Counter = field(default_factory=Counter)
    #: what the tlog reader stepped over between good records, by kind
    #: (``uavest.ingest.skip.SKIP_KINDS``: text_bytes, bad_crc, partial_frame, ...)
    skipped: Counter = field(default_factory=Counter)
    messages: Counter = field(default_factory=Counter)
    accepted: Counter = field(default_factory=Counter)
    rejected: Counter = field(default_factory=Counter)

    def bad(self, kind: str, source: str = "", n: int = 1) -> None:
        """Count ``n`` items of bad data of ``kind`` (one of :data:`BAD_KINDS`)."""
        if n <= 0:
            return
        setattr(self, kind, getattr(self, kind) + int(n))
        if source:
            self.rejected[f"{kind}:{source}"] += int(n)

    @property
    def bad_total(self) -> int:
        """Total number of bad items of all kinds."""
        return sum(getattr(self, k) for k in BAD_KINDS)

    def as_dict(self) -> dict:
        """Plain-dict view (JSON-serialisable)."""
        d: dict = {k: getattr(self, k) for k in BAD_KINDS}
        for k in EVENT_KINDS:
            d[k] = getattr(self, k)
        d["bad_total"] = self.bad_total
        d["absent"] = dict(sorted(self.absent.items()))
        d["unusable"] = dict(sorted(self.unusable.items()))
        d["skipped"] = dict(sorted(self.skipped.items()))
        d["messages"] = dict(sorted(self.messages.items()))
        d["accepted"] = dict(sorted(self.accepted.items()))
        d["rejected"] = dict(sorted(self.rejected.items()))
        return d


@dataclass(frozen=True, slots=True)
class ImuSeries:
    """IMU samples of one source: t (N,) s; gyro (N,3) rad/s FRD; accel (N,3) m/s^2 FRD."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    source: str
    instance: int = 0

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True, slots=True)
class MagSeries:
    """Magnetometer samples of one source: t (M,) s; field (M,3) gauss, body FRD."""

    t: np.ndarray
    field: np.ndarray
    source: str
    instance: int = 0

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True, slots=True)
class RefSeries:
    """Attitude reference series: t (K,) s; q (K,4) scalar-first body FRD -> NED."""

    t: np.ndarray
    q: np.ndarray
    kind: str
    source: str

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True, slots=True)
class PositionSeries:
    """Positions of one source; arrays are NaN where the source lacks that quantity.

    t (P,) s; ned (P,3) m; vel_ned (P,3) m/s; lat_lon_alt (P,3) deg, deg, m AMSL.
    """

    t: np.ndarray
    ned: np.ndarray
    vel_ned: np.ndarray
    lat_lon_alt: np.ndarray
    source: str

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True, slots=True)
class GnssSeries:
    """Raw GNSS fixes of one receiver, the fields of :class:`GnssSample` as arrays.

    t (G,) s; lat_lon_alt (G,3) deg, deg, m AMSL; vel_ned (G,3) m/s (NaN where absent);
    fix_type (G,) int; h_acc, v_acc (G,) m; s_acc (G,) m/s; hdop, vdop (G,); satellites
    (G,) int.
    """

    t: np.ndarray
    lat_lon_alt: np.ndarray
    vel_ned: np.ndarray
    fix_type: np.ndarray
    h_acc: np.ndarray
    v_acc: np.ndarray
    s_acc: np.ndarray
    hdop: np.ndarray
    vdop: np.ndarray
    satellites: np.ndarray
    source: str
    instance: int = 0

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True, slots=True)
class BaroSeries:
    """Barometer readings of one sensor: t (B,) s; pressure (B,) Pa; temperature (B,)
    deg C; alt (B,) m pressure altitude as logged (NaN where absent)."""

    t: np.ndarray
    pressure: np.ndarray
    temperature: np.ndarray
    alt: np.ndarray
    source: str
    instance: int = 0

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(slots=True)
class LogData:
    """A whole log as time-sorted, de-duplicated numpy arrays (see :func:`read_log`).

    ``imu`` is the chosen IMU source (``imu.source`` names it); ``imu_sources``
    lists all IMU sources with their sample counts; ``mag`` is the chosen
    magnetometer or None; ``references`` maps source name -> :class:`RefSeries`;
    ``positions`` maps source name -> :class:`PositionSeries`.
    """

    path: Path
    format: str
    imu: ImuSeries
    mag: MagSeries | None
    references: dict[str, RefSeries]
    positions: dict[str, PositionSeries]
    params: dict[str, float]
    stats: IngestStats
    imu_sources: dict[str, int] = field(default_factory=dict)
    mag_sources: dict[str, int] = field(default_factory=dict)
    #: raw GNSS receivers by source name (``"GPS_RAW_INT"``, ``"GPS[0]"``, ...): aiding
    #: measurements for the navigation filter (never the autopilot's fused positions)
    gnss: dict[str, GnssSeries] = field(default_factory=dict)
    #: barometers by source name (``"SCALED_PRESSURE"``, ``"BARO[0]"``, ``"sensor_baro"``)
    baro: dict[str, BaroSeries] = field(default_factory=dict)

    @property
    def duration(self) -> float:
        """Span of the chosen IMU series in seconds (0 if fewer than 2 samples)."""
        if len(self.imu) < 2:
            return 0.0
        return float(self.imu.t[-1] - self.imu.t[0])

    @property
    def imu_rate_hz(self) -> float:
        """Mean IMU sample rate of the chosen source in Hz (0 if undefined)."""
        d = self.duration
        return (len(self.imu) - 1) / d if d > 0 else 0.0
