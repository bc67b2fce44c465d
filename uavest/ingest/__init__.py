"""Ingest layer: log bytes -> typed, timestamped SI measurements in explicit frames.

Knows nothing about filters.  See ``docs/ingest.md``.

>>> from uavest.ingest import read_log          # doctest: +SKIP
>>> log = read_log("flight.ulg")               # doctest: +SKIP
>>> log.imu.t, log.imu.gyro, log.references["vehicle_attitude"].q   # doctest: +SKIP
"""

from ..geometry.rotation import euler_to_quat
from .api import Source, detect_format, open_source, read_log
from .types import (
    BAD_KINDS,
    REF_KINDS,
    AttitudeRef,
    ImuSample,
    ImuSeries,
    IngestError,
    IngestStats,
    LogData,
    MagSample,
    MagSeries,
    PositionSample,
    PositionSeries,
    RefSeries,
)

__all__ = [
    "open_source",
    "read_log",
    "detect_format",
    "euler_to_quat",
    "Source",
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
]
