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

uavest's per-step attitude channels and raw samples are protobuf messages of its own schema
(:mod:`uavest.sinks.protobuf`); its other channels are JSON with a JSON schema with a
``title`` (``uavest.*``), NaN written as null.
"""

from __future__ import annotations

import base64
import json
import math
import struct
import time
from bisect import bisect_right
from collections import deque
from typing import Any

import foxglove
import numpy as np
from foxglove import channels as fch
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    LinePrimitive,
    LinePrimitiveLineType,
    LocationFix,
    Log,
    LogLevel,
    Point3,
    Pose,
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

from ..engine.records import RunInfo, ScanRecord, StateSample, StepRecord
from ..geometry.rotation import (
    quat_conj,
    quat_log,
    quat_mul,
    quat_slerp_interp,
)
from ..layouts import REFERENCE_COLOUR, colour
from . import protobuf as pb

Array = np.ndarray

__all__ = [
    "DEFAULT_FRAME_RATE_HZ", "Publisher", "SCHEMAS", "euler_sigma_deg", "ned_frd_to_enu_flu",
    "b64_floats", "quat_to_rpy_deg", "triu_to_full",
]

_S2 = math.sqrt(0.5)
#: NED -> ENU (coordinates of a vector), FRD -> FLU, as [w, x, y, z].
Q_NED2ENU = np.array([0.0, _S2, _S2, 0.0])
Q_FRD2FLU = np.array([0.0, 1.0, 0.0, 0.0])

#: Order of preference among references for the error channels (truth first, as
#: :func:`uavest.eval.attitude.select_reference`).
_REF_ORDER = ("SIMSTATE", "SIM", "ATTITUDE_QUATERNION", "ATTITUDE", "ATT", "vehicle_attitude")
_KIND_RANK = {"truth": 0, "autopilot": 1, "ahrs2": 2}


# ------------------------------------------------------------------------- conversions


def ned_frd_to_enu_flu(q: Array) -> Array:
    """Quaternion(s) (..., 4) [w, x, y, z] body FRD -> NED to body FLU -> ENU:
    ``q_ned2enu * q * q_frd2flu`` (vectorised)."""
    from ..geometry.rotation import quat_mul

    q = np.asarray(q, float)
    return quat_mul(quat_mul(np.broadcast_to(Q_NED2ENU, q.shape), q),
                    np.broadcast_to(Q_FRD2FLU, q.shape))


def quat_to_rpy_deg(q) -> tuple[float, float, float]:
    """ZYX roll, pitch, yaw (deg) of one quaternion [w, x, y, z] (as
    :func:`uavest.geometry.rotation.quat_to_euler`)."""
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(min(max(2 * (w * y - x * z), -1.0), 1.0))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


_DEG = 180.0 / math.pi


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


def _rpy_rows(Q: Array) -> Array:
    """:func:`quat_to_rpy_deg` of quaternion rows (N, 4) -> (N, 3) deg (vectorised)."""
    w, x, y, z = Q[:, 0], Q[:, 1], Q[:, 2], Q[:, 3]
    out = np.empty((Q.shape[0], 3))
    np.multiply(_DEG, np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
                out=out[:, 0])
    np.multiply(_DEG, np.arcsin(np.clip(2.0 * (w * y - x * z), -1.0, 1.0)), out=out[:, 1])
    np.multiply(_DEG, np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)),
                out=out[:, 2])
    return out


def _sigma3_rows(rpy: Array, P3: Array) -> Array:
    """3 x :func:`euler_sigma_deg` of rows given their Euler angles (N, 3) deg and attitude
    covariance blocks (N, 3, 3) rad^2 -> 3-sigma (N, 3) deg, written out (W has zeros at
    [1][0] and [2][0]); inf at gimbal lock, a rounding-level negative variance 0, a
    negative one NaN."""
    r, p = rpy[:, 0] / _DEG, rpy[:, 1] / _DEG
    sr, cr, cp = np.sin(r), np.cos(r), np.cos(p)
    lock = np.abs(cp) < 1e-12
    cp = np.where(lock, 1.0, cp)
    tp = np.sin(p) / cp
    p00, p01, p02 = P3[:, 0, 0], P3[:, 0, 1], P3[:, 0, 2]
    p10, p11, p12 = P3[:, 1, 0], P3[:, 1, 1], P3[:, 1, 2]
    p20, p21, p22 = P3[:, 2, 0], P3[:, 2, 1], P3[:, 2, 2]
    b, c = sr * tp, cr * tp
    v = np.empty((rpy.shape[0], 3))
    v[:, 0] = (p00 + b * (p01 + p10) + c * (p02 + p20) + b * b * p11 + b * c * (p12 + p21)
               + c * c * p22)
    v[:, 1] = cr * cr * p11 - cr * sr * (p12 + p21) + sr * sr * p22
    b, c = sr / cp, cr / cp
    v[:, 2] = b * b * p11 + b * c * (p12 + p21) + c * c * p22
    with np.errstate(invalid="ignore"):
        out = (3.0 * _DEG) * np.sqrt(np.where((v < 0.0) & (v > -1e-300), 0.0, v))
    out[lock] = math.inf
    return out


def _enu_flu_rows(Q: Array) -> Array:
    """:func:`ned_frd_to_enu_flu` of rows (N, 4), written out (the recorder's hot path):
    with a = q_ned2enu * q = s (-(x + y), w + z, w - z, y - x), s = 1/sqrt 2, the product
    a * [0, 1, 0, 0] = (-a_x, a_w, a_z, -a_y)."""
    w, x, y, z = Q[:, 0], Q[:, 1], Q[:, 2], Q[:, 3]
    out = np.empty_like(Q)
    out[:, 0] = -(_S2 * (w + z))
    out[:, 1] = _S2 * (-x - y)
    out[:, 2] = _S2 * (y - x)
    out[:, 3] = -(_S2 * (w - z))
    return out


def _nees_rows(q: Array, qr: Array, P3: Array) -> Array:
    """Attitude NEES of rows (as :func:`uavest.eval.attitude.nees_attitude`): e = Log(q^-1
    q_ref), e^T P3^-1 e by Cramer's rule (N,); NaN where P3 is singular or not finite."""
    e = quat_log(quat_mul(quat_conj(q), qr))
    a, b, c = P3[:, 0, 0], P3[:, 0, 1], P3[:, 0, 2]
    d, f, g = P3[:, 1, 0], P3[:, 1, 1], P3[:, 1, 2]
    h, i, j = P3[:, 2, 0], P3[:, 2, 1], P3[:, 2, 2]
    e0, e1, e2 = e[:, 0], e[:, 1], e[:, 2]
    det = a * (f * j - g * i) - b * (d * j - g * h) + c * (d * i - f * h)
    bad = (det == 0.0) | ~np.isfinite(det)
    det = np.where(bad, 1.0, det)
    out = (e0 * ((f * j - g * i) * e0 + (c * i - b * j) * e1 + (b * g - c * f) * e2)
           + e1 * ((g * h - d * j) * e0 + (a * j - c * h) * e1 + (c * d - a * g) * e2)
           + e2 * ((d * i - f * h) * e0 + (b * h - a * i) * e1 + (a * f - b * d) * e2)) / det
    out[bad] = math.nan
    return out


def _ns_rows(T: Array) -> list[int]:
    """:func:`_ns` of an array of times (s) as a list of ints (ns)."""
    return np.maximum(np.rint(T * 1e9), 0.0).astype(np.int64).tolist()


def _rows(a) -> Array:
    """``a`` as (N, m) rows; an empty scan (``[]``, (0,) or (0, m)) gives (0, m) (m = 0
    when unknown) instead of the ``reshape(0, -1)`` error numpy raises for size 0."""
    a = np.asarray(a, float)
    if a.size == 0:
        return a.reshape(0, a.shape[-1] if a.ndim > 1 else 0)
    return a.reshape(len(a), -1)


def _stack3(vs: list) -> Array:
    """Rows of 3-vectors (a list of (3,) arrays) as (N, 3) float."""
    return np.array(vs, float).reshape(-1, 3)


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

#: JSON schemas (by title) of uavest's own JSON channels (the per-step attitude channels
#: and the raw samples are protobuf: :mod:`uavest.sinks.protobuf`; ``uavest.FilterHealth``
#: is also the JSON schema of the generic ``/state/<label>/health``).
SCHEMAS: dict[str, dict] = {
    "uavest.Position": _obj("uavest.Position", "vehicle position: NED m from the local "
                            "origin, velocity NED m/s, lat deg, lon deg, alt m AMSL", {
        "t": _NUM, "source": {"type": "string"}, "ned_m": _VEC3, "vel_ned_m_s": _VEC3,
        "lat_lon_alt": _VEC3}, ["t"]),
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
        self.q.append(tuple(q.tolist()) if type(q) is np.ndarray else
                      tuple(float(v) for v in q))
        return True

    def trim(self, t: float) -> None:
        i = bisect_right(self.t, t) - 1
        if i > 0:
            del self.t[:i], self.q[:i]


def _ref_rank(source: str, kind: str) -> tuple:
    order = _REF_ORDER.index(source) if source in _REF_ORDER else len(_REF_ORDER)
    return (_KIND_RANK.get(kind, 9), order, source)


# --------------------------------------------------------------------------- publisher

#: Default limit (Hz of data time) of the 3-D channels per estimator and reference of the
#: recording and live sinks: they only move the bodies in the 3-D view (a ground station
#: shows a vehicle's ATTITUDE stream at a few Hz to ~10 Hz), the plots carry every step;
#: at the default 25 Hz filter rate the 3-D messages were 40 % of the recorder's cost at
#: 30 Hz (docs/recording.md, "Cost").
DEFAULT_FRAME_RATE_HZ = 15.0


class _FramePack:
    """A translation (Vector3 x, y, z) and a rotation (Quaternion x, y, z, w) as two
    protobuf fields, tags ``tag_t`` and ``tag_r``, packed in one ``struct`` call."""

    def __init__(self, tag_t: int, tag_r: int) -> None:
        self.s = struct.Struct("<BBBdBdBdBBBdBdBdBd")
        self.tags = (tag_t, tag_r)

    def pack(self, tx, ty, tz, qx, qy, qz, qw) -> bytes:
        a, b = self.tags
        return self.s.pack(a, 27, 0x09, tx, 0x11, ty, 0x19, tz, b, 36, 0x09, qx, 0x11, qy,
                           0x19, qz, 0x21, qw)


#: FrameTransform: translation (field 4) and rotation (field 5).
_TF_POSE = _FramePack(0x22, 0x2A)
#: PoseInFrame: frame_id "world" (field 2), then pose (field 3, 67 bytes: Pose's position
#: (field 1) and orientation (field 2)).
_POSE_HEAD = b"\x12\x05world\x1a\x43"
_POSE = _FramePack(0x0A, 0x12)


class _Lane:
    """One attitude estimator's channels (made once; the record hot path)."""

    __slots__ = ("label", "t_est", "t_health", "t_err", "est", "health", "err", "frame",
                 "offset", "key", "last_frame", "buf", "pend", "enc", "enc_dims")

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
        self.buf: list = []  # records not yet encoded
        self.pend: list[dict] = []  # encoded steps waiting for the reference (row chunks)
        self.enc: dict[str, pb.FixedEncoder] = {}
        self.enc_dims: tuple | None = None


class Publisher:
    """Turns samples and records into Foxglove messages on channels of one context.

    ``spacing_m``: the 3-D view puts filter i's body frame ``spacing_m * (i + 1)`` m east
    of the vehicle position (references at the position itself), so the bodies stand side
    by side instead of on top of each other (a display offset only: ``PoseInFrame`` and
    the per-step channels carry the true position). ``frame_rate_hz``: limit of the 3-D
    channels (``/tf/*``, ``/attitude/*/pose``) per estimator in data time (None: every
    step); the per-step channels always carry every step. ``history``: points of a track's
    history line. ``only_subscribed``: skip building messages for channels nobody
    listens to (the live view). ``batch``: :meth:`sample` and :meth:`record` queue their
    argument; every ``batch`` calls (1: at once, the live view) :meth:`flush` handles the
    queue in order and encodes the per-step attitude channels and the raw samples
    (protobuf, :mod:`uavest.sinks.protobuf`) vectorised over it; the recorder also
    flushes before it closes a chunk, so nothing waits longer than a chunk."""

    def __init__(self, context, *, spacing_m: float = 2.0, frame_rate_hz: float | None = None,
                 history: int = 60, only_subscribed: bool = False, batch: int = 1) -> None:
        self.ctx = context
        self.batch = max(int(batch), 1)
        self._queue: list = []  # samples and records not yet handled, in order
        self._nrec = -1  # (the first record sends the markers)
        # raw samples not yet encoded: (kind, source) -> samples ((t, q) for references)
        self._sbuf: dict[tuple[str, str], list] = {}
        self._senc: dict[tuple[str, str], tuple] = {}
        self._raw: dict[tuple[type, str], list] = {}  # (sample type, source) -> its buffer
        self._kinds: dict[type, int] = {}  # queued item type -> 0 sample, 1 raw, 2 record
        self._frames: dict[str, tuple] = {}
        self._fq: list[tuple] = []  # frames not yet encoded
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
        self._drains = 0
        self.counts: dict[str, int] = {}
        self.info: dict | None = None

    # -- channels -------------------------------------------------------------------------
    def _channel(self, topic: str, schema: str):
        ch = self.channels.get(topic)
        if ch is None:
            if schema.startswith("wk:"):  # a well-known schema, messages encoded here
                ch = foxglove.Channel(topic, schema=getattr(foxglove.messages, schema[3:])
                                      .get_schema(), message_encoding="protobuf",
                                      context=self.ctx)
            elif schema.startswith("pb:"):
                ch = foxglove.Channel(topic, schema=pb.schema(schema[3:]),
                                      message_encoding="protobuf", context=self.ctx)
            elif schema.startswith("uavest."):
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
        self.flush()  # (the start event after what came before it on /log)
        if label not in self.labels:
            self.labels.append(label)
        self.log_event(t0, "info", label, f"start {label} at t = {t0:.3f} s")

    # -- samples --------------------------------------------------------------------------
    def sample(self, s) -> None:
        """Queue a sample or a record (handled with the batch, in order)."""
        q = self._queue
        q.append(s)
        if len(q) >= self.batch:
            self.flush()

    record = sample  # records and samples share the queue

    def _raw_buffer(self, s) -> list:
        """The buffer of IMU / magnetometer samples of ``s``'s type and source."""
        key = (type(s), s.source)
        buf = self._raw.get(key)
        if buf is None:
            buf = self._raw[key] = self._sbuf.setdefault(
                ("imu" if type(s).__name__ == "ImuSample" else "mag", s.source), [])
        return buf

    def _sample(self, s) -> None:
        """A queued sample other than IMU / magnetometer (:meth:`flush` puts those in their
        buffers itself)."""
        name = type(s).__name__
        if name == "AttitudeRef":
            self._reference(s)
        elif name == "PositionSample":
            self._position(s)
        elif name == "RadarScanSample" or (hasattr(s, "Z") and hasattr(s, "model")):
            self._radar(s)
        elif name == "StateSample":
            self._state_sample(s)

    def _flush_samples(self) -> None:
        """Encode and log the buffered raw samples (IMU, magnetometer, references)."""
        for key, buf in self._sbuf.items():
            if not buf:
                continue
            hit = self._senc.get(key)
            if hit is None:
                kind, source = key
                topic = {"imu": "/imu/", "mag": "/mag/", "ref": "/reference/"}[kind] + source
                if kind == "imu":
                    enc = pb.FixedEncoder("Imu", {"source": source},
                                          {"gyro_rad_s": 3, "accel_m_s2": 3})
                    ch = self._channel(topic, "pb:Imu")
                elif kind == "mag":
                    enc = pb.FixedEncoder("Mag", {"source": source}, {"field_gauss": 3})
                    ch = self._channel(topic, "pb:Mag")
                else:
                    enc = pb.FixedEncoder("AttitudeReference", {
                        "source": source, "kind": self.refs[source].kind}, {"q": 4})
                    ch = self._channel(topic, "pb:AttitudeReference")
                hit = self._senc[key] = (topic, ch, enc)
            topic, ch, enc = hit
            n = len(buf)
            if not self.only_subscribed or ch.has_sinks():
                if key[0] == "ref":
                    T = np.array([b[0] for b in buf], float)
                    Q = np.array([b[1] for b in buf], float).reshape(n, 4)
                    cols = {"t": T, "q": Q, "rpy_deg": _rpy_rows(Q)}
                else:
                    T = np.array([b.t for b in buf], float)
                    if key[0] == "imu":
                        cols = {"t": T, "gyro_rad_s": _stack3([b.gyro for b in buf]),
                                "accel_m_s2": _stack3([b.accel for b in buf])}
                    else:
                        cols = {"t": T, "field_gauss": _stack3([b.field for b in buf])}
                self._log_many(ch, topic, enc.encode(n, cols), _ns_rows(T))
            buf.clear()

    def _log_many(self, ch, topic: str, msgs: list[bytes], ns: list[int]) -> None:
        log = ch.base.log
        for m, t in zip(msgs, ns, strict=True):
            log(m, t)
        c = self.counts
        c[topic] = c.get(topic, 0) + len(msgs)

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
        key = ("ref", s.source)
        buf = self._sbuf.get(key)
        if buf is None:
            buf = self._sbuf[key] = []
        buf.append((s.t, q))
        frame = self.ref_frames[s.source]
        self._frame(frame[5:], frame, s.t, q, 0.0, "ref:" + s.source)

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
        self._fq.append((name, frame, t, q, offset_east, self.pos_enu))

    def _flush_frames(self) -> None:
        """Encode and log the queued frames (``/tf/<name>``, ``/attitude/<name>/pose``):
        the ENU/FLU rotations and the times vectorised, each message one ``struct`` pack."""
        fq = self._fq
        if not fq:
            return
        self._fq = []
        m = len(fq)
        W = _enu_flu_rows(np.array([r[3] for r in fq], float).reshape(m, 4)).tolist()
        NS = _ns_rows(np.array([r[2] for r in fq], float))
        osub = self.only_subscribed
        c = self.counts
        frames = self._frames
        for (name, frame, _, _, offset_east, (e, n, u)), (w, x, y, z), ns in zip(
                fq, W, NS, strict=True):
            hit = frames.get(name)
            if hit is None:
                # foxglove.FrameTransform / foxglove.PoseInFrame (the SDK's schemas)
                # encoded here: the same protobuf messages, without seven SDK objects each
                tf_t, pose_t = f"/tf/{name}", f"/attitude/{name}/pose"
                tf_ch = self._channel(tf_t, "wk:FrameTransform")
                pose_ch = self._channel(pose_t, "wk:PoseInFrame")
                hit = frames[name] = (
                    tf_t, tf_ch, tf_ch.base.log,
                    pb.len_field(2, b"world") + pb.len_field(3, frame.encode()),
                    pose_t, pose_ch, pose_ch.base.log)
            tf_t, tf_ch, tf_log, tf_ids, pose_t, pose_ch, pose_log = hit
            stamp = pb.timestamp_field(1, ns)
            if not osub or tf_ch.has_sinks():
                tf_log(stamp + tf_ids + _TF_POSE.pack(e + offset_east, n, u, x, y, z, w), ns)
                c[tf_t] = c.get(tf_t, 0) + 1
            if not osub or pose_ch.has_sinks():
                pose_log(stamp + _POSE_HEAD + _POSE.pack(e, n, u, x, y, z, w), ns)
                c[pose_t] = c.get(pose_t, 0) + 1

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
        ln.est = self._channel(ln.t_est, "pb:AttitudeEstimate")
        ln.health = self._channel(ln.t_health, "pb:FilterHealth")
        self.lanes[lab] = ln
        return ln

    def _log(self, ch, topic: str, data: bytes, ns: int) -> None:
        """Log JSON bytes on a channel made by :meth:`_channel` (the wrapper's checks
        skipped: ``foxglove.Channel.base.log``)."""
        ch.base.log(data, ns)
        c = self.counts
        c[topic] = c.get(topic, 0) + 1

    def _record(self, rec: StepRecord | ScanRecord) -> None:
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
        lab, t = rec.estimator, rec.t
        ln = self.lanes.get(lab) or self._lane(lab)
        ln.buf.append(rec)
        if rec.reset:
            self._reset_event(rec)
        if self.frame_dt:
            last = ln.last_frame
            if last is None or t - last >= self.frame_dt:
                ln.last_frame = t
                self._frame(lab, ln.frame, t, rec.x[:4].tolist(), ln.offset, ln.key)
        else:
            self._frame(lab, ln.frame, t, rec.x[:4].tolist(), ln.offset, ln.key)
        self._nrec += 1
        if not self._nrec & 31:  # the wall clock read every 32nd record
            self._markers(t)
        self.last_step_t = t

    def flush(self) -> None:
        """Encode and log everything buffered: raw samples first (the references the
        errors need), then each estimator's estimates and health, then the errors of the
        steps the chosen reference has reached."""
        q = self._queue
        if q:
            # the queued calls in order, in one loop (each sink call of the run only
            # appends: cheap between the filters' steps, which evict the recorder's
            # working set from the caches)
            self._queue = []
            sample, record = self._sample, self._record
            kinds, raw = self._kinds, self._raw
            for it in q:
                tp = type(it)
                k = kinds.get(tp)
                if k is None:
                    k = kinds[tp] = (2 if tp is StepRecord or issubclass(tp, ScanRecord) else
                                     1 if tp.__name__ in ("ImuSample", "MagSample") else 0)
                if k == 1:  # a raw sample: into its buffer (the hot case, inline)
                    b = raw.get((tp, it.source))
                    if b is None:
                        b = self._raw_buffer(it)
                    b.append(it)
                elif k == 2:
                    record(it)
                else:
                    sample(it)
        self._flush_frames()
        self._flush_samples()
        for ln in self.lanes.values():
            if ln.buf:
                self._flush_lane(ln)
        self._drain(final=False)

    def _encoders(self, ln: _Lane, nx: int, nP: int) -> dict:
        if ln.enc_dims != (nx, nP):
            ln.enc_dims = (nx, nP)
            ln.enc = {
                "est": pb.FixedEncoder("AttitudeEstimate", lengths={
                    "q": 4, "bias_rad_s": 3, "P_triu": nP * (nP + 1) // 2}),
                "health": pb.FixedEncoder("FilterHealth")}
        return ln.enc

    def _flush_lane(self, ln: _Lane) -> None:
        """The buffered records of one attitude estimator: ``/attitude/<label>/estimate``
        and ``.../health`` (vectorised over the batch), and their rows for the errors."""
        recs = ln.buf
        ln.buf = []
        n = len(recs)
        T = np.array([r.t for r in recs], float)
        K = np.array([r.k for r in recs], np.int64)
        try:
            X = np.array([r.x for r in recs], float)
            P = np.array([r.P for r in recs], float)
            if X.ndim != 2 or P.ndim != 3:
                raise ValueError
        except ValueError:  # states of different sizes in one batch: one at a time
            for r in recs:
                ln.buf = [r]
                self._flush_lane(ln)
            return
        nx, nP = X.shape[1], P.shape[1]
        enc = self._encoders(ln, nx, nP)
        Q = X[:, :4]
        B = X[:, 4:7] if nx >= 7 else np.full((n, 3), math.nan)
        rpy = _rpy_rows(Q)
        P3 = P[:, :3, :3]
        s3 = _sigma3_rows(rpy, P3)
        ns = _ns_rows(T)
        osub = self.only_subscribed
        if not osub or ln.est.has_sinks():
            i, j = _triu(nP)
            self._log_many(ln.est, ln.t_est, enc["est"].encode(n, {
                "t": T, "k": K, "q": Q, "bias_rad_s": B, "rpy_deg": rpy, "sigma3_deg": s3,
                "P_triu": P[:, i, j]}), ns)
        if not osub or ln.health.has_sinks():
            nis = np.full(n, math.nan)
            dof = np.zeros(n, np.int64)
            extra: dict[int, bytes] = {}  # message index -> its variable fields
            upd = pb.update_bytes
            for m, r in enumerate(recs):
                ups = r.updates
                if ups:
                    b, d, v = b"", 0, 0.0
                    for u in ups:
                        nu = u.nu
                        dd = nu.size if type(nu) is np.ndarray else int(np.size(nu))
                        d += dd
                        v += u.nis
                        b += upd(5, u.kind, float(u.nis), dd)
                    nis[m], dof[m] = v, d
                    extra[m] = b
                if r.reason:
                    extra[m] = extra.get(m, b"") + pb.field_bytes(7, str(r.reason))
            msgs = enc["health"].encode(n, {
                "t": T, "k": K, "nis": nis, "nis_dof": dof,
                "reset": np.array([r.reset for r in recs], bool),
                "resets": np.array([r.resets for r in recs], np.int64),
                "wall_us": 1e6 * np.array([r.wall_s for r in recs], float)})
            for m, e in extra.items():
                msgs[m] += e
            self._log_many(ln.health, ln.t_health, msgs, ns)
        if self.refs:
            ln.pend.append({"t": T, "ns": np.asarray(ns, np.int64), "k": K, "q": Q,
                            "P3": P3, "s3": s3, "rpy": rpy})

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
        """Errors of the waiting steps whose time the chosen reference has reached
        (vectorised over each estimator's waiting rows); ``final``: the rest too (those
        outside the reference's span are not scored, as the scorer)."""
        name = self.best_ref
        if name is None:
            return
        r = self.refs[name]
        truth = r.kind == "truth"
        if not r.t:
            return
        rt = np.asarray(r.t)
        rq = np.asarray(r.q, float).reshape(-1, 4)
        keep_t = None
        for ln in self.lanes.values():
            if not ln.pend:
                continue
            rows = ln.pend[0] if len(ln.pend) == 1 else {
                k: np.concatenate([c[k] for c in ln.pend]) for k in ln.pend[0]}
            t = rows["t"]
            if final:
                ln.pend = []
                ready = np.ones(t.shape, bool)
            else:
                ready = t <= rt[-1]
                if ready.all():
                    ln.pend = []
                else:
                    later = ~ready
                    ln.pend = [{k: v[later] for k, v in rows.items()}]
                    t0 = float(t[later].min())
                    keep_t = t0 if keep_t is None else min(keep_t, t0)
                    rows = {k: v[ready] for k, v in rows.items()}
            ok = (rows["t"] >= rt[0]) & (rows["t"] <= rt[-1])
            if not ok.all():
                rows = {k: v[ok] for k, v in rows.items()}
            n = rows["t"].shape[0]
            if n == 0:
                continue
            ch = ln.err
            if ch is None:
                ch = ln.err = self._channel(ln.t_err, "pb:AttitudeError")
            if self.only_subscribed and not ch.has_sinks():
                continue
            enc = ln.enc.get(("err", name))
            if enc is None:
                enc = ln.enc[("err", name)] = pb.FixedEncoder(
                    "AttitudeError", {"reference": name, "kind": r.kind})
            qr, _ = quat_slerp_interp(rt, rq, rows["t"])
            err = (rows["rpy"] - _rpy_rows(qr) + 180.0) % 360.0 - 180.0  # as _wrap180
            s3 = rows["s3"]
            cols = {"t": rows["t"], "k": rows["k"], "err_deg": err, "sigma3_deg": s3,
                    "neg_sigma3_deg": -s3,
                    "nees": _nees_rows(rows["q"], qr, rows["P3"]) if truth else math.nan}
            self._log_many(ch, ln.t_err, enc.encode(n, cols), rows["ns"].tolist())
        # later steps come at or after the newest step seen: keep what they may need
        # (trimmed now and then: the interpolation's search does not mind a longer list)
        self._drains += 1
        if final or self._drains % 8 == 0:
            keep = keep_t if keep_t is not None else self.last_step_t
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

        Z = _rows(s.Z)
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
            X = _rows(s.truths)
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
        self.flush()
        self._drain(final=True)


# ------------------------------------------------------------------------------ helpers


_TRIU: dict[int, tuple] = {}


def _triu(n: int) -> tuple:
    """``numpy.triu_indices(n)`` (cached)."""
    if n not in _TRIU:
        _TRIU[n] = np.triu_indices(n)
    return _TRIU[n]


def b64_floats(s: str | list[str]) -> Array:
    """float64 array(s) from the recorder's base64 fields (a list gives a stacked array)."""
    if isinstance(s, str):
        return np.frombuffer(base64.b64decode(s), "<f8")
    if len(s) == 0:
        return np.empty((0, 0))
    return np.stack([np.frombuffer(base64.b64decode(x), "<f8") for x in s])


def triu_to_full(v, n: int) -> Array:
    """Symmetric (..., n, n) matrices from their upper triangles (..., n (n + 1) / 2) as
    written by the recorder (``P_triu`` of ``uavest.AttitudeEstimate``; ``P_triu_b64`` of
    channel set 1, decoded with :func:`b64_floats`)."""
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
