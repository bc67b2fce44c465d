"""Ingest layer: log bytes -> typed, timestamped SI measurements in explicit frames.

Knows nothing about filters.  See ``docs/ingest.md``.

>>> from uavest.ingest import read_log          # doctest: +SKIP
>>> log = read_log("flight.ulg")               # doctest: +SKIP
>>> log.imu.t, log.imu.gyro, log.references["vehicle_attitude"].q   # doctest: +SKIP
"""

import os

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink.mavutil is imported (signing)

from ..geometry.rotation import euler_to_quat  # noqa: E402
from .adsb_radar import AdsbRadar, RadarConfig, virtual_radar  # noqa: E402
from .api import Source, detect_format, open_source, read_log  # noqa: E402
from .detections import attach_pose, group_scans, rae_from_frd, to_sensor_frame  # noqa: E402
from .live import LinkTimeout, LiveLink, open_live  # noqa: E402
from .types import (  # noqa: E402
    BAD_KINDS,
    EVENT_KINDS,
    REF_KINDS,
    AdsbSample,
    AttitudeRef,
    BaroSample,
    BaroSeries,
    DetectionSample,
    DetectionScan,
    GnssSample,
    GnssSeries,
    ImuSample,
    ImuSeries,
    IngestError,
    IngestStats,
    LinkEvent,
    LogData,
    MagSample,
    MagSeries,
    PositionSample,
    PositionSeries,
    RefSeries,
)

__all__ = [
    "open_source",
    "open_live",
    "LiveLink",
    "LinkTimeout",
    "DetectionSample",
    "DetectionScan",
    "AdsbSample",
    "LinkEvent",
    "EVENT_KINDS",
    "attach_pose",
    "group_scans",
    "rae_from_frd",
    "to_sensor_frame",
    "virtual_radar",
    "AdsbRadar",
    "RadarConfig",
    "read_log",
    "detect_format",
    "euler_to_quat",
    "Source",
    "IngestError",
    "ImuSample",
    "MagSample",
    "AttitudeRef",
    "PositionSample",
    "GnssSample",
    "GnssSeries",
    "BaroSample",
    "BaroSeries",
    "IngestStats",
    "ImuSeries",
    "MagSeries",
    "RefSeries",
    "PositionSeries",
    "LogData",
    "BAD_KINDS",
    "REF_KINDS",
]
