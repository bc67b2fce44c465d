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

__all__ = [
    "IngestError",
    "ImuSample",
    "MagSample",
    "AttitudeRef",
    "PositionSample",
    "IngestStats",
    "ImuSeries",
    "MagSeries",
    "RefSeries",
    "PositionSeries",
    "LogData",
    "BAD_KINDS",
    "REF_KINDS",
    "Sample",
]


class IngestError(ValueError):
    """A file or connection could not be read as any supported log format."""


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
    "empty",  # all-zero sensor payload (sensor not present) or no GPS fix
    "no_time",  # no vehicle time could be assigned (no timed message seen yet)
    "late",  # arrived later than the streaming reorder window allows
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


#: One typed, timestamped sample from a source (data, not a measurement *model*).
Sample = ImuSample | MagSample | AttitudeRef | PositionSample


@dataclass(slots=True)
class IngestStats:
    """Counts of bad data per kind (skipped) and of good data per type.

    Every bad-data kind in :data:`BAD_KINDS` is an attribute.  ``messages`` counts
    decoded records per message/topic type (good framing, before validation);
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
    time_reset: int = 0  # vehicle reboots detected (not bad data; time continued)
    time_wrap: int = 0  # 32-bit time_boot_ms wraps unwrapped
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
        d["time_reset"] = self.time_reset
        d["time_wrap"] = self.time_wrap
        d["bad_total"] = self.bad_total
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
