"""The attitude channels: raw samples (``/imu/*``, ``/mag/*``, ``/reference/*``), each
estimator's ``/attitude/<label>/estimate``, ``.../health`` and ``.../error`` (against the
best reference, slerped at the step times), and the filter health of generic states.

The per-step channels and the raw samples are protobuf messages of uavest's own schema
(:mod:`uavest.sinks.protobuf`), encoded vectorised over a batch of records.
"""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np

from ...engine.records import StepRecord
from ...geometry.navigation import SIZE as NAV_SIZE
from ...geometry.rotation import quat_conj, quat_log, quat_mul, quat_slerp_interp
from .. import protobuf as pb
from .channels import ChannelSet, Scene
from .encode import _g, _n, _ns, _ns_rows, _q, _stack3, _triu
from .frames import Frames

Array = np.ndarray

__all__ = ["AttitudeChannels", "euler_sigma_deg", "quat_to_rpy_deg"]

#: Order of preference among references for the error channels (truth first, as
#: :func:`uavest.eval.attitude.select_reference`).
_REF_ORDER = ("SIMSTATE", "SIM", "ATTITUDE_QUATERNION", "ATTITUDE", "ATT", "vehicle_attitude")

_KIND_RANK = {"truth": 0, "autopilot": 1, "ahrs2": 2}

_DEG = 180.0 / math.pi



def quat_to_rpy_deg(q) -> tuple[float, float, float]:
    """ZYX roll, pitch, yaw (deg) of one quaternion [w, x, y, z] (as
    :func:`uavest.geometry.rotation.quat_to_euler`)."""
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(min(max(2 * (w * y - x * z), -1.0), 1.0))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)



def euler_sigma_deg(q: Array, P: Array) -> Array:
    """1-sigma of ZYX roll, pitch, yaw (deg), (..., 3), of an attitude ``q`` (..., 4) with
    body-frame tangent covariance ``P`` (..., >=3, >=3) (rad^2), linearised: a small body
    rotation d (q' = q Exp(d)) changes the Euler angles by W d with
    ``W = [[1, sin r tan p, cos r tan p], [0, cos r, -sin r], [0, sin r / cos p,
    cos r / cos p]]``, so Cov(euler) = W P W^T (diverges at pitch +-90 deg)."""
    from ...geometry.rotation import quat_to_euler

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



class _Lane:
    """One attitude estimator's channels (made once; the record hot path)."""

    __slots__ = ("label", "t_est", "t_health", "t_err", "t_nav", "est", "health", "err",
                 "nav", "frame", "offset", "key", "last_frame", "buf", "pend", "enc",
                 "enc_dims")

    def __init__(self, label: str, offset: float) -> None:
        self.label = label
        self.t_est = f"/attitude/{label}/estimate"
        self.t_health = f"/attitude/{label}/health"
        self.t_err = f"/attitude/{label}/error"
        self.t_nav = f"/navigation/{label}/estimate"
        self.est = self.health = self.err = self.nav = None
        self.frame = f"body_{label}"
        self.offset = offset
        self.key = "lab:" + label
        self.last_frame: float | None = None
        self.buf: list = []  # records not yet encoded
        self.pend: list[dict] = []  # encoded steps waiting for the reference (row chunks)
        self.enc: dict[str, pb.FixedEncoder] = {}
        self.enc_dims: tuple | None = None



class AttitudeChannels:
    """The attitude estimators' channels, the raw samples and the references (see module
    docstring). ``spacing``: the 3-D view puts estimator i's body ``spacing * (i + 1)`` m
    east of the vehicle (a display offset only)."""

    def __init__(self, chans: ChannelSet, scene: Scene, frames: Frames,
                 spacing: float) -> None:
        self.chans = chans
        self.scene = scene
        self.frames = frames
        self.spacing = spacing
        # raw samples not yet encoded: (kind, source) -> samples ((t, q) for references)
        self._sbuf: dict[tuple[str, str], list] = {}
        self._senc: dict[tuple[str, str], tuple] = {}
        self.raw: dict[tuple[type, str], list] = {}  # (sample type, source) -> its buffer
        self.refs: dict[str, _RefSeries] = {}
        self.ref_frames: dict[str, str] = {}
        self.best_ref: str | None = None
        self.last_step_t: float | None = None
        self.lanes: dict[str, _Lane] = {}
        self.health_lanes: dict[str, _Lane] = {}
        self._drains = 0
        self._nrec = -1  # (the first record sends the markers)

    def raw_buffer(self, s) -> list:
        """The buffer of IMU / magnetometer samples of ``s``'s type and source."""
        key = (type(s), s.source)
        buf = self.raw.get(key)
        if buf is None:
            buf = self.raw[key] = self._sbuf.setdefault(
                ("imu" if type(s).__name__ == "ImuSample" else "mag", s.source), [])
        return buf

    def reference(self, s) -> None:
        self.scene.kind = self.scene.kind or "attitude"
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
        self.frames.frame(frame[5:], frame, s.t, q, 0.0, "ref:" + s.source)

    def flush_samples(self) -> None:
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
                    ch = self.chans.channel(topic, "pb:Imu")
                elif kind == "mag":
                    enc = pb.FixedEncoder("Mag", {"source": source}, {"field_gauss": 3})
                    ch = self.chans.channel(topic, "pb:Mag")
                else:
                    enc = pb.FixedEncoder("AttitudeReference", {
                        "source": source, "kind": self.refs[source].kind}, {"q": 4})
                    ch = self.chans.channel(topic, "pb:AttitudeReference")
                hit = self._senc[key] = (topic, ch, enc)
            topic, ch, enc = hit
            n = len(buf)
            if not self.chans.only_subscribed or ch.has_sinks():
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
                self.chans.log_many(ch, topic, enc.encode(n, cols), _ns_rows(T))
            buf.clear()

    def lane(self, lab: str) -> _Lane:
        """The channels and 3-D placement of attitude estimator ``lab`` (made once)."""
        if lab not in self.scene.labels:
            self.scene.labels.append(lab)
        ln = _Lane(lab, self.spacing * (self.scene.labels.index(lab) + 1))
        ln.est = self.chans.channel(ln.t_est, "pb:AttitudeEstimate")
        ln.health = self.chans.channel(ln.t_health, "pb:FilterHealth")
        self.lanes[lab] = ln
        return ln

    def record(self, rec: StepRecord) -> None:
        """Queue an attitude step's estimate and health (encoded by :meth:`flush_lane`),
        its frame, and its reset on ``/log``."""
        if self.scene.kind != "attitude":
            self.scene.kind = "attitude+radar" if self.scene.kind in ("radar", "attitude+radar") \
                else "attitude"
        lab, t = rec.estimator, rec.t
        ln = self.lanes.get(lab) or self.lane(lab)
        ln.buf.append(rec)
        if rec.reset:
            self.reset_event(rec)
        if len(rec.x) >= NAV_SIZE:
            self.frames.nav_position(lab, rec.x[7:10])
        if self.frames.frame_dt:
            last = ln.last_frame
            if last is None or t - last >= self.frames.frame_dt:
                ln.last_frame = t
                self.frames.frame(lab, ln.frame, t, rec.x[:4].tolist(), ln.offset, ln.key)
        else:
            self.frames.frame(lab, ln.frame, t, rec.x[:4].tolist(), ln.offset, ln.key)
        self._nrec += 1
        if not self._nrec & 31:  # the wall clock read every 32nd record
            self.frames.markers(t, self.ref_frames)
        self.last_step_t = t

    def _encoders(self, ln: _Lane, nx: int, nP: int) -> dict:
        if ln.enc_dims != (nx, nP):
            ln.enc_dims = (nx, nP)
            ln.enc = {
                "est": pb.FixedEncoder("AttitudeEstimate", lengths={
                    "q": 4, "bias_rad_s": 3, "P_triu": nP * (nP + 1) // 2}),
                "health": pb.FixedEncoder("FilterHealth")}
            if nx >= NAV_SIZE:
                ln.enc["nav"] = pb.FixedEncoder("NavigationEstimate", lengths={
                    "velocity_ned_m_s": 3, "position_ned_m": 3, "sigma3_velocity_m_s": 3,
                    "sigma3_position_m": 3, "accel_bias_m_s2": 3})
        return ln.enc

    def flush_lane(self, ln: _Lane) -> None:
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
                self.flush_lane(ln)
            return
        nx, nP = X.shape[1], P.shape[1]
        enc = self._encoders(ln, nx, nP)
        Q = X[:, :4]
        nav = nx >= NAV_SIZE
        if nav:  # the navigation state [q, v, p, bg, ba]: the gyro bias is 10:13
            B = X[:, 10:13]
        else:
            B = X[:, 4:7] if nx >= 7 else np.full((n, 3), math.nan)
        rpy = _rpy_rows(Q)
        P3 = P[:, :3, :3]
        s3 = _sigma3_rows(rpy, P3)
        ns = _ns_rows(T)
        osub = self.chans.only_subscribed
        if not osub or ln.est.has_sinks():
            i, j = _triu(nP)
            self.chans.log_many(ln.est, ln.t_est, enc["est"].encode(n, {
                "t": T, "k": K, "q": Q, "bias_rad_s": B, "rpy_deg": rpy, "sigma3_deg": s3,
                "P_triu": P[:, i, j]}), ns)
        if nav:
            self._flush_nav(ln, enc["nav"], T, K, X, P, ns)
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
            self.chans.log_many(ln.health, ln.t_health, msgs, ns)
        if self.refs:
            ln.pend.append({"t": T, "ns": np.asarray(ns, np.int64), "k": K, "q": Q,
                            "P3": P3, "s3": s3, "rpy": rpy})

    def _flush_nav(self, ln: _Lane, enc: pb.FixedEncoder, T: Array, K: Array, X: Array,
                   P: Array, ns: Array) -> None:
        """``/navigation/<label>/estimate``: velocity (m/s) and position (m), NED in the
        local frame of the first GNSS fix, their 3-sigma bounds and the accelerometer bias
        (m/s^2, body FRD), of a batch of navigation records (tangent order
        ``[dtheta, dv, dp, dbg, dba]``)."""
        if ln.nav is None:
            ln.nav = self.chans.channel(ln.t_nav, "pb:NavigationEstimate")
        if self.chans.only_subscribed and not ln.nav.has_sinks():
            return
        d = np.sqrt(np.clip(np.diagonal(P, axis1=1, axis2=2), 0.0, None))
        self.chans.log_many(ln.nav, ln.t_nav, enc.encode(len(T), {
            "t": T, "k": K, "velocity_ned_m_s": X[:, 4:7], "position_ned_m": X[:, 7:10],
            "sigma3_velocity_m_s": 3.0 * d[:, 3:6], "sigma3_position_m": 3.0 * d[:, 6:9],
            "accel_bias_m_s2": X[:, 13:16]}), ns)

    def _health_fast(self, ln: _Lane, rec: StepRecord, ns: int) -> None:
        ups, dof, nis = [], 0, 0.0
        for u in rec.updates:
            nu = u.nu
            d = nu.size if type(nu) is np.ndarray else int(np.size(nu))
            dof += d
            nis += u.nis
            ups.append('{"kind":%s,"nis":%s,"dof":%d}' % (_q(u.kind), _n(u.nis), d))  # noqa: UP031
        self.chans.log(ln.health, ln.t_health, (
            '{"t":%s,"k":%d,"nis":%s,"nis_dof":%d,"updates":[%s],"reset":%s,'  # noqa: UP031
            '"reason":%s,"resets":%d,"wall_us":%s}' % (
                _n(rec.t), rec.k, _n(float(nis)) if ups else "null", dof, ",".join(ups),
                "true" if rec.reset else "false", _q(rec.reason), int(rec.resets),
                _g(1e6 * rec.wall_s))).encode(), ns)
        if rec.reset:
            self.reset_event(rec)

    def reset_event(self, rec: StepRecord) -> None:
        t, lab = rec.t, rec.estimator
        self.chans.log_event(t, "warning", lab, f"{lab} reset at t = {t:.3f} s (step {rec.k}): "
                       f"{rec.reason or 'divergence guard'}; resets so far {rec.resets}")

    def health(self, topic: str, rec: StepRecord) -> None:
        """``uavest.FilterHealth`` of a step on ``topic`` (and its reset on ``/log``)."""
        ln = self.health_lanes.get(topic)
        if ln is None:
            ln = self.health_lanes[topic] = _Lane(rec.estimator, 0.0)
            ln.t_health = topic
            ln.health = self.chans.channel(topic, "uavest.FilterHealth")
        if not self.chans.only_subscribed or ln.health.has_sinks():
            self._health_fast(ln, rec, _ns(rec.t))
        elif rec.reset:
            self.reset_event(rec)

    def drain(self, final: bool) -> None:
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
                ch = ln.err = self.chans.channel(ln.t_err, "pb:AttitudeError")
            if self.chans.only_subscribed and not ch.has_sinks():
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
            self.chans.log_many(ch, ln.t_err, enc.encode(n, cols), rows["ns"].tolist())
        # later steps come at or after the newest step seen: keep what they may need
        # (trimmed now and then: the interpolation's search does not mind a longer list)
        self._drains += 1
        if final or self._drains % 8 == 0:
            keep = keep_t if keep_t is not None else self.last_step_t
            if keep is not None:
                for ref in self.refs.values():
                    ref.trim(keep)

    def flush_lanes(self) -> None:
        """Encode and log every estimator's buffered records."""
        for ln in self.lanes.values():
            if ln.buf:
                self.flush_lane(ln)
