"""The channels uavest publishes to Foxglove (MCAP recordings and the live WebSocket view),
and the one place that turns samples and records into their messages.

:class:`Publisher` owns a ``foxglove.Context``; the MCAP sink opens a writer on it, the
live sink a WebSocket server, so both carry exactly the same channels and messages. See
``docs/recording.md`` for the channel list.

Frames. Our data are NED (navigation) / FRD (body); Foxglove's 3-D panel is ENU / FLU
(x east, y north, z up; body x forward, y left, z up). Attitudes are converted as::

    q_enu_flu = q_ned2enu * q_ned_frd * q_frd2flu

with ``q_ned2enu`` = 180 deg about (1, 1, 0)/sqrt(2) = [0, 1/sqrt2, 1/sqrt2, 0] (swaps x
and y, flips z) and ``q_frd2flu`` = 180 deg about x = [0, 1, 0, 0] (flips y and z); see
:func:`ned_frd_to_enu_flu`. Positions: ENU = (east, north, -down). Radar scenarios are
already ENU (world) and are published unchanged. The root frame is ``world`` (ENU).

Times. ``log_time`` of every message is the data time ``t`` (s, the source's clock: vehicle
time since boot for logs) in nanoseconds; JSON messages also carry ``t`` in seconds.

JSON channels have a JSON schema with a ``title`` (``uavest.*``); NaN is written as null.
"""

from __future__ import annotations

import base64
import json
import math
import re
import time
from bisect import bisect_right
from collections import deque
from dataclasses import dataclass
from typing import Any

import foxglove
import numpy as np
from foxglove import channels as fch
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    FrameTransform,
    LinePrimitive,
    LinePrimitiveLineType,
    LocationFix,
    Log,
    LogLevel,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from ..engine.records import RunInfo, ScanRecord, StepRecord
from ..geometry.rotation import qlog_f, qmul_f, slerp_one
from ..layouts import REFERENCE_COLOUR, colour

Array = np.ndarray

__all__ = [
    "DEFAULT_FRAME_RATE_HZ", "Publisher", "RadarScanSample", "SCHEMAS", "StateSample",
    "euler_sigma_deg", "ned_frd_to_enu_flu", "b64_floats", "quat_to_rpy_deg", "triu_to_full",
]

_S2 = math.sqrt(0.5)
#: NED -> ENU (coordinates of a vector), FRD -> FLU, as [w, x, y, z].
Q_NED2ENU = np.array([0.0, _S2, _S2, 0.0])
Q_FRD2FLU = np.array([0.0, 1.0, 0.0, 0.0])

#: Order of preference among references for the error channels (truth first, as
#: :func:`uavest.eval.attitude.select_reference`).
_REF_ORDER = ("SIMSTATE", "SIM", "ATTITUDE_QUATERNION", "ATTITUDE", "ATT", "vehicle_attitude")
_KIND_RANK = {"truth": 0, "autopilot": 1, "ahrs2": 2}


@dataclass(frozen=True, slots=True)
class RadarScanSample:
    """One radar scan as a sample for sinks (the engine hook a radar source hands to
    :meth:`~uavest.sinks.base.Sink.sample`): scan ``k`` at ``t`` (s), detections ``Z``
    (N, m) [range m, azimuth rad, (elevation rad), (range rate m/s)], the radar model at
    the scan's pose (``RadarMeasurement``, world ENU), optional ``origins`` (N,) (target
    index, -1 clutter) and optional ``truths`` (n_targets, state) world ENU [p, v] with NaN
    rows for absent targets (recorded as the truth for the report's GOSPA)."""

    t: float
    k: int
    Z: Array
    model: Any
    origins: Array | None = None
    truths: Array | None = None


@dataclass(frozen=True, slots=True)
class StateSample:
    """One step of a generic vector-state run (a Monte Carlo trial of the benchmark
    systems: UNGM, nonlinear2d, linear_cv) as a sample for sinks, handed with the step
    through ``Step.info["samples"]`` before the estimators step: step ``k`` at ``t`` (s),
    the true state ``x`` (n,) (None when unknown) and the step's measurement ``z`` (m,)
    (None without one), in the system's own units. A recorder that sees one records the
    run's :class:`~uavest.engine.records.StepRecord` s on the generic ``/state/<label>/*``
    channels (state = plain vector, covariance in the same coordinates) instead of the
    attitude ones."""

    t: float
    k: int
    x: Array | None = None
    z: Array | None = None


# ------------------------------------------------------------------------- conversions


def ned_frd_to_enu_flu(q: Array) -> Array:
    """Quaternion(s) (..., 4) [w, x, y, z] body FRD -> NED to body FLU -> ENU:
    ``q_ned2enu * q * q_frd2flu`` (vectorised)."""
    from ..geometry.rotation import quat_mul

    q = np.asarray(q, float)
    return quat_mul(quat_mul(np.broadcast_to(Q_NED2ENU, q.shape), q),
                    np.broadcast_to(Q_FRD2FLU, q.shape))


def _enu_flu(q) -> tuple[float, float, float, float]:
    """Scalar form of :func:`ned_frd_to_enu_flu` (the recorder's hot path): with
    a = q_ned2enu * q = s (-(x + y), w + z, w - z, y - x), s = 1/sqrt 2, the product
    a * [0, 1, 0, 0] = (-a_x, a_w, a_z, -a_y)."""
    w, x, y, z = (float(v) for v in q)
    aw, ax, ay, az = _S2 * (-x - y), _S2 * (w + z), _S2 * (w - z), _S2 * (y - x)
    return (-ax, aw, az, -ay)


def _nees3(q, q_ref, P) -> float:
    """e^T P3^-1 e with e = Log(q^-1 q_ref) (as :func:`uavest.eval.attitude.nees_attitude`;
    P3 the upper-left 3x3 block of ``P`` (nested lists, the attitude block), solved by
    Cramer's rule)."""
    w, x, y, z = q
    e0, e1, e2 = qlog_f(qmul_f((w, -x, -y, -z), q_ref))
    (a, b, c), (d, f, g), (h, i, j) = P[0][:3], P[1][:3], P[2][:3]
    det = a * (f * j - g * i) - b * (d * j - g * h) + c * (d * i - f * h)
    if det == 0.0 or not math.isfinite(det):
        return math.nan
    return (e0 * ((f * j - g * i) * e0 + (c * i - b * j) * e1 + (b * g - c * f) * e2)
            + e1 * ((g * h - d * j) * e0 + (a * j - c * h) * e1 + (c * d - a * g) * e2)
            + e2 * ((d * i - f * h) * e0 + (b * h - a * i) * e1 + (a * f - b * d) * e2)) / det


def quat_to_rpy_deg(q) -> tuple[float, float, float]:
    """ZYX roll, pitch, yaw (deg) of one quaternion [w, x, y, z] (as
    :func:`uavest.geometry.rotation.quat_to_euler`)."""
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(min(max(2 * (w * y - x * z), -1.0), 1.0))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


_DEG = 180.0 / math.pi


def _rpy(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """:func:`quat_to_rpy_deg` of Python floats (the recorder's hot path)."""
    s = 2.0 * (w * y - x * z)
    return (_DEG * math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
            _DEG * math.asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s)),
            _DEG * math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def euler_sigma_deg(q: Array, P: Array) -> Array:
    """1-sigma of ZYX roll, pitch, yaw (deg), (..., 3), of an attitude ``q`` (..., 4) with
    body-frame tangent covariance ``P`` (..., >=3, >=3) (rad^2), linearised: a small body
    rotation d (q' = q Exp(d)) changes the Euler angles by W d with
    ``W = [[1, sin r tan p, cos r tan p], [0, cos r, -sin r], [0, sin r / cos p,
    cos r / cos p]]``, so Cov(euler) = W P W^T (diverges at pitch +-90 deg)."""
    from ..geometry.rotation import quat_to_euler

    e = quat_to_euler(np.asarray(q, float))
    r, p = e[..., 0], e[..., 1]
    sr, cr, tp, cp = np.sin(r), np.cos(r), np.tan(p), np.cos(p)
    W = np.zeros(e.shape[:-1] + (3, 3))
    W[..., 0, 0] = 1.0
    W[..., 0, 1] = sr * tp
    W[..., 0, 2] = cr * tp
    W[..., 1, 1] = cr
    W[..., 1, 2] = -sr
    W[..., 2, 1] = sr / cp
    W[..., 2, 2] = cr / cp
    P3 = np.asarray(P, float)[..., :3, :3]
    C = np.einsum("...ij,...jk,...lk->...il", W, P3, W)
    return np.degrees(np.sqrt(np.clip(np.einsum("...ii->...i", C), 0.0, None)))


def _sigma3_scalar(rpy_deg, P) -> tuple[float, float, float]:
    """3-sigma (deg) of roll, pitch, yaw: :func:`euler_sigma_deg` for one attitude given
    its Euler angles (deg) and the tangent covariance ``P`` (nested lists, >= 3x3),
    written out (W has zeros at [1][0] and [2][0])."""
    r, p = rpy_deg[0] / _DEG, rpy_deg[1] / _DEG
    sr, cr, cp = math.sin(r), math.cos(r), math.cos(p)
    if abs(cp) < 1e-12:  # gimbal lock: the Euler bounds are unbounded
        return math.inf, math.inf, math.inf
    tp = math.sin(p) / cp
    (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = P[0][:3], P[1][:3], P[2][:3]
    b, c = sr * tp, cr * tp  # roll row (1, b, c)
    v0 = p00 + b * (p01 + p10) + c * (p02 + p20) + b * b * p11 + b * c * (p12 + p21) \
        + c * c * p22
    v1 = cr * cr * p11 - cr * sr * (p12 + p21) + sr * sr * p22  # pitch row (0, cr, -sr)
    b, c = sr / cp, cr / cp  # yaw row (0, b, c)
    v2 = b * b * p11 + b * c * (p12 + p21) + c * c * p22
    k = 3.0 * _DEG  # a rounding-level negative variance counts as 0
    return (k * math.sqrt(v0) if v0 >= 0.0 else (0.0 if v0 > -1e-300 else math.nan),
            k * math.sqrt(v1) if v1 >= 0.0 else (0.0 if v1 > -1e-300 else math.nan),
            k * math.sqrt(v2) if v2 >= 0.0 else (0.0 if v2 > -1e-300 else math.nan))


def _wrap180(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def _clean(v):
    """JSON-safe floats (NaN/inf -> None)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, list):
        return [_clean(x) for x in v]
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    return v


def _floats(a) -> list:
    lst = np.asarray(a, float).ravel().tolist()
    return [x if math.isfinite(x) else None for x in lst]


def _rgba(hex_colour: str, alpha: float = 1.0):

    h = hex_colour.lstrip("#")
    return Color(r=int(h[0:2], 16) / 255, g=int(h[2:4], 16) / 255, b=int(h[4:6], 16) / 255,
                 a=alpha)


# ----------------------------------------------------------------------------- schemas


def _obj(title: str, desc: str, props: dict, required=()) -> dict:
    return {"title": title, "description": desc, "type": "object", "properties": props,
            "required": list(required)}


_NUM = {"type": ["number", "null"]}
_VEC3 = {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3}
_RPY = {"type": "object", "properties": {"roll": _NUM, "pitch": _NUM, "yaw": _NUM}}

#: JSON schemas (by title) of uavest's own channels.
SCHEMAS: dict[str, dict] = {
    "uavest.Imu": _obj("uavest.Imu", "IMU sample, body FRD", {
        "t": _NUM, "source": {"type": "string"},
        "gyro_rad_s": _VEC3, "accel_m_s2": _VEC3}, ["t", "gyro_rad_s", "accel_m_s2"]),
    "uavest.Mag": _obj("uavest.Mag", "magnetometer sample, body FRD, gauss", {
        "t": _NUM, "source": {"type": "string"}, "field_gauss": _VEC3}, ["t", "field_gauss"]),
    "uavest.Position": _obj("uavest.Position", "vehicle position: NED m from the local "
                            "origin, velocity NED m/s, lat deg, lon deg, alt m AMSL", {
        "t": _NUM, "source": {"type": "string"}, "ned_m": _VEC3, "vel_ned_m_s": _VEC3,
        "lat_lon_alt": _VEC3}, ["t"]),
    "uavest.AttitudeReference": _obj(
        "uavest.AttitudeReference", "attitude reference (truth / autopilot / ahrs2), q "
        "[w,x,y,z] body FRD -> NED, ZYX Euler deg", {
            "t": _NUM, "source": {"type": "string"}, "kind": {"type": "string"},
            "q": {"type": "array", "items": _NUM}, "rpy_deg": _RPY}, ["t", "q", "kind"]),
    "uavest.AttitudeEstimate": _obj(
        "uavest.AttitudeEstimate", "a filter's posterior: q [w,x,y,z] body FRD -> NED, gyro "
        "bias rad/s FRD, ZYX Euler deg with 3-sigma (deg, linearised), P_triu_b64: the upper "
        "triangle of the symmetric 6x6 tangent covariance, row by row (numpy.triu_indices; "
        "3 body rotation errors rad, 3 bias errors rad/s), as base64 of little-endian "
        "float64 (exact, and 50x cheaper to write than JSON numbers)", {
            "t": _NUM, "k": {"type": "integer"}, "q": {"type": "array", "items": _NUM},
            "bias_rad_s": _VEC3, "rpy_deg": _RPY, "sigma3_deg": _RPY,
            "P_triu_b64": {"type": "string", "contentEncoding": "base64"}},
        ["t", "k", "q", "P_triu_b64"]),
    "uavest.AttitudeError": _obj(
        "uavest.AttitudeError", "estimate - reference ZYX Euler error (deg, wrapped), the "
        "filter's own +-3 sigma (deg), NEES (3 dof, against truth only); the reference is "
        "interpolated (slerp) at the step time", {
            "t": _NUM, "k": {"type": "integer"}, "reference": {"type": "string"},
            "kind": {"type": "string"}, "err_deg": _RPY, "sigma3_deg": _RPY,
            "neg_sigma3_deg": _RPY, "nees": _NUM}, ["t", "k", "err_deg", "sigma3_deg"]),
    "uavest.FilterHealth": _obj(
        "uavest.FilterHealth", "a filter step's health: total NIS of the updates and its "
        "degrees of freedom, per-update NIS, guard resets, wall time us", {
            "t": _NUM, "k": {"type": "integer"}, "nis": _NUM, "nis_dof": {"type": "integer"},
            "updates": {"type": "array"}, "reset": {"type": "boolean"},
            "reason": {"type": "string"}, "resets": {"type": "integer"},
            "wall_us": _NUM}, ["t", "k", "wall_us"]),
    "uavest.RadarScan": _obj(
        "uavest.RadarScan", "radar detections of one scan: z rows [range m, az rad, (el "
        "rad), (range rate m/s)], world ENU positions m, origins (target index, -1 clutter)",
        {"t": _NUM, "k": {"type": "integer"}, "z": {"type": "array"},
         "xyz": {"type": "array"}, "origins": {"type": "array"},
         "sensor_position": {"type": "array"}}, ["t", "k", "z"]),
    "uavest.TargetTruth": _obj(
        "uavest.TargetTruth", "true targets alive at the scan: id (target index), x world "
        "ENU [p m, v m/s]", {"t": _NUM, "k": {"type": "integer"}, "n": {"type": "integer"},
                             "targets": {"type": "array"}}, ["t", "k", "targets"]),
    "uavest.Tracks": _obj(
        "uavest.Tracks", "a tracker's live tracks after a scan: id, x, P (row-major), "
        "confirmed, hit; deleted ids; wall time us", {
            "t": _NUM, "k": {"type": "integer"}, "n_confirmed": {"type": "integer"},
            "n_tentative": {"type": "integer"}, "tracks": {"type": "array"},
            "deleted": {"type": "array"}, "resets": {"type": "integer"},
            "wall_us": _NUM}, ["t", "k", "tracks"]),
    "uavest.StateEstimate": _obj(
        "uavest.StateEstimate", "a filter's posterior of a generic vector state (the "
        "system's own units): x (n,), per-component 3-sigma 3 sqrt(P_ii), P (n x n, "
        "row-major; the same coordinates as x)", {
            "t": _NUM, "k": {"type": "integer"}, "n": {"type": "integer"},
            "x": {"type": "array", "items": _NUM}, "sigma3": {"type": "array", "items": _NUM},
            "P": {"type": "array", "items": _NUM}}, ["t", "k", "x", "P"]),
    "uavest.StateError": _obj(
        "uavest.StateError", "estimate - truth of a generic vector state per component, "
        "the filter's own +-3 sigma per component (3 sqrt(P_ii)), NEES e^T P^-1 e with "
        "dof = n (truth of the same step)", {
            "t": _NUM, "k": {"type": "integer"}, "err": {"type": "array", "items": _NUM},
            "sigma3": {"type": "array", "items": _NUM},
            "neg_sigma3": {"type": "array", "items": _NUM}, "nees": _NUM,
            "dof": {"type": "integer"}}, ["t", "k", "err", "sigma3", "nees"]),
    "uavest.StateTruth": _obj(
        "uavest.StateTruth", "the true state of a simulated run at step k (system units)", {
            "t": _NUM, "k": {"type": "integer"}, "x": {"type": "array", "items": _NUM}},
        ["t", "k", "x"]),
    "uavest.Measurement": _obj(
        "uavest.Measurement", "the measurement z of step k (system units)", {
            "t": _NUM, "k": {"type": "integer"}, "z": {"type": "array", "items": _NUM}},
        ["t", "k", "z"]),
    "uavest.RunInfo": _obj("uavest.RunInfo", "the run (also in the MCAP metadata)", {
        "command": {"type": "string"}, "source": {"type": "string"},
        "seed": {"type": "integer"}, "filters": {"type": "object"},
        "config": {"type": "object"}, "versions": {"type": "object"}}),
}


# ------------------------------------------------------------------------- references


class _RefSeries:
    """Recent samples of one reference source (for slerp at step times)."""

    __slots__ = ("kind", "t", "q")

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.t: list[float] = []
        self.q: list[Array] = []

    def add(self, t: float, q: Array) -> bool:
        if self.t and t <= self.t[-1]:
            return False
        self.t.append(t)
        self.q.append(tuple(float(v) for v in q))
        return True

    def at(self, t: float):
        """Slerp at ``t`` as a tuple (None outside the span seen so far), as the scorer:
        q0 Exp(s Log(q0^-1 q1))."""
        ts = self.t
        if not ts or t < ts[0] or t > ts[-1]:
            return None
        if len(ts) == 1:
            return self.q[0]
        i = min(bisect_right(ts, t) - 1, len(ts) - 2)
        s = min(max((t - ts[i]) / (ts[i + 1] - ts[i]), 0.0), 1.0)
        return slerp_one(self.q[i], self.q[i + 1], s)

    def trim(self, t: float) -> None:
        i = bisect_right(self.t, t) - 1
        if i > 0:
            del self.t[:i], self.q[:i]


def _ref_rank(source: str, kind: str) -> tuple:
    order = _REF_ORDER.index(source) if source in _REF_ORDER else len(_REF_ORDER)
    return (_KIND_RANK.get(kind, 9), order, source)


# --------------------------------------------------------------------------- publisher

#: Default limit (Hz of data time) of the 3-D channels per estimator and reference of the
#: recording and live sinks: Foxglove's 3-D panel needs no more, and at a 248 Hz filter
#: rate the FrameTransform and PoseInFrame messages were 2 of the 5 per filter step.
DEFAULT_FRAME_RATE_HZ = 30.0

#: ``uavest.AttitudeEstimate`` up to ``"sigma3_deg":`` (t, k, q, bias exact; Euler deg
#: derived, 10 digits).
_EST_TPL = ('{"t":%.17g,"k":%d,"q":[%.17g,%.17g,%.17g,%.17g],"bias_rad_s":[%.17g,%.17g,'
            '%.17g],"rpy_deg":{"roll":%.10g,"pitch":%.10g,"yaw":%.10g},"sigma3_deg":')


class _Lane:
    """One attitude estimator's channels (made once; the record hot path)."""

    __slots__ = ("label", "t_est", "t_health", "t_err", "est", "health", "err", "frame",
                 "offset", "key", "last_frame")

    def __init__(self, label: str, offset: float) -> None:
        self.label = label
        self.t_est = f"/attitude/{label}/estimate"
        self.t_health = f"/attitude/{label}/health"
        self.t_err = f"/attitude/{label}/error"
        self.est = self.health = self.err = None
        self.frame = f"body_{label}"
        self.offset = offset
        self.key = "lab:" + label
        self.last_frame: float | None = None



class Publisher:
    """Turns samples and records into Foxglove messages on channels of one context.

    ``spacing_m``: the 3-D view puts filter i's body frame ``spacing_m * (i + 1)`` m east
    of the vehicle position (references at the position itself), so the bodies stand side
    by side instead of on top of each other (a display offset only: ``PoseInFrame`` and
    the JSON channels carry the true position). ``frame_rate_hz``: limit of the 3-D
    channels (``/tf/*``, ``/attitude/*/pose``) per estimator in data time (None: every
    step); the JSON channels always carry every step. ``history``: points of a track's
    history line. ``only_subscribed``: skip building messages for channels nobody
    listens to (the live view)."""

    def __init__(self, context, *, spacing_m: float = 2.0, frame_rate_hz: float | None = None,
                 history: int = 60, only_subscribed: bool = False) -> None:
        self.ctx = context
        self.spacing = float(spacing_m)
        self.frame_dt = 1.0 / frame_rate_hz if frame_rate_hz else 0.0
        self.history = int(history)
        self.only_subscribed = only_subscribed
        self.channels: dict[str, Any] = {}
        self.labels: list[str] = []
        self.kind: str | None = None  # "attitude" | "radar" | "attitude+radar" | "state"
        self.refs: dict[str, _RefSeries] = {}
        self.ref_frames: dict[str, str] = {}
        self.best_ref: str | None = None
        # steps waiting for the reference: (t, ns, k, lane, q, P (lists), +3 sigma JSON,
        # -3 sigma JSON, rpy)
        self.pending: deque = deque()
        self.last_step_t: float | None = None
        self.pos_enu = (0.0, 0.0, 0.0)
        self.pos_source: str | None = None
        self.last_frame: dict[str, float] = {}
        self.tracks_hist: dict[tuple[str, int], deque] = {}
        self.markers_wall = -1e9
        # generic vector-state runs: the latest truth (t, x) and the largest state size
        self.state_truth: tuple[float, Array] | None = None
        self.state_dim = 0
        self.lanes: dict[str, _Lane] = {}
        self.track_labels: list[str] = []  # labels of trackers (ScanRecord)
        self.health_lanes: dict[str, _Lane] = {}
        self._err_tpl: dict[str, str] = {}
        self._drains = 0
        self._src: dict[tuple[str, str], tuple] = {}
        self.counts: dict[str, int] = {}
        self.info: dict | None = None

    # -- channels -------------------------------------------------------------------------
    def _channel(self, topic: str, schema: str):
        ch = self.channels.get(topic)
        if ch is None:
            if schema.startswith("uavest."):
                ch = foxglove.Channel(topic, schema=SCHEMAS[schema], context=self.ctx)
            else:
                ch = getattr(fch, schema + "Channel")(topic, context=self.ctx)
            self.channels[topic] = ch
        return ch

    def _want(self, topic: str, schema: str):
        ch = self._channel(topic, schema)
        if self.only_subscribed and not ch.has_sinks():
            return None
        return ch

    def _json(self, topic: str, schema: str, t: float, msg: dict) -> None:
        ch = self._want(topic, schema)
        if ch is not None:
            try:
                data = json.dumps(msg, allow_nan=False)
            except ValueError:  # a NaN/inf somewhere (a diverged filter): write null
                data = json.dumps(_clean(msg), allow_nan=False)
            ch.log(data.encode(), log_time=_ns(t))
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def _text(self, topic: str, schema: str, t: float, text: str) -> None:
        """Log JSON text made by the caller (the hot path)."""
        ch = self._want(topic, schema)
        if ch is not None:
            ch.log(text.encode(), log_time=_ns(t))
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def _pb(self, topic: str, schema: str, t: float, build) -> None:
        ch = self._want(topic, schema)
        if ch is not None:
            ch.log(build(), log_time=_ns(t))
            self.counts[topic] = self.counts.get(topic, 0) + 1

    # -- run ------------------------------------------------------------------------------
    def open(self, info: RunInfo) -> None:
        self.info = _clean(_jsonable(info.as_dict()))
        self._json("/run/info", "uavest.RunInfo", 0.0, self.info)

    def log_event(self, t: float, level: str, name: str, message: str) -> None:
        """An event on ``/log`` (foxglove.Log): level ``info``/``warning``/``error``."""

        lvl = {"info": LogLevel.Info, "warning": LogLevel.Warning,
               "error": LogLevel.Error}[level]
        self._pb("/log", "Log", t, lambda: Log(
            timestamp=_ts(t), level=lvl, message=message, name=name, file="uavest", line=0))

    def start(self, label: str, t0: float, x0: Array, P0: Array) -> None:
        if label not in self.labels:
            self.labels.append(label)
        self.log_event(t0, "info", label, f"start {label} at t = {t0:.3f} s")

    # -- samples --------------------------------------------------------------------------
    def sample(self, s) -> None:
        name = type(s).__name__
        if name == "ImuSample":
            topic, ch, tpl = self._src_channel("/imu/", s.source, "uavest.Imu",
                                               '"gyro_rad_s":[%.17g,%.17g,%.17g],'
                                               '"accel_m_s2":[%.17g,%.17g,%.17g]}')
            if ch is not None:
                g, a = s.gyro.tolist(), s.accel.tolist()
                self._log(ch, topic, _fill(tpl, (s.t, g[0], g[1], g[2], a[0], a[1], a[2])
                                           ).encode(), _ns(s.t))
        elif name == "MagSample":
            topic, ch, tpl = self._src_channel("/mag/", s.source, "uavest.Mag",
                                               '"field_gauss":[%.17g,%.17g,%.17g]}')
            if ch is not None:
                f = s.field.tolist()
                self._log(ch, topic, _fill(tpl, (s.t, f[0], f[1], f[2])).encode(), _ns(s.t))
        elif name == "AttitudeRef":
            self._reference(s)
        elif name == "PositionSample":
            self._position(s)
        elif name == "RadarScanSample" or (hasattr(s, "Z") and hasattr(s, "model")):
            self._radar(s)
        elif name == "StateSample":
            self._state_sample(s)

    def _src_channel(self, prefix: str, source: str, schema: str, body: str):
        """(topic, channel or None when nobody listens, template) of a per-source sample
        channel; the template starts ``{"t":%.17g,"source":"<source>",`` + ``body``."""
        key = (prefix, source)
        hit = self._src.get(key)
        if hit is None:
            topic = prefix + source
            hit = self._src[key] = (topic, self._channel(topic, schema),
                                    '{"t":%.17g,"source":' + _pct(_q(source)) + "," + body)
        if self.only_subscribed and not hit[1].has_sinks():
            return hit[0], None, hit[2]
        return hit

    def _state_sample(self, s: StateSample) -> None:
        """Truth and measurement of a generic vector-state step (``/truth/state``,
        ``/measurement/z``); the truth is kept for the error of the step's records."""
        self.kind = "state"
        if s.x is not None:
            x = np.asarray(s.x, float).ravel()
            self.state_truth = (float(s.t), x)
            self._json("/truth/state", "uavest.StateTruth", s.t,
                       {"t": s.t, "k": int(s.k), "x": _floats(x)})
        if s.z is not None:
            self._json("/measurement/z", "uavest.Measurement", s.t,
                       {"t": s.t, "k": int(s.k), "z": _floats(s.z)})

    def _position(self, s) -> None:
        msg = {"t": s.t, "source": s.source}
        if s.ned is not None:
            msg["ned_m"] = _floats(s.ned)
            if self.pos_source in (None, s.source):
                self.pos_source = s.source
                n, e, d = (float(v) for v in s.ned)
                if math.isfinite(n + e + d):
                    self.pos_enu = (e, n, -d)
        if s.vel_ned is not None:
            msg["vel_ned_m_s"] = _floats(s.vel_ned)
        if s.lat_lon_alt is not None:
            lla = _floats(s.lat_lon_alt)
            msg["lat_lon_alt"] = lla
            if all(v is not None for v in lla):

                self._pb(f"/gps/{s.source}", "LocationFix", s.t, lambda: LocationFix(
                    timestamp=_ts(s.t), frame_id="world", latitude=lla[0], longitude=lla[1],
                    altitude=lla[2]))
        self._json(f"/position/{s.source}", "uavest.Position", s.t, msg)

    def _reference(self, s) -> None:
        self.kind = self.kind or "attitude"
        r = self.refs.get(s.source)
        if r is None:
            r = self.refs[s.source] = _RefSeries(s.kind)
            taken = set(self.ref_frames.values())
            self.ref_frames[s.source] = (f"body_{s.kind}" if f"body_{s.kind}" not in taken
                                         else f"body_{s.source}")
            if self.best_ref is None or (_ref_rank(s.source, s.kind)
                                         < _ref_rank(self.best_ref, self.refs[self.best_ref].kind)):
                self.best_ref = s.source
        if not r.add(s.t, s.q):
            return
        q = r.q[-1]  # as Python floats
        topic, ch, tpl = self._src_channel(
            "/reference/", s.source, "uavest.AttitudeReference",
            '"kind":' + _pct(_q(s.kind)) + ',"q":[%.17g,%.17g,%.17g,%.17g],'
            '"rpy_deg":{"roll":%.10g,"pitch":%.10g,"yaw":%.10g}}')
        if ch is not None:
            rpy = _rpy(*q)
            self._log(ch, topic, _fill(tpl, (s.t, *q, *rpy)).encode(), _ns(s.t))
        frame = self.ref_frames[s.source]
        self._frame(frame[5:], frame, s.t, q, 0.0, "ref:" + s.source)
        if s.source == self.best_ref:
            self._drain(final=False)

    # -- 3-D ------------------------------------------------------------------------------
    def _frame(self, name: str, frame: str, t: float, q, offset_east: float, key: str) -> None:
        """``/tf/<name>`` and ``/attitude/<name>/pose`` of attitude ``q`` (NED/FRD, a
        tuple) at ``t``; estimators' records check the rate limit themselves, the
        references here (per ``key``)."""
        if self.frame_dt and not key.startswith("lab:"):
            last = self.last_frame.get(key)
            if last is not None and t - last < self.frame_dt:
                return
            self.last_frame[key] = t
        w, x, y, z = _enu_flu(q)
        e, n, u = self.pos_enu
        rot = Quaternion(x=x, y=y, z=z, w=w)
        ts = _ts(t)
        self._pb(f"/tf/{name}", "FrameTransform", t, lambda: FrameTransform(
            timestamp=ts, parent_frame_id="world", child_frame_id=frame,
            translation=Vector3(x=e + offset_east, y=n, z=u), rotation=rot))
        self._pb(f"/attitude/{name}/pose", "PoseInFrame", t, lambda: PoseInFrame(
            timestamp=ts, frame_id="world",
            pose=Pose(position=Vector3(x=e, y=n, z=u), orientation=rot)))

    def _markers(self, t: float) -> None:
        """Body markers (nose arrow, label) in every body frame, re-sent once per wall
        second so a live client that joins late sees them."""
        now = time.monotonic()
        if now - self.markers_wall < 1.0:
            return
        self.markers_wall = now
        if self.only_subscribed and self.info is not None:  # for live clients joining late
            self._json("/run/info", "uavest.RunInfo", 0.0, self.info)

        ents = []
        items = [(lab, f"body_{lab}", colour(lab)) for lab in self.labels]
        items += [(f[5:], f, REFERENCE_COLOUR) for f in self.ref_frames.values()]
        ident = Quaternion(x=0, y=0, z=0, w=1)
        for name, frame, col in items:
            ents.append(SceneEntity(
                timestamp=_ts(t), frame_id=frame, id=f"body/{name}", frame_locked=True,
                arrows=[ArrowPrimitive(pose=Pose(position=Vector3(x=0, y=0, z=0),
                                                 orientation=ident),
                                       shaft_length=1.0, shaft_diameter=0.08,
                                       head_length=0.3, head_diameter=0.2,
                                       color=_rgba(col))],
                cubes=[CubePrimitive(pose=Pose(position=Vector3(x=0, y=0, z=0),
                                               orientation=ident),
                                     size=Vector3(x=0.8, y=1.2, z=0.08),
                                     color=_rgba(col, 0.5))],
                texts=[TextPrimitive(pose=Pose(position=Vector3(x=0, y=0, z=0.5),
                                               orientation=ident),
                                     billboard=True, font_size=14, scale_invariant=True,
                                     color=_rgba(col), text=name)]))
        self._pb("/attitude/bodies", "SceneUpdate", t, lambda: SceneUpdate(entities=ents))

    # -- records --------------------------------------------------------------------------
    def _lane(self, lab: str) -> _Lane:
        """The channels and 3-D placement of attitude estimator ``lab`` (made once)."""
        if lab not in self.labels:
            self.labels.append(lab)
        ln = _Lane(lab, self.spacing * (self.labels.index(lab) + 1))
        ln.est = self._channel(ln.t_est, "uavest.AttitudeEstimate")
        ln.health = self._channel(ln.t_health, "uavest.FilterHealth")
        self.lanes[lab] = ln
        return ln

    def _log(self, ch, topic: str, data: bytes, ns: int) -> None:
        """Log JSON bytes on a channel made by :meth:`_channel` (the wrapper's checks
        skipped: ``foxglove.Channel.base.log``)."""
        ch.base.log(data, ns)
        c = self.counts
        c[topic] = c.get(topic, 0) + 1

    def record(self, rec: StepRecord | ScanRecord) -> None:
        if type(rec) is not StepRecord:
            if isinstance(rec, ScanRecord):
                self._scan(rec)
                return
        if self.kind == "state":
            self._state_record(rec)
            return
        if self.kind != "attitude":
            self.kind = "attitude+radar" if self.kind in ("radar", "attitude+radar") \
                else "attitude"
        lab, t, k = rec.estimator, rec.t, rec.k
        ln = self.lanes.get(lab) or self._lane(lab)
        ns = _ns(t)
        osub = self.only_subscribed
        P = rec.P
        xs = rec.x.tolist()
        Pl = P[:3, :3].tolist()  # the attitude block (sigma3, NEES)
        w, x, y, z = xs[0], xs[1], xs[2], xs[3]
        rpy = _rpy(w, x, y, z)
        s3 = _sigma3_scalar(rpy, Pl)
        s3t = (_g(s3[0]), _g(s3[1]), _g(s3[2]))
        s3j = '{"roll":%s,"pitch":%s,"yaw":%s}' % s3t  # noqa: UP031
        # the hot path: JSON text assembled directly (q, bias, t exact with %.17g; derived
        # Euler angles and bounds with 10 digits; NaN/inf -> null), one formatting
        # operation per message
        if not osub or ln.est.has_sinks():
            b = xs[4:7] if len(xs) >= 7 else (xs[4:7] + [math.nan] * 3)[:3]
            self._log(ln.est, ln.t_est, (_fill(_EST_TPL, (
                t, k, w, x, y, z, b[0], b[1], b[2], rpy[0], rpy[1], rpy[2]))
                + s3j + ',"P_triu_b64":"' + _b64_triu(P) + '"}').encode(), ns)
        if not osub or ln.health.has_sinks():
            self._health_fast(ln, rec, ns)
        elif rec.reset:
            self._reset_event(rec)
        if self.frame_dt:
            last = ln.last_frame
            if last is None or t - last >= self.frame_dt:
                ln.last_frame = t
                self._frame(lab, ln.frame, t, (w, x, y, z), ln.offset, ln.key)
        else:
            self._frame(lab, ln.frame, t, (w, x, y, z), ln.offset, ln.key)
        self._markers(t)
        self.last_step_t = t
        if self.refs:
            self.pending.append((t, ns, k, ln, (w, x, y, z), Pl, s3j,
                                 '{"roll":%s,"pitch":%s,"yaw":%s}' % (  # noqa: UP031
                                     _neg(s3t[0]), _neg(s3t[1]), _neg(s3t[2])), rpy))
            self._drain(final=False)

    def _health_fast(self, ln: _Lane, rec: StepRecord, ns: int) -> None:
        ups, dof, nis = [], 0, 0.0
        for u in rec.updates:
            nu = u.nu
            d = nu.size if type(nu) is np.ndarray else int(np.size(nu))
            dof += d
            nis += u.nis
            ups.append('{"kind":%s,"nis":%s,"dof":%d}' % (_q(u.kind), _n(u.nis), d))  # noqa: UP031
        self._log(ln.health, ln.t_health, (
            '{"t":%s,"k":%d,"nis":%s,"nis_dof":%d,"updates":[%s],"reset":%s,'  # noqa: UP031
            '"reason":%s,"resets":%d,"wall_us":%s}' % (
                _n(rec.t), rec.k, _n(float(nis)) if ups else "null", dof, ",".join(ups),
                "true" if rec.reset else "false", _q(rec.reason), int(rec.resets),
                _g(1e6 * rec.wall_s))).encode(), ns)
        if rec.reset:
            self._reset_event(rec)

    def _reset_event(self, rec: StepRecord) -> None:
        t, lab = rec.t, rec.estimator
        self.log_event(t, "warning", lab, f"{lab} reset at t = {t:.3f} s (step {rec.k}): "
                       f"{rec.reason or 'divergence guard'}; resets so far {rec.resets}")

    def _health(self, topic: str, rec: StepRecord) -> None:
        """``uavest.FilterHealth`` of a step on ``topic`` (and its reset on ``/log``)."""
        ln = self.health_lanes.get(topic)
        if ln is None:
            ln = self.health_lanes[topic] = _Lane(rec.estimator, 0.0)
            ln.t_health = topic
            ln.health = self._channel(topic, "uavest.FilterHealth")
        if not self.only_subscribed or ln.health.has_sinks():
            self._health_fast(ln, rec, _ns(rec.t))
        elif rec.reset:
            self._reset_event(rec)

    def _state_record(self, rec: StepRecord) -> None:
        """A generic vector-state step: ``/state/<label>/estimate``, ``.../health`` and,
        when the truth of the same step was seen, ``.../error`` (estimate - truth, the
        filter's own +-3 sigma, NEES with dof n). The state is a plain vector (x and P in
        the same coordinates); a state whose covariance is of another size has no error
        channel."""
        lab, t = rec.estimator, rec.t
        if lab not in self.labels:
            self.labels.append(lab)
        x = np.asarray(rec.x, float).ravel()
        P = np.asarray(rec.P, float).reshape(x.size, -1) if np.size(rec.P) else \
            np.zeros((x.size, 0))
        self.state_dim = max(self.state_dim, int(x.size))
        d = np.diagonal(P) if P.shape[0] == P.shape[1] else np.full(x.size, np.nan)
        with np.errstate(invalid="ignore"):
            s3 = 3.0 * np.sqrt(d)
        s3l = _floats(s3)
        self._json(f"/state/{lab}/estimate", "uavest.StateEstimate", t, {
            "t": t, "k": int(rec.k), "n": int(x.size), "x": _floats(x), "sigma3": s3l,
            "P": _floats(P)})
        self._health(f"/state/{lab}/health", rec)
        tr = self.state_truth
        if tr is not None and tr[0] == t and tr[1].size == x.size == P.shape[0] == P.shape[1]:
            e = x - tr[1]
            try:
                ne = float(e @ np.linalg.solve(P, e))
            except np.linalg.LinAlgError:
                ne = math.nan
            self._json(f"/state/{lab}/error", "uavest.StateError", t, {
                "t": t, "k": int(rec.k), "err": _floats(e), "sigma3": s3l,
                "neg_sigma3": _floats(-s3), "nees": ne if math.isfinite(ne) else None,
                "dof": int(x.size)})

    def _drain(self, final: bool) -> None:
        """Errors of the waiting steps whose time the chosen reference has reached."""
        name = self.best_ref
        if name is None:
            return
        r = self.refs[name]
        truth = r.kind == "truth"
        pend = self.pending
        rt = r.t
        osub = self.only_subscribed
        tpl = self._err_tpl.get(name)
        if tpl is None:
            tpl = self._err_tpl[name] = (
                '{"t":%%.17g,"k":%%d,"reference":%s,"kind":%s,'  # noqa: UP031
                '"err_deg":{"roll":%%.10g,"pitch":%%.10g,"yaw":%%.10g}' % (
                    _pct(_q(name)), _pct(_q(r.kind))))
        while pend:
            t, ns, k, ln, q, Pl, s3j, negj, a = pend[0]
            if rt and t > rt[-1] and not final:
                break
            pend.popleft()
            qr = r.at(t)
            if qr is None:
                continue  # outside the reference's span: not scored (as the scorer)
            ch = ln.err
            if ch is None:
                ch = ln.err = self._channel(ln.t_err, "uavest.AttitudeError")
            if osub and not ch.has_sinks():
                continue
            b = _rpy(*qr)
            tail = ',"nees":' + _g(_nees3(q, qr, Pl)) + "}" if truth else "}"
            self._log(ch, ln.t_err, (_fill(tpl, (
                t, k, (a[0] - b[0] + 180.0) % 360.0 - 180.0,  # wrapped as _wrap180
                (a[1] - b[1] + 180.0) % 360.0 - 180.0, (a[2] - b[2] + 180.0) % 360.0 - 180.0))
                + ',"sigma3_deg":' + s3j + ',"neg_sigma3_deg":' + negj + tail).encode(), ns)
        # later steps come at or after the newest step seen: keep what they may need
        # (trimmed now and then: the slerp's bisection does not mind a longer list)
        self._drains += 1
        if final or self._drains % 64 == 0:
            keep = pend[0][0] if pend else self.last_step_t
            if keep is not None:
                for ref in self.refs.values():
                    ref.trim(keep)

    # -- radar ----------------------------------------------------------------------------
    def _saw_radar(self) -> None:
        """Radar data: kind ``radar``, or ``attitude+radar`` for a run with both (a live
        link: attitude filters and trackers side by side)."""
        if self.kind in (None, "radar"):
            self.kind = "radar"
        elif self.kind == "attitude":
            self.kind = "attitude+radar"

    def _radar(self, s) -> None:
        self._saw_radar()

        Z = np.asarray(s.Z, float).reshape(len(s.Z), -1)
        m = s.model
        xyz = []
        for z in Z:
            p, _ = m.to_cartesian(z)
            p = np.asarray(p, float)
            xyz.append([float(p[0]), float(p[1]), float(p[2]) if p.size > 2 else 0.0])
        msg = {"t": s.t, "k": int(s.k), "z": [_floats(z) for z in Z], "xyz": xyz,
               "sensor_position": _floats(m.pose.position)}
        if s.origins is not None:
            msg["origins"] = [int(o) for o in s.origins]
        self._json("/radar/scan", "uavest.RadarScan", s.t, msg)
        ident = Quaternion(x=0, y=0, z=0, w=1)
        sp = np.asarray(m.pose.position, float)
        ents = [SceneEntity(
            timestamp=_ts(s.t), frame_id="world", id="detections",
            spheres=[SpherePrimitive(pose=Pose(position=Vector3(x=a, y=b, z=c),
                                               orientation=ident),
                                     size=Vector3(x=60, y=60, z=60),
                                     color=_rgba("#808080", 0.8)) for a, b, c in xyz]
            + [SpherePrimitive(pose=Pose(position=Vector3(
                x=float(sp[0]), y=float(sp[1]), z=float(sp[2]) if sp.size > 2 else 0.0),
                orientation=ident), size=Vector3(x=150, y=150, z=150),
                color=_rgba("#d62728", 1.0))])]
        self._pb("/radar/detections", "SceneUpdate", s.t, lambda: SceneUpdate(entities=ents))
        if s.truths is not None:
            X = np.asarray(s.truths, float)
            alive = [i for i in range(len(X)) if np.isfinite(X[i]).all()]
            self._json("/radar/truth/state", "uavest.TargetTruth", s.t, {
                "t": s.t, "k": int(s.k), "n": len(alive),
                "targets": [{"id": i, "x": _floats(X[i])} for i in alive]})
            d = 3 if X.shape[1] >= 6 else 2
            tents = []
            for i in alive:
                pos = (float(X[i, 0]), float(X[i, 1]), float(X[i, 2]) if d == 3 else 0.0)
                h = self.tracks_hist.setdefault(("truth", i), deque(maxlen=self.history))
                h.append(pos)
                tents.append(self._track_entity(s.t, f"truth/{i}", pos, None, f"target {i}",
                                                REFERENCE_COLOUR, 1.0, h))
            self._pb("/radar/truth", "SceneUpdate", s.t, lambda: SceneUpdate(entities=tents))

    def _track_entity(self, t, eid, pos, P, text, col, alpha, hist):

        ident = Quaternion(x=0, y=0, z=0, w=1)
        if P is None:
            size, orient = (40.0, 40.0, 40.0), ident
        else:
            size, (w, x, y, z) = _ellipsoid(P)
            orient = Quaternion(x=x, y=y, z=z, w=w)
        return SceneEntity(
            timestamp=_ts(t), frame_id="world", id=eid,
            spheres=[SpherePrimitive(pose=Pose(position=Vector3(x=pos[0], y=pos[1],
                                                                z=pos[2]),
                                               orientation=orient),
                                     size=Vector3(x=size[0], y=size[1], z=size[2]),
                                     color=_rgba(col, 0.35 * alpha))],
            texts=[TextPrimitive(pose=Pose(position=Vector3(x=pos[0], y=pos[1],
                                                            z=pos[2] + 100.0),
                                           orientation=ident),
                                 billboard=True, font_size=14, scale_invariant=True,
                                 color=_rgba(col, alpha), text=text)],
            lines=[LinePrimitive(type=LinePrimitiveLineType.LineStrip,
                                 pose=Pose(position=Vector3(x=0, y=0, z=0), orientation=ident),
                                 thickness=3.0, scale_invariant=True,
                                 points=[Point3(x=a, y=b, z=c) for a, b, c in hist],
                                 color=_rgba(col, alpha))] if len(hist) > 1 else [])

    def _scan(self, rec: ScanRecord) -> None:

        self._saw_radar()
        lab, t = rec.estimator, rec.t
        if lab not in self.labels:
            self.labels.append(lab)
        if lab not in self.track_labels:
            self.track_labels.append(lab)
        col = colour(lab)
        rows, ents = [], []
        for tr in rec.tracks:
            x = np.asarray(tr.x, float)
            P = np.asarray(tr.P, float)
            d = 3 if x.size >= 6 else 2
            pos = (float(x[0]), float(x[1]), float(x[2]) if d == 3 else 0.0)
            rows.append({"id": int(tr.id), "x": _floats(x), "P": _floats(P),
                         "confirmed": bool(tr.confirmed), "hit": bool(tr.hit)})
            h = self.tracks_hist.setdefault((lab, tr.id), deque(maxlen=self.history))
            h.append(pos)
            ents.append(self._track_entity(
                t, f"{lab}/{tr.id}", pos, P[:d, :d], f"{lab} #{tr.id}", col,
                1.0 if tr.confirmed else 0.35, h))
        for i in rec.deleted:
            self.tracks_hist.pop((lab, i), None)
        nc = sum(1 for r in rows if r["confirmed"])
        self._json(f"/tracks/{lab}/state", "uavest.Tracks", t, {
            "t": t, "k": rec.k, "n_confirmed": nc, "n_tentative": len(rows) - nc,
            "tracks": rows, "deleted": [int(i) for i in rec.deleted],
            "resets": int(rec.resets), "wall_us": 1e6 * rec.wall_s})
        dels = [SceneEntityDeletion(timestamp=_ts(t), type=SceneEntityDeletionType.MatchingId,
                                    id=f"{lab}/{i}") for i in rec.deleted]
        self._pb(f"/tracks/{lab}", "SceneUpdate", t,
                 lambda: SceneUpdate(deletions=dels, entities=ents))
        if rec.resets:
            self.log_event(t, "warning", lab, f"{lab}: {rec.resets} track filter reset(s) "
                           f"at scan {rec.k}")

    def close(self) -> None:
        self._drain(final=True)


# ------------------------------------------------------------------------------ helpers


_TRIU: dict[int, tuple] = {}


def _triu(n: int) -> tuple:
    """``numpy.triu_indices(n)`` (cached)."""
    if n not in _TRIU:
        _TRIU[n] = np.triu_indices(n)
    return _TRIU[n]


_TRIU_FLAT: dict[int, Array] = {}


def _b64_triu(P: Array) -> str:
    """:func:`_b64` of the upper triangle of square ``P``, row by row (as
    ``P[numpy.triu_indices(n)]``; ``take`` with cached flat indices is cheaper)."""
    n = P.shape[0]
    idx = _TRIU_FLAT.get(n)
    if idx is None:
        idx = _TRIU_FLAT[n] = np.ravel_multi_index(np.triu_indices(n), (n, n))
    v = P.take(idx)
    if v.dtype != np.dtype("<f8"):
        v = v.astype("<f8")
    return base64.b64encode(v.tobytes()).decode()


def _b64(a: Array) -> str:
    return base64.b64encode(np.ascontiguousarray(a, "<f8").tobytes()).decode()


def b64_floats(s: str | list[str]) -> Array:
    """float64 array(s) from the recorder's base64 fields (a list gives a stacked array)."""
    if isinstance(s, str):
        return np.frombuffer(base64.b64decode(s), "<f8")
    return np.stack([np.frombuffer(base64.b64decode(x), "<f8") for x in s])


def triu_to_full(v, n: int) -> Array:
    """Symmetric (..., n, n) matrices from their upper triangles (..., n (n + 1) / 2) as
    written by the recorder (``P_triu_b64``, decoded with :func:`b64_floats`)."""
    v = np.asarray(v, float)
    out = np.empty(v.shape[:-1] + (n, n))
    i, j = np.triu_indices(n)
    out[..., i, j] = v
    out[..., j, i] = v
    return out


def _ns(t: float) -> int:
    return max(int(round(t * 1e9)), 0)


def _ts(t: float):

    ns = _ns(t)
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _n(v) -> str:
    """A float as JSON text: %.17g (exact round trip), null for None/NaN/inf."""
    if v is None or not math.isfinite(v):
        return "null"
    return "%.17g" % v  # noqa: UP031


def _g(v: float) -> str:
    """A derived display quantity (Euler angles, 3-sigma, errors, NEES, wall time) as JSON
    text: 10 significant digits (%.10g, about 4x cheaper to format than the exact
    %.17g), null for NaN/inf."""
    return "%.10g" % v if v - v == 0.0 else "null"  # noqa: UP031


_NULLS: dict[str, str] = {}
_FLOAT_FIELD = re.compile(r"%\.\d+g")


def _fill(tpl: str, vals: tuple) -> str:
    """``tpl % vals`` for a template whose float fields are ``%.17g`` (exact) or
    ``%.10g`` (derived) and int fields ``%d``: one formatting operation when every value
    is finite (checked with one ``sum``), else NaN/inf written as null."""
    if math.isfinite(sum(vals)):
        return tpl % vals
    t2 = _NULLS.get(tpl)
    if t2 is None:
        t2 = _NULLS[tpl] = _FLOAT_FIELD.sub("%s", tpl)
    return t2 % tuple(_n(v) if isinstance(v, float) else v for v in vals)


def _pct(s: str) -> str:
    """``s`` as literal text inside a %-template."""
    return s.replace("%", "%%")


def _neg(s: str) -> str:
    """The JSON text of -v from the JSON text of v (null stays null)."""
    if s == "null":
        return s
    return s[1:] if s[0] == "-" else "-" + s


_QUOTED: dict[str, str] = {}


def _q(s: str) -> str:
    """A string as JSON text (cached: sources, labels, kinds repeat)."""
    out = _QUOTED.get(s)
    if out is None:
        out = json.dumps(s)
        if len(_QUOTED) < 10_000:
            _QUOTED[s] = out
    return out


def _fin(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, np.generic):
        return o.item()
    if o is None or isinstance(o, bool | int | float | str):
        return o
    return str(o)


def _ellipsoid(P: Array) -> tuple[tuple[float, float, float], tuple]:
    """3-sigma ellipsoid of a 2x2/3x3 position covariance: full axis lengths (m) and the
    orientation [w, x, y, z] of its principal axes (world)."""
    from ..geometry.rotation import dcm_to_quat

    d = P.shape[0]
    P3 = np.eye(3) * 1.0
    P3[:d, :d] = P
    if d == 2:
        P3[2, 2] = 1.0
    w, V = np.linalg.eigh(0.5 * (P3 + P3.T))
    if np.linalg.det(V) < 0:
        V[:, 0] = -V[:, 0]
    size = tuple(float(6.0 * math.sqrt(max(v, 0.0))) for v in w)
    q = dcm_to_quat(V)
    return size, (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
