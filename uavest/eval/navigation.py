"""Scoring navigation estimates: velocity and position RMSE, NEES per block, airborne part.

:class:`NavScorer` keeps each estimator's step estimates (t, attitude q, and for a
navigation state v NED m/s, p NED m with their covariance blocks) and the references
(attitude truth quaternions; velocities and positions of position sources), and scores
them at the end (:meth:`NavScorer.scores`):

* velocity RMSE (m/s: the root mean square of the error vector's length, 3-D, or
  horizontal when the reference has no vertical speed), horizontal position RMSE (m:
  of the horizontal error's length) and vertical (m; the reference's lat/lon/alt moved
  into the estimate's local NED frame);
* NEES per block against the reference: attitude (3 dof, ``Log(q_est^-1 q_ref)``),
  velocity (3 dof), position (3 dof): the mean and the share of steps inside the
  two-sided 95 % chi-square band [chi2(0.025), chi2(0.975)] (a consistent filter: 0.95;
  an over-confident one falls above it, an over-cautious one below: the shares below and
  above are kept too, 0.025 each for a consistent filter);
* the same over the **airborne** steps: the reference height more than
  :data:`AIRBORNE_M` above its lowest value in the run (the ground the vehicle took off
  from or landed on), with roll/pitch/yaw RMSE (deg) there;
* on request, the same over the **settled** steps: those at least ``settle_s`` seconds
  after the estimator's first step (a start in flight: the part after the alignment's
  transient, which a 30-s whole-run figure is mostly made of).

References are linearly interpolated (slerp for attitude) at step times; a step more
than :data:`MAX_REF_GAP_S` from a reference sample on either side is not scored.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..geometry.rotation import quat_conj, quat_log, quat_mul, quat_slerp_interp
from .attitude import TRUTH_SOURCES, euler_errors_deg

Array = np.ndarray

__all__ = ["AIRBORNE_M", "MAX_REF_GAP_S", "NavScorer", "POSITION_REFS", "choose_position_ref",
           "gyro_bias_trend", "interp_reference", "nees_band"]

#: Height above the run's lowest reference height (m) from which a step is airborne.
AIRBORNE_M = 2.0
#: A step further than this (s) from the reference samples around it is not scored.
MAX_REF_GAP_S = 1.0
#: Position/velocity reference sources by preference (after truth): the autopilot's own
#: fused outputs, which are references and never measurements.
POSITION_REFS = ("GLOBAL_POSITION_INT", "vehicle_global_position", "POS",
                 "LOCAL_POSITION_NED", "vehicle_local_position")


#: :func:`gyro_bias_trend` calls a bias ramping when, on every axis, a line explains this
#: share of its estimate's variance or more, and the line's change over the span is this
#: many times the estimate's own std (its median) or more.
RAMP_R2 = 0.9
RAMP_SIGMAS = 3.0


def gyro_bias_trend(t: Array, bg: Array, sd: Array) -> dict[str, Any] | None:
    """A filter's gyro bias estimate over a run: ``t`` (K,) s, ``bg`` (K, 3) rad/s
    (body FRD), ``sd`` (K, 3) its std. A least-squares line per axis: its slope (deg/s
    per minute), its change over the span (deg/s), the share of the variance it explains
    and the change in units of the estimate's median std; ``ramps`` when every axis is
    such a line (:data:`RAMP_R2`, :data:`RAMP_SIGMAS`): a bias that a random walk follows
    with a lag (docs/navigation.md, "The gyro drift states"). None for fewer than 20
    steps or a span under 10 s."""
    t, bg, sd = np.asarray(t, float), np.asarray(bg, float), np.asarray(sd, float)
    if len(t) < 20 or t[-1] - t[0] < 10.0:
        return None
    tc = t - t.mean()
    slope = (tc @ (bg - bg.mean(axis=0))) / float(tc @ tc)  # rad/s^2 per axis
    resid = bg - bg.mean(axis=0) - np.outer(tc, slope)
    var = bg.var(axis=0)
    r2 = np.where(var > 0, 1.0 - resid.var(axis=0) / np.where(var > 0, var, 1.0), 0.0)
    change = slope * (t[-1] - t[0])
    sigmas = np.abs(change) / np.maximum(np.median(sd, axis=0), 1e-12)
    return {"deg_s_per_min": [float(v) for v in np.degrees(slope) * 60.0],
            "change_deg_s": [float(v) for v in np.degrees(change)],
            "r2": [float(v) for v in r2], "sigmas": [float(v) for v in sigmas],
            "span_s": float(t[-1] - t[0]),
            "ramps": bool(np.all(r2 >= RAMP_R2) and np.all(sigmas >= RAMP_SIGMAS))}


def nees_band(d: int) -> tuple[float, float]:
    """The two-sided 95 % band of chi-square with ``d`` degrees of freedom."""
    from scipy.special import chdtri

    return float(chdtri(d, 0.975)), float(chdtri(d, 0.025))


def choose_position_ref(names: list[str]) -> str | None:
    """Truth first (:data:`~uavest.eval.attitude.TRUTH_SOURCES` in order: ``SIM_STATE``,
    ``SIM``, ``HIL_STATE_QUATERNION``), then :data:`POSITION_REFS` in order."""
    for k in (*TRUTH_SOURCES, *POSITION_REFS):
        if k in names:
            return k
    return None


def interp_reference(t_ref: Array, y: Array, t: Array) -> tuple[Array, Array]:
    """Linear interpolation of the reference rows ``y`` (K, d) sampled at ``t_ref``
    (K,) s at the step times ``t`` (N,) s, and the mask (N,) of the steps the scorer
    scores: inside the reference's span with both neighbouring samples within
    :data:`MAX_REF_GAP_S` (a step in a longer reference gap is not scored). Whether the
    interpolated values are finite is the caller's check. The one interpolation of a
    reference for the scores and for the report's figures."""
    out = np.full((t.shape[0], y.shape[1]), np.nan)
    if t_ref.shape[0] < 2:
        return out, np.zeros(t.shape[0], bool)
    i = np.clip(np.searchsorted(t_ref, t) - 1, 0, t_ref.shape[0] - 2)
    t0, t1 = t_ref[i], t_ref[i + 1]
    s = np.clip((t - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)[:, None]
    out = y[i] * (1 - s) + y[i + 1] * s
    ok = ((t >= t_ref[0]) & (t <= t_ref[-1]) & (t - t0 <= MAX_REF_GAP_S)
          & (t1 - t <= MAX_REF_GAP_S))
    return out, ok


def _nees(e: Array, P: Array) -> Array:
    return np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])


def _block(ne: Array, d: int) -> dict[str, Any]:
    if ne.size == 0:
        return {"mean": None, "in_band95": None, "below_band95": None, "above_band95": None,
                "n": 0}
    lo, hi = nees_band(d)
    return {"mean": float(np.mean(ne)), "in_band95": float(np.mean((ne >= lo) & (ne <= hi))),
            "below_band95": float(np.mean(ne < lo)), "above_band95": float(np.mean(ne > hi)),
            "n": int(ne.size)}


def _rms(e: Array) -> float | None:
    """Root mean square of the lengths of the error rows ``e`` (N, d) (d = 1: of the
    values); None when there are none."""
    return float(np.sqrt(np.mean(np.sum(e * e, axis=-1)))) if e.size else None


class NavScorer:
    """Collects estimates and references during a run; :meth:`scores` at the end."""

    def __init__(self) -> None:
        self.est: dict[str, list[tuple[float, Array, Array]]] = {}
        self.att: dict[str, tuple[list[float], list[Array]]] = {}
        self.pos: dict[str, list[tuple[float, Array, Array, Array]]] = {}
        #: vehicle time (s) before which the estimates' positions are not in the run's
        #: frame (a navigation stream that started unaided before its first GNSS fix:
        #: ``NavStream.fix_from``); None: all are
        self.pos_from: float | None = None

    def add_estimate(self, label: str, t: float, x: Array, P: Array) -> None:
        """One step of estimator ``label``: state ``x`` (attitude 7 or navigation 16)
        and its tangent covariance ``P``."""
        n = 9 if x.shape[0] >= 16 else 3
        self.est.setdefault(label, []).append((t, x[:10].copy(), P[:n, :n].copy()))

    def add_attitude(self, source: str, t: float, q: Array) -> None:
        ts, qs = self.att.setdefault(source, ([], []))
        if not ts or t > ts[-1]:
            ts.append(t)
            qs.append(q)

    def add_position(self, source: str, t: float, ned: Array | None, vel: Array | None,
                     lla: Array | None) -> None:
        """A reference position sample (any part may be None)."""
        rows = self.pos.setdefault(source, [])
        if rows and t <= rows[-1][0]:
            return
        nan3 = np.full(3, np.nan)
        rows.append((t, nan3 if ned is None else np.asarray(ned, float),
                     nan3 if vel is None else np.asarray(vel, float),
                     nan3 if lla is None else np.asarray(lla, float)))

    def position_ref(self) -> str | None:
        """The position/velocity reference source (:func:`choose_position_ref`)."""
        return choose_position_ref([k for k, v in self.pos.items() if len(v) >= 10])

    def scores(self, label: str, att_ref: str | None, frame: Any = None,
               settle_s: float | None = None) -> dict[str, Any]:
        """Scores of ``label`` (module docstring) against the attitude truth ``att_ref``
        (None: no attitude block) and the position reference, its positions moved into
        ``frame`` (a :class:`~uavest.geometry.geodesy.LocalFrame`; None: no position
        block; positions before :attr:`pos_from` are not scored). Keys: ``vel_rmse_ms``,
        ``hpos_rmse_m``, ``vpos_rmse_m``, ``nees`` {attitude, velocity, position: {mean,
        in_band95, n}}, ``airborne`` {t, n, height_above_lowest_m,
        roll/pitch/yaw_rmse_deg, vel/hpos/vpos RMSE, nees}, and with ``settle_s`` (s,
        > 0) ``settled`` {the same keys, ``after_s`` in place of the height} over the
        steps ``settle_s`` or more after ``label``'s first step; only what can be
        scored (no ``settled`` block when the run is not longer than ``settle_s``)."""
        rows = self.est.get(label)
        if not rows:
            return {}
        t = np.array([r[0] for r in rows])
        x = np.array([r[1] for r in rows])
        P = np.array([r[2] for r in rows])
        out: dict[str, Any] = {}
        nees: dict[str, Array] = {}
        masks: dict[str, Array] = {}
        errs: dict[str, Array] = {}
        if att_ref is not None and att_ref in self.att:
            self._attitude_errors(att_ref, t, x, P, nees, masks, errs)
        pref = self.position_ref()
        air = None
        if pref is not None:
            out["position_reference"] = pref
            air = self._position_errors(pref, t, x, P, frame, out, nees, masks, errs)
        dof = {"attitude": 3, "velocity": 3, "position": 3}
        if "velocity" in nees and errs["vel"].shape[1] == 2:
            dof["velocity"] = 2
        out["nees"] = {k: _block(v, dof[k]) for k, v in nees.items()}
        if air is not None and air.any():
            out["airborne"] = {**_window(t, air, nees, masks, errs, dof),
                               "height_above_lowest_m": AIRBORNE_M}
        if settle_s is not None and settle_s > 0:
            late = t >= t[0] + settle_s
            if late.any():
                out["settled"] = {**_window(t, late, nees, masks, errs, dof),
                                  "after_s": float(settle_s)}
        return out

    def _attitude_errors(self, att_ref: str, t: Array, x: Array, P: Array,
                         nees: dict[str, Array], masks: dict[str, Array],
                         errs: dict[str, Array]) -> None:
        """Fill ``nees["attitude"]``, ``masks["attitude"]`` (steps with a reference) and
        ``errs["euler"]`` (deg) from the truth ``att_ref`` interpolated to the steps ``t``
        (s); ``x``/``P`` are the steps' states and covariances."""
        ts, qs = self.att[att_ref]
        qr, ok = quat_slerp_interp(np.array(ts), np.array(qs), t)
        e = quat_log(quat_mul(quat_conj(x[ok, :4]), qr[ok]))
        nees["attitude"], masks["attitude"] = _nees(e, P[ok, :3, :3]), ok
        errs["euler"] = euler_errors_deg(x[ok, :4], qr[ok])

    def _position_errors(self, pref: str, t: Array, x: Array, P: Array, frame: Any,
                         out: dict[str, Any], nees: dict[str, Array],
                         masks: dict[str, Array], errs: dict[str, Array]) -> Array | None:
        """Against the position reference ``pref``: the position (m, NED of ``frame``, or of
        the reference's first valid fix for an attitude run) and velocity (m/s) errors of a
        navigation state, their RMSE in ``out`` and NEES in ``nees``. Returns the airborne
        steps (more than ``AIRBORNE_M`` above the reference's lowest point), None when the
        reference has fewer than 10 valid fixes."""
        nav = P.shape[1] == 9
        air = None
        pr = self.pos[pref]
        tr = np.array([r[0] for r in pr])
        vel = np.array([r[2] for r in pr])
        lla = np.array([r[3] for r in pr])
        good = np.isfinite(lla).all(axis=1)
        if frame is None and good.sum() >= 10:  # an attitude run: the reference's own
            from ..geometry.geodesy import LocalFrame

            frame = LocalFrame(*lla[good][0])
        if frame is not None and good.sum() >= 10:
            ned = np.asarray(frame.geodetic_to_ned(lla[good, 0], lla[good, 1],
                                                   lla[good, 2]), float)
            p_ref, okp = interp_reference(tr[good], ned, t)
            air = okp & (-p_ref[:, 2] > np.nanmin(-ned[:, 2]) + AIRBORNE_M)
            if self.pos_from is not None:
                okp = okp & (t >= self.pos_from)
            if nav:
                e = p_ref[okp] - x[okp, 7:10]
                errs["pos"], masks["position"] = e, okp
                out["hpos_rmse_m"] = _rms(e[:, :2])
                out["vpos_rmse_m"] = _rms(e[:, 2:3])
                nees["position"] = _nees(e, P[okp, 6:9, 6:9])
        if nav:
            v_ref, okv = interp_reference(tr, vel, t)
            okv &= np.isfinite(v_ref[:, :2]).all(axis=1)
            vz = bool(np.isfinite(v_ref[okv, 2]).all())
            cols = [0, 1, 2] if vz else [0, 1]
            e = (v_ref[okv] - x[okv, 4:7])[:, cols]
            errs["vel"], masks["velocity"] = e, okv
            out["vel_rmse_ms"] = _rms(e)
            nees["velocity"] = _nees(e, P[okv][:, 3:6, 3:6][:, cols][:, :, cols])
        return air


def _window(t: Array, air: Array, nees: dict[str, Array], masks: dict[str, Array],
            errs: dict[str, Array], dof: dict[str, int]) -> dict[str, Any]:
    """The ``airborne`` or ``settled`` block of :meth:`NavScorer.scores`: the scores over
    the steps ``air`` only (time span in s, Euler RMSE in deg, velocity/position RMSE,
    NEES)."""
    a: dict[str, Any] = {"t": [float(t[air][0]), float(t[air][-1])], "n": int(air.sum())}
    if "attitude" in masks:
        sel = air[masks["attitude"]]
        eu = errs["euler"][sel]
        if eu.size:
            r = np.sqrt(np.mean(eu * eu, axis=0))
            a.update(roll_rmse_deg=float(r[0]), pitch_rmse_deg=float(r[1]),
                     yaw_rmse_deg=float(r[2]))
    if "velocity" in masks:
        a["vel_rmse_ms"] = _rms(errs["vel"][air[masks["velocity"]]])
    if "position" in masks:
        ep = errs["pos"][air[masks["position"]]]
        a["hpos_rmse_m"] = _rms(ep[:, :2])
        a["vpos_rmse_m"] = _rms(ep[:, 2:3])
    a["nees"] = {k: _block(v[air[masks[k]]], dof[k]) for k, v in nees.items()}
    return a
