"""The radar channels: scans (``/radar/scan``, ``/radar/detections``), the true targets
(``/radar/truth/state``, ``/radar/truth``) and each tracker's tracks (``/tracks/<label>``
with 3-sigma ellipsoids and history lines, ``/tracks/<label>/state``). Radar scenarios
are already ENU (world) and are published unchanged."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from foxglove.messages import (
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Vector3,
)

from ...engine.records import ScanRecord
from ...layouts import REFERENCE_COLOUR, colour
from .channels import ChannelSet, Scene
from .encode import _floats, _rgba, _rows, _ts

Array = np.ndarray

__all__ = ["RadarChannels"]


def _ellipsoid(P: Array) -> tuple[tuple[float, float, float], tuple]:
    """3-sigma ellipsoid of a 2x2/3x3 position covariance: full axis lengths (m) and the
    orientation [w, x, y, z] of its principal axes (world)."""
    from ...geometry.rotation import dcm_to_quat

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



class RadarChannels:
    """Radar scans, true targets and tracks (see module docstring). ``history``: points
    of a track's history line."""

    def __init__(self, chans: ChannelSet, scene: Scene, history: int) -> None:
        self.chans = chans
        self.scene = scene
        self.history = int(history)
        self.tracks_hist: dict[tuple[str, int], deque] = {}
        self.track_labels: list[str] = []  # labels of trackers (ScanRecord)

    def saw_radar(self) -> None:
        """Radar data: kind ``radar``, or ``attitude+radar`` for a run with both (a live
        link: attitude filters and trackers side by side)."""
        if self.scene.kind in (None, "radar"):
            self.scene.kind = "radar"
        elif self.scene.kind == "attitude":
            self.scene.kind = "attitude+radar"

    def scan_sample(self, s) -> None:
        self.saw_radar()

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
        self.chans.json("/radar/scan", "uavest.RadarScan", s.t, msg)
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
        self.chans.pb("/radar/detections", "SceneUpdate", s.t, lambda: SceneUpdate(entities=ents))
        if s.truths is not None:
            X = _rows(s.truths)
            alive = [i for i in range(len(X)) if np.isfinite(X[i]).all()]
            self.chans.json("/radar/truth/state", "uavest.TargetTruth", s.t, {
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
            self.chans.pb("/radar/truth", "SceneUpdate", s.t, lambda: SceneUpdate(entities=tents))

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

    def scan(self, rec: ScanRecord) -> None:

        self.saw_radar()
        lab, t = rec.estimator, rec.t
        self.scene.label(lab)
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
        self.chans.json(f"/tracks/{lab}/state", "uavest.Tracks", t, {
            "t": t, "k": rec.k, "n_confirmed": nc, "n_tentative": len(rows) - nc,
            "tracks": rows, "deleted": [int(i) for i in rec.deleted],
            "resets": int(rec.resets), "wall_us": 1e6 * rec.wall_s})
        dels = [SceneEntityDeletion(timestamp=_ts(t), type=SceneEntityDeletionType.MatchingId,
                                    id=f"{lab}/{i}") for i in rec.deleted]
        self.chans.pb(f"/tracks/{lab}", "SceneUpdate", t,
                 lambda: SceneUpdate(deletions=dels, entities=ents))
        if rec.resets:
            self.chans.log_event(t, "warning", lab, f"{lab}: {rec.resets} track filter reset(s) "
                           f"at scan {rec.k}")
