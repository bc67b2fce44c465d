"""The navigation stream's alignment arithmetic (:class:`~uavest.engine.navigation.NavStream`,
its module docstring's "Alignment"): the level and yaw from the alignment window, the
vehicle's acceleration from the GNSS velocities, velocity and position priors from a fix,
and the magnetic inclination the start takes. Pure functions of what the stream holds;
the stream keeps the state (the window, the waiting) and records the decisions."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np
from scipy.linalg import block_diag

from ..geometry.rotation import G0, euler_to_quat, quat_rotate, quat_rotate_inv, wrap_pi
from ..models.attitude import inclination_from_params, inclination_from_samples
from ..models.navigation import NavNoise
from .attitude import _Raw
from .history import restore_vars, snapshot_vars
from .nav_aiding import _Aid, good_fix

Array = np.ndarray

#: The start takes the World Magnetic Model's inclination (rad) at the first fix when the
#: alignment window's angle between accelerometer and magnetometer is within this of it:
#: that angle is off by the level's error (the vehicle's acceleration in the window, the
#: accel bias / g; 0.3-0.6 deg on sim_default, whose field is the model's within 0.02
#: deg), and the 3-D field then holds the tilt at that error for the run (pitch 0.30 deg
#: against 0.10). Further apart, the local field is not the model's (the ArduPilot SITL's
#: table field on vtol.tlog: 1.2 deg off it, the window 0.7) and the window is taken.
WMM_INCLINATION_TOL = np.deg2rad(1.0)


class AlignWindow:
    """Where the stream's alignment stands (``waiting`` for a start or a re-alignment,
    ``started`` once, ``unaided``: running before the first fix, ``switched``: the IMU
    changed, so the next start keeps no biases) and what it holds while waiting: the
    steps of the last ``align_s`` s (``recent``), the good fixes' times and velocities
    (``vfix``, for the vehicle's acceleration), and ``why`` it waits. Its state is part of
    the stream's snapshot (:meth:`snapshot`)."""

    def __init__(self) -> None:
        self.recent: deque[_Raw] = deque()
        self.vfix: deque[tuple[float, Array]] = deque(maxlen=64)
        self.switched = False
        self.waiting = True
        self.started = False
        self.unaided = False
        self.why = "no good GNSS fix yet"

    def snapshot(self) -> dict[str, Any]:
        """This moment, for :meth:`restore` (:mod:`uavest.engine.history`)."""
        return snapshot_vars(self)

    def restore(self, snap: dict[str, Any]) -> None:
        restore_vars(self, snap)

    def wait(self, why: str) -> None:
        """Wait (again) for a good fix: the window and the fixes start over."""
        self.waiting = True
        self.recent.clear()
        self.vfix.clear()
        self.why = why

    def add(self, r: _Raw, aids: list[_Aid], align_s: float) -> _Aid | None:
        """Hold the step ``r`` (the window keeps the last ``align_s`` s) and the velocity
        of its last good fix, which is returned (None: no good fix in ``aids``)."""
        if r.a is not None:
            self.recent.append(r)
            while self.recent and self.recent[0].t < r.t - align_s:
                self.recent.popleft()
        fix = good_fix(aids)
        if fix is not None and fix.gnss is not None:
            self.vfix.append((fix.t, np.asarray(fix.gnss.vel_ned, float)))
        return fix

    def mags(self) -> list[Any]:
        """The magnetometer samples of the window (non-zero)."""
        return [x.mag for x in self.recent if x.mag is not None and np.any(x.mag)]

    def done(self) -> None:
        """The start (or re-alignment) is made: no longer waiting, the window emptied."""
        self.waiting = False
        self.started = True
        self.recent.clear()


def level(recent: Iterable[_Raw], a_ned: Array, mags: list[Any], vh: Array,
          noise: NavNoise, declination: float) -> tuple[Array, float, str]:
    """(quaternion, yaw prior std rad, where the yaw came from) from the accelerometer
    mean of the alignment window ``recent`` less the vehicle's acceleration ``a_ned``
    (NED, m/s^2), and the last magnetometer sample of ``mags`` with ``declination`` (rad;
    none: the GNSS course of the horizontal velocity ``vh``, m/s)."""
    n = noise
    acc = np.mean([x.a for x in recent if x.a is not None], axis=0)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    roll = pitch = yaw = 0.0
    syaw, ywhy = n.init_yaw, "the magnetometer"
    for _ in range(3 if np.any(a_ned) else 1):  # tilt <-> body acceleration, refined
        a = quat_rotate_inv(q, a_ned) - acc  # gravity direction in the body
        roll = float(np.arctan2(a[1], a[2]))
        pitch = float(np.arctan2(-a[0], np.hypot(a[1], a[2])))
        if mags:
            q0 = euler_to_quat(np.array(roll), np.array(pitch), np.array(0.0))
            m = quat_rotate(q0, np.asarray(mags[-1], float))
            yaw = float(wrap_pi(declination - np.arctan2(m[1], m[0])))
        else:
            yaw = float(np.arctan2(vh[1], vh[0]))
            speed = float(np.hypot(vh[0], vh[1]))
            syaw, ywhy = n.init_yaw_course, f"the GNSS course at {speed:.1f} m/s"
        q = euler_to_quat(np.array(roll), np.array(pitch), np.array(yaw))
    return q, syaw, ywhy


def gnss_acceleration(vfix: Iterable[tuple[float, Array]], t_from: float) -> Array:
    """The vehicle's own mean acceleration (NED, m/s^2) over the alignment window from
    the GNSS velocities ``vfix`` ((t s, v NED m/s) in time order) at its ends, those from
    ``t_from`` (s) on; zero without two of them 0.05 to 2 s apart. In flight the
    accelerometer is not gravity (two consecutive fixes 0.2 s apart with 0.1 m/s of noise
    leave 0.7 m/s^2, 4 deg)."""
    a_ned = np.zeros(3)
    win = [(t, v) for t, v in vfix if t >= t_from]
    if len(win) >= 2:
        (t1, v1), (t2, v2) = win[0], win[-1]
        if 0.05 < t2 - t1 < 2.0:
            a_ned = np.nan_to_num((v2 - v1) / (t2 - t1))
    return a_ned


def fix_prior(fix: _Aid, dt: float, noise: NavNoise) -> tuple[Array, Array, list[float]]:
    """Velocity (NED m/s), position (NED m, moved ``dt`` s on to the step's time) and
    their six prior variances from a good fix."""
    n, g = noise, fix.gnss
    assert g is not None and fix.ned is not None
    v = np.asarray(g.vel_ned, float).copy()
    vz_ok = bool(np.isfinite(v[2]))
    if not vz_ok:
        v[2] = 0.0
    p = fix.ned + v * dt
    sh, sv = n.gnss_pos_sd(g.h_acc, g.v_acc)
    svel = max(n.gnss_vel_floor, g.s_acc if np.isfinite(g.s_acc) else 0.0)
    return v, p, ([svel**2] * 2 + [(svel if vz_ok else n.init_vel) ** 2]
                  + [sh**2] * 2 + [sv**2])


#: km: an inclination learned farther than this from a run's start is not taken at it
#: (``--aiding-from``; the field's inclination changes by up to about 1 deg per 100 km)
MAG_SITE_KM = 30.0


def start_inclination(recent: Iterable[_Raw], params: dict[str, Any],
                      inclination: float | None, why: str | None, use_wmm: bool
                      ) -> tuple[float | None, str, tuple[float, str] | None]:
    """(inclination rad or None, why, the model's) at the first start: ``inclination``
    when given (with ``why``, else "option"), else the angle between the accelerometer and
    the magnetometer over the alignment window ``recent``, replaced by the World Magnetic
    Model's (from ``params``) when ``use_wmm`` and within :data:`WMM_INCLINATION_TOL` of
    it; None without magnetometer samples in the window. The third is (the model's
    inclination, where it came from) when the window's angle was taken over it (a choice
    a live run judges later), else None."""
    pairs = [(x.a, x.mag) for x in recent if x.mag is not None and x.a is not None]
    why = why or "option"
    if inclination is not None:
        return float(inclination), why, None
    if not pairs:
        return None, why, None
    inc = inclination_from_samples(np.array([p[0] for p in pairs]),
                                   np.array([p[1] for p in pairs]))
    why = "the angle between the accelerometer and the magnetometer at the start"
    wmm, wwhy = (inclination_from_params(params) if use_wmm else (None, ""))
    if wmm is None:
        return inc, why, None
    if abs(wmm - inc) <= WMM_INCLINATION_TOL:
        return wmm, (f"the magnetic model ({wwhy}; the accelerometer's angle "
                     f"{np.degrees(abs(inc - wmm)):.2f} deg from it)"), None
    return inc, why, (float(wmm), wwhy)


#: The heading std is at most this many times the field-direction std (an inclination
#: of 84.3 deg; near the magnetic poles the horizontal field says little).
HEADING_SCALE_MAX = 10.0


def heading_noise_scale(inc: float | None, why: str) -> tuple[float, str]:
    """(scale, why) of ``--mag-mode heading``'s noise: ``mag_noise`` is the std of the
    field's direction per axis (rad), and a heading is the angle of the horizontal part
    alone, ``cos(inc)`` of the field: its std is ``mag_noise / cos(inc)``, at most
    :data:`HEADING_SCALE_MAX` times it. ``inc`` (rad) from :func:`start_inclination` with
    its ``why``; without one (no magnetometer reading in the alignment window) 1."""
    if inc is None or not np.isfinite(inc):
        return 1.0, ("the field-direction noise itself: no inclination at the start (no "
                     "magnetometer reading in the alignment window)")
    c = float(np.cos(inc))
    scale = 1.0 / max(c, 1.0 / HEADING_SCALE_MAX)
    return scale, (f"the field-direction noise over cos({np.degrees(inc):.2f} deg), the "
                   f"horizontal field's share (the inclination: {why})")


def fix_start(q: Array, tilt: float, syaw: float, v: Array, p: Array, pv: list[float],
              noise: NavNoise) -> tuple[Array, Array]:
    """(x, P) of a start at a fix: attitude ``q`` (roll/pitch std ``tilt``, yaw std
    ``syaw`` rad), velocity ``v`` and position ``p`` with their variances ``pv``
    (:func:`fix_prior`), biases zero."""
    n = noise
    x = np.concatenate([q, v, p, np.zeros(6)])
    P = np.diag([tilt**2] * 2 + [syaw**2] + pv
                + [n.init_gyro_bias**2] * 3 + [n.init_accel_bias**2] * 3)
    return with_mag_ref(*with_gyro_drift(*with_gnss_bias(x, P, n, from_fix=True), n), n)


def widen_tilt(g: Any, var: float, gravity: float = G0) -> Any:
    """A running navigation estimate ``g`` (a Gaussian) with ``var`` (rad^2) added to the
    variance of both tilt axes of its attitude tangent (body x and y: the same for every
    yaw) and ``gravity^2 var`` ((m/s^2)^2) to that of its horizontal accelerometer bias
    (body x and y), its mean and the rest of its covariance as they are: for a magnetic
    reference changed mid-run, which had held the tilt to the old field. A tilt error and
    a horizontal accelerometer bias look alike until the vehicle turns, and the filter
    has put part of the old field's pull into its bias: widening the tilt alone left the
    bias to pull the tilt back (an accelerating start of the simulator: the pitch 0.55-1.06
    deg off for 25 s after the change, against under 0.11 deg 4 s after it with both)."""
    P = np.array(g.P, float)
    for i in (0, 1):
        P[i, i] += var
        P[12 + i, 12 + i] += gravity**2 * var
    return type(g)(np.array(g.x, float), P)


def add_gnss_bias(g: Any, noise: NavNoise) -> Any:
    """A running navigation estimate ``g`` (a Gaussian, 16 components, then the gyro
    drift states and the magnetic reference's errors when ``noise`` has them) with the
    GNSS bias states of ``noise`` inserted after the 16: its position has been fitted to
    fixes that carry the bias, so it is taken as a fix's (:func:`with_gnss_bias`,
    ``from_fix``); the states after the 16 keep their estimate and covariances."""
    gx, gP = np.asarray(g.x, float), np.asarray(g.P, float)
    x, P = with_gnss_bias(gx[:16], gP[:15, :15], noise, from_fix=True)
    k = len(gx) - 16  # the gyro drift's and the magnetic reference's after the 16
    if k:
        d = len(P)
        P2 = np.zeros((d + k, d + k))
        P2[:d, :d] = P
        P2[d:, d:] = gP[15:, 15:]
        P2[:15, d:] = gP[:15, 15:]
        P2[d:, :15] = gP[15:, :15]
        x, P = np.concatenate([x, gx[16:]]), P2
    return type(g)(x, P)


def with_gnss_bias(x: Array, P: Array, noise: NavNoise, from_fix: bool) -> tuple[Array, Array]:
    """``(x, P)`` of the 15-dimensional start with the GNSS bias states appended when
    ``noise`` has them (:attr:`NavNoise.gnss_bias`): zero, at their steady std. A position
    ``from_fix`` is the fix less its bias: its variance grows by the bias's and the two
    are anti-correlated (``P_pb = -sigma_b^2``)."""
    if not noise.gnss_bias:
        return x, P
    sb2 = noise.gnss_bias_sd**2
    P2 = np.zeros((18, 18))
    P2[:15, :15] = P
    P2[15:, 15:] = np.diag(sb2)
    if from_fix:
        P2[6:9, 6:9] += np.diag(sb2)
        P2[6:9, 15:18] = P2[15:18, 6:9] = -np.diag(sb2)
    return np.concatenate([x, np.zeros(3)]), P2


def with_gyro_drift(x: Array, P: Array, noise: NavNoise) -> tuple[Array, Array]:
    """``(x, P)`` of a start (with its GNSS bias states, if any) with the gyro drift
    states appended when ``noise`` has them (:attr:`NavNoise.gyro_drift`): zero, at their
    prior std ``init_gyro_drift``."""
    if not noise.gyro_drift:
        return x, P
    return (np.concatenate([x, np.zeros(3)]),
            block_diag(P, np.eye(3) * noise.init_gyro_drift**2))


def with_mag_ref(x: Array, P: Array, noise: NavNoise) -> tuple[Array, Array]:
    """``(x, P)`` of a start (with its GNSS bias states, if any) with the magnetic
    reference's error states appended when ``noise`` has them (:attr:`NavNoise.mag_ref`):
    zero, at their prior std."""
    if not noise.mag_ref:
        return x, P
    return np.concatenate([x, np.zeros(2)]), block_diag(P, np.diag(noise.mag_ref_sd**2))


def kept_biases(space: Any) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """``(x indices, tangent indices)`` of the IMU biases, the gyro drift states and the
    magnetic reference's errors of a navigation ``space``: what a re-alignment keeps of
    the running estimate (``Start.keep_x`` / ``keep_P``; the GNSS bias states are the
    new fix's)."""
    ds = space.drift_slice
    mx = (*range(ds.start, ds.stop), *range(space.size - space.mag, space.size))
    return (*range(10, 16), *mx), (*range(9, 15), *(i - 1 for i in mx))


def unaided_start(q: Array, syaw: float, noise: NavNoise) -> tuple[Array, Array]:
    """(x, P) of a start without a fix: attitude ``q`` (yaw std ``syaw`` rad), velocity
    0 +- ``init_vel``, position at the provisional origin +- ``nofix_pos_noise``, biases
    zero."""
    n = noise
    x = np.concatenate([q, np.zeros(12)])
    P = np.diag([n.init_tilt**2] * 2 + [syaw**2] + [n.init_vel**2] * 3
                + [n.nofix_pos_noise**2] * 3
                + [n.init_gyro_bias**2] * 3 + [n.init_accel_bias**2] * 3)
    return with_mag_ref(*with_gyro_drift(*with_gnss_bias(x, P, n, from_fix=False), n), n)


def anchor_start(v: Array, p: Array, pv: list[float], noise: NavNoise
                 ) -> tuple[Array, Array]:
    """(x, P) of the first fix after an unaided start: velocity ``v`` and position ``p``
    with their variances ``pv`` (:func:`fix_prior`); attitude and biases placeholders
    (the running ones are kept)."""
    n = noise
    x = np.concatenate([[1.0, 0.0, 0.0, 0.0], v, p, np.zeros(6)])
    P = np.diag([n.init_tilt**2] * 3 + pv + [n.init_gyro_bias**2] * 3
                + [n.init_accel_bias**2] * 3)
    return with_mag_ref(*with_gyro_drift(*with_gnss_bias(x, P, n, from_fix=True), n), n)
