"""Frames: our NED / FRD data in Foxglove's ENU / FLU 3-D panel, and the 3-D channels
(``/tf/<name>``, ``/attitude/<name>/pose``, the body markers, the vehicle position).

Attitudes are converted as::

    q_enu_flu = q_ned2enu * q_ned_frd * q_frd2flu

with ``q_ned2enu`` = 180 deg about (1, 1, 0)/sqrt(2) = [0, 1/sqrt2, 1/sqrt2, 0] (swaps x
and y, flips z) and ``q_frd2flu`` = 180 deg about x = [0, 1, 0, 0] (flips y and z); see
:func:`ned_frd_to_enu_flu`. Positions: ENU = (east, north, -down). The root frame is
``world`` (ENU).
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np
from foxglove.messages import (
    ArrowPrimitive,
    CubePrimitive,
    LocationFix,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    TextPrimitive,
    Vector3,
)

from ...layouts import REFERENCE_COLOUR, colour
from .. import protobuf as pb
from .channels import ChannelSet, Scene
from .encode import _floats, _ns_rows, _rgba, _ts

Array = np.ndarray

__all__ = ["DEFAULT_FRAME_RATE_HZ", "Frames", "Q_FRD2FLU", "Q_NED2ENU", "ned_frd_to_enu_flu"]

_S2 = math.sqrt(0.5)

#: NED -> ENU (coordinates of a vector), FRD -> FLU, as [w, x, y, z].
Q_NED2ENU = np.array([0.0, _S2, _S2, 0.0])

Q_FRD2FLU = np.array([0.0, 1.0, 0.0, 0.0])



def ned_frd_to_enu_flu(q: Array) -> Array:
    """Quaternion(s) (..., 4) [w, x, y, z] body FRD -> NED to body FLU -> ENU:
    ``q_ned2enu * q * q_frd2flu`` (vectorised)."""
    from ...geometry.rotation import quat_mul

    q = np.asarray(q, float)
    return quat_mul(quat_mul(np.broadcast_to(Q_NED2ENU, q.shape), q),
                    np.broadcast_to(Q_FRD2FLU, q.shape))



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



class Frames:
    """The 3-D channels: each body's ``/tf/<name>`` and ``/attitude/<name>/pose`` (queued
    by :meth:`frame`, encoded by :meth:`flush`), the body markers, and the vehicle
    position that places them (:meth:`position`). ``frame_dt``: the least data time (s)
    between two frames of one reference (0: every one)."""

    def __init__(self, chans: ChannelSet, scene: Scene, frame_dt: float) -> None:
        self.chans = chans
        self.scene = scene
        self.frame_dt = frame_dt
        self.pos_enu = (0.0, 0.0, 0.0)
        self.pos_source: str | None = None
        self.last_frame: dict[str, float] = {}
        self.markers_wall = -1e9
        self._frames: dict[str, tuple] = {}
        self._fq: list[tuple] = []  # frames not yet encoded

    def position(self, s) -> None:
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

                self.chans.pb(f"/gps/{s.source}", "LocationFix", s.t, lambda: LocationFix(
                    timestamp=_ts(s.t), frame_id="world", latitude=lla[0], longitude=lla[1],
                    altitude=lla[2]))
        self.chans.json(f"/position/{s.source}", "uavest.Position", s.t, msg)

    def nav_position(self, label: str, p_ned) -> None:
        """A navigation estimate's position (NED m, its local frame): the first navigation
        filter's own position places the bodies (the 3-D view follows its trajectory;
        position samples then no longer move it)."""
        src = "nav:" + label
        if self.pos_source is not None and self.pos_source.startswith("nav:") \
                and self.pos_source != src:
            return
        n, e, d = (float(v) for v in p_ned)
        if math.isfinite(n + e + d):
            self.pos_source = src
            self.pos_enu = (e, n, -d)

    def frame(self, name: str, frame: str, t: float, q, offset_east: float, key: str) -> None:
        """``/tf/<name>`` and ``/attitude/<name>/pose`` of attitude ``q`` (NED/FRD, a
        tuple) at ``t``; estimators' records check the rate limit themselves, the
        references here (per ``key``)."""
        if self.frame_dt and not key.startswith("lab:"):
            last = self.last_frame.get(key)
            if last is not None and t - last < self.frame_dt:
                return
            self.last_frame[key] = t
        self._fq.append((name, frame, t, q, offset_east, self.pos_enu))

    def flush(self) -> None:
        """Encode and log the queued frames (``/tf/<name>``, ``/attitude/<name>/pose``):
        the ENU/FLU rotations and the times vectorised, each message one ``struct`` pack."""
        fq = self._fq
        if not fq:
            return
        self._fq = []
        m = len(fq)
        W = _enu_flu_rows(np.array([r[3] for r in fq], float).reshape(m, 4)).tolist()
        NS = _ns_rows(np.array([r[2] for r in fq], float))
        osub = self.chans.only_subscribed
        c = self.chans.counts
        frames = self._frames
        for (name, frame, _, _, offset_east, (e, n, u)), (w, x, y, z), ns in zip(
                fq, W, NS, strict=True):
            hit = frames.get(name)
            if hit is None:
                # foxglove.FrameTransform / foxglove.PoseInFrame (the SDK's schemas)
                # encoded here: the same protobuf messages, without seven SDK objects each
                tf_t, pose_t = f"/tf/{name}", f"/attitude/{name}/pose"
                tf_ch = self.chans.channel(tf_t, "wk:FrameTransform")
                pose_ch = self.chans.channel(pose_t, "wk:PoseInFrame")
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

    def markers(self, t: float, ref_frames: dict[str, str]) -> None:
        """Body markers (nose arrow, label) in every body frame, re-sent once per wall
        second so a live client that joins late sees them."""
        now = time.monotonic()
        if now - self.markers_wall < 1.0:
            return
        self.markers_wall = now
        if self.chans.only_subscribed and self.scene.info is not None:  # late live clients
            self.chans.json("/run/info", "uavest.RunInfo", 0.0, self.scene.info)

        ents = []
        items = [(lab, f"body_{lab}", colour(lab)) for lab in self.scene.labels]
        items += [(f[5:], f, REFERENCE_COLOUR) for f in ref_frames.values()]
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
        self.chans.pb("/attitude/bodies", "SceneUpdate", t, lambda: SceneUpdate(entities=ents))
