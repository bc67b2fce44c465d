"""Radar-like detections: sensor-frame geometry, pose attachment and scan grouping.

Pure functions and streaming stages (generators over a time-ordered sample stream).
Conventions (see ``docs/live.md``): the sensor axes are the vehicle body FRD axes; the
measurement ``rae = [range, azimuth, elevation]`` follows :mod:`uavest.models.radar` for
that sensor (``SensorPose.from_ned_frd``): with ``d`` the line of sight in body FRD,
``azimuth = atan2(-d_y, d_x)`` (counter-clockwise seen from above, positive *left*) and
``elevation = atan2(-d_z, hypot(d_x, d_y))`` (positive up).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator

import numpy as np

from ..geometry.rotation import quat_rotate_inv
from .types import AttitudeRef, DetectionSample, DetectionScan, IngestError, PositionSample

__all__ = ["rae_from_frd", "frd_from_rae", "to_sensor_frame", "attach_pose", "group_scans"]


def rae_from_frd(d: np.ndarray) -> np.ndarray:
    """``[range m, azimuth rad, elevation rad]`` of a body-FRD line of sight ``d`` (3,) m.

    azimuth = atan2(-d_y, d_x) in [-pi, pi] (positive left, the radar model's FLU
    convention); elevation = atan2(-d_z, hypot(d_x, d_y)) (positive up).
    """
    x, y, z = (float(v) for v in d)
    return np.array([math.sqrt(x * x + y * y + z * z), math.atan2(-y, x),
                     math.atan2(-z, math.hypot(x, y))])


def frd_from_rae(rae: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rae_from_frd`: body-FRD vector (3,) m from ``[r, az, el]``."""
    r, az, el = (float(v) for v in rae)
    c = math.cos(el)
    return np.array([r * c * math.cos(az), -r * c * math.sin(az), -r * math.sin(el)])


def to_sensor_frame(
    xyz: np.ndarray, frame: str, q: np.ndarray | None, vehicle_ned: np.ndarray | None = None
) -> np.ndarray:
    """Line of sight (3,) m in the sensor (body FRD) frame of a detection given in ``frame``.

    ``q``: vehicle attitude ``[w,x,y,z]`` rotating body FRD -> NED (needed unless the frame
    is ``BODY_FRD``).  ``vehicle_ned``: vehicle (sensor) position in the autopilot's local
    NED frame, m (needed for ``LOCAL_NED``).  Raises ``ValueError`` if one is missing.
    """
    xyz = np.asarray(xyz, dtype=float)
    if frame == "BODY_FRD":
        return xyz
    if q is None:
        raise IngestError(f"a {frame} detection needs the vehicle attitude q")
    if frame == "BODY_NED":
        return quat_rotate_inv(np.asarray(q, float), xyz)
    if frame == "LOCAL_NED":
        if vehicle_ned is None:
            raise IngestError("a LOCAL_NED detection needs the vehicle local NED position")
        return quat_rotate_inv(np.asarray(q, float), xyz - np.asarray(vehicle_ned, float))
    raise IngestError(f"unknown detection frame {frame!r}")


def attach_pose(
    samples: Iterable,
    *,
    kind: str = "autopilot",
    max_age: float = 0.5,
) -> Iterator:
    """Streaming stage: fill ``rae``, ``q`` and ``sensor_ned`` of detections.

    Keeps the latest :class:`AttitudeRef` of ``kind`` and the latest local-NED
    :class:`PositionSample` (``ned`` not None) seen in the (time-ordered) stream; each
    :class:`DetectionSample` gets them when they are at most ``max_age`` s old (zero-order
    hold, no interpolation).  World-frame detections (BODY_NED, LOCAL_NED) without a recent
    enough pose pass through with ``rae`` None.  Other samples pass through unchanged.
    """
    q = q_t = pos = pos_t = None
    for s in samples:
        if isinstance(s, AttitudeRef) and s.kind == kind:
            q, q_t = s.q, s.t
        elif isinstance(s, PositionSample) and s.ned is not None:
            pos, pos_t = s.ned, s.t
        elif isinstance(s, DetectionSample):
            qq = q if q is not None and s.t - q_t <= max_age else None
            pp = pos if pos is not None and s.t - pos_t <= max_age else None
            rae = s.rae
            if rae is None and qq is not None and (s.frame != "LOCAL_NED" or pp is not None):
                rae = rae_from_frd(to_sensor_frame(s.xyz, s.frame, qq, pp))
            s = dataclasses.replace(s, rae=rae, q=qq if s.q is None else s.q,
                                    sensor_ned=pp if s.sensor_ned is None else s.sensor_ned)
        yield s


def group_scans(samples: Iterable, *, window: float = 0.0) -> Iterator:
    """Streaming stage: group detections into :class:`DetectionScan` objects.

    A scan is the detections of one ``source`` whose times lie within ``window`` s of the
    scan's first detection; with the default ``window=0`` it is exactly the detections
    that share one ``time_boot_ms`` (what a radar driver sending one sweep stamps them
    with).  The input must be time-ordered (as sources yield).  A scan is emitted, in
    stream order, as soon as any sample later than ``scan.t + window`` arrives, and at the
    end of the stream; ``scan.t`` is the time of its first detection.  Non-detection
    samples pass through.  A sweep that saw nothing cannot be told apart from no sweep on
    MAVLink, so no empty scans are produced.
    """
    open_scans: dict[str, list] = {}

    def ready(now: float) -> Iterator[DetectionScan]:
        for src in [k for k, v in open_scans.items() if now > v[0].t + window]:
            dets = open_scans.pop(src)
            yield DetectionScan(dets[0].t, tuple(dets), src)

    for s in samples:
        yield from ready(s.t)
        if isinstance(s, DetectionSample):
            open_scans.setdefault(s.source, []).append(s)
        else:
            yield s
    for src, dets in sorted(open_scans.items(), key=lambda kv: kv[1][0].t):
        yield DetectionScan(dets[0].t, tuple(dets), src)
