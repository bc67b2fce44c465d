"""Radar scenario generator: truths, sensor poses and detections from a typed scenario.

A scenario (``scenarios/radar_*.toml``, ``kind = "radar"``, typed by
:func:`uavest.scenarios.load_typed`) is read by :func:`generate_run`; the filters' models
come from its tables (:func:`motion_model`, :func:`radar_model`, :func:`clutter_box`); see
``docs/tracking.md`` for the format.
World frame ENU (m, m/s); scans at ``t_k = k dt``, k = 1..steps; truth index 0 is the
initial state at t = 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError
from ..models.motion import NearlyConstantVelocity, ncv_matrices
from ..models.radar import RadarMeasurement, SensorPose, euler_zyx, wrap_angle
from ..models.turn import CoordinatedTurn, ct_step

Array = np.ndarray
G = 9.81


@dataclass
class RunData:
    """One Monte Carlo run of a scenario.

    truths: (n_targets, steps + 1, 2 ndim) world [p, v], NaN where the target is absent.
    alive: (n_targets, steps + 1) bool.
    scans: per scan k = 1..steps the detections (n_k, m) (target-originated and clutter,
      shuffled) and their origins (n_k,) (target index, -1 for clutter).
    poses_true / poses_est: per scan the true sensor pose (used to simulate) and the
      pose the tracker is given (ground radar: identical; UAV: estimated attitude).
    x0: a draw from the prior N(m0, P0) (filter mode initialisation; same for all filters).
    """

    truths: Array
    alive: Array
    scans: list[Array]
    origins: list[Array]
    poses_true: list[SensorPose]
    poses_est: list[SensorPose]
    x0: Array | None


# The scenario's tables arrive typed (the frozen dataclasses of uavest.scenarios.schema:
# RadarScenario and its Motion, TrackRadar, RadarPrior, Uav, RadarTarget tables, every
# default filled in there); this layer reads their attributes and imports none of them
# (the scenarios layer sits above it), hence the ``Any`` hints.


def state_dim(ndim: int, motion: Any) -> int:
    """Tangent dimension of the filters' state: 2 ndim, + 1 (turn rate) for ``ct``."""
    return 2 * ndim + (1 if motion.model == "ct" else 0)


def radar_model(radar: Any, ndim: int, n: int) -> RadarMeasurement:
    """The radar of the ``[radar]`` table (noise std in m, deg, m/s; boresight yaw deg)
    for an ``n``-dimensional filter state in ``ndim``-D."""
    rr = radar.sigma_rr
    return RadarMeasurement(
        ndim=ndim,
        state_dim=n,
        sigma_range=float(radar.sigma_range),
        sigma_az=np.deg2rad(float(radar.sigma_az_deg)),
        sigma_el=np.deg2rad(float(radar.sigma_el_deg)),
        sigma_rr=None if rr is None else float(rr),
        pose=SensorPose.fixed(
            ndim, None if radar.position is None else list(radar.position),
            np.deg2rad(float(radar.yaw_deg))
        ),
    )


def motion_model(motion: Any, ndim: int):
    """The filters' motion model of the ``[motion]`` table: ``ncv`` or ``ct`` (``q``
    m^2/s^3, ``q_omega`` rad^2/s^3)."""
    if motion.model == "ct":
        return CoordinatedTurn(ndim, float(motion.q), float(motion.q_omega))
    return NearlyConstantVelocity(ndim, float(motion.q))


def build_models(sc: Any):
    """(motion model, radar model) for the filters of a typed radar scenario."""
    motion = motion_model(sc.motion, sc.ndim)
    return motion, radar_model(sc.radar, sc.ndim, motion.space.dim)


def detection_range(radar: Any) -> float:
    """``radar.r_max`` (m): targets beyond it are not detected, clutter is drawn within."""
    return float(radar.r_max)


def clutter_box(radar: Any, meas: RadarMeasurement) -> tuple[Array, Array]:
    """(lo, hi) of the measurement-space box clutter is drawn uniformly in (range up to
    ``radar.r_max``, full azimuth, elevation; range rate within +-``radar.rr_max`` m/s)."""
    return meas.measurement_box(detection_range(radar), float(radar.rr_max))


def initial_prior(p: Any, n: int) -> tuple[Array, Array]:
    """Filter-mode prior (m0, P0) of the ``[prior]`` table (``mean``, ``std``; a CT state's
    turn rate appended with mean 0 and std ``omega_std``) in an ``n``-dimensional state."""
    if not p.mean or not p.std:
        raise InputError("a filter-mode radar scenario needs prior.mean and prior.std")
    m0 = np.asarray(p.mean, float)
    s0 = np.asarray(p.std, float)
    if m0.size < n:  # CT: append a zero turn rate
        m0 = np.concatenate([m0, np.zeros(n - m0.size)])
        s0 = np.concatenate([s0, np.full(n - s0.size, float(p.omega_std))])
    return m0, np.diag(s0**2)


def prior(sc: Any) -> tuple[Array, Array]:
    """Filter-mode prior (m0, P0) of a typed radar scenario (:func:`initial_prior`)."""
    return initial_prior(sc.prior, state_dim(sc.ndim, sc.motion))


# ------------------------------------------------------------------------------ truths


def _turn_rate(turns, k: int) -> float:
    """Turn rate (rad/s) at step k from ``[[k_start, k_end, deg_per_s], ...]``."""
    for a, b, w in turns or ():
        if a <= k < b:
            return np.deg2rad(float(w))
    return 0.0


def _truth_track(
    start: Array, ndim: int, steps: int, dt: float, turns, q: float, rng, born: int, died: int
) -> tuple[Array, Array]:
    x = np.full((steps + 1, 2 * ndim), np.nan)
    alive = np.zeros(steps + 1, bool)
    _, Q = ncv_matrices(ndim, dt, q)
    L = np.linalg.cholesky(Q) if q > 0 else None
    cur = np.asarray(start, float).copy()
    for k in range(born, min(died, steps) + 1):
        if k > born:
            w = _turn_rate(turns, k - 1)
            P, V = ct_step(cur[None, 0:2], cur[None, ndim : ndim + 2], np.array([w]), dt)
            nxt = cur.copy()
            nxt[0:2], nxt[ndim : ndim + 2] = P[0], V[0]
            if ndim == 3:
                nxt[2] += dt * cur[5]
            if L is not None:
                nxt = nxt + L @ rng.standard_normal(2 * ndim)
            cur = nxt
        x[k], alive[k] = cur, True
    return x, alive


def _uav_poses(u: Any, steps: int, dt: float, rng) -> tuple[list, list]:
    """True and estimated poses of a UAV-carried radar (the ``[uav]`` table ``u``).

    The UAV flies at constant speed and altitude with turn segments ``turns`` (deg/s);
    attitude is yaw = course, pitch 0, roll = coordinated-turn bank atan(v omega / g).
    The radar is body-fixed (FLU). The tracker gets the true position and an *estimated*
    attitude: truth plus white errors of ``attitude_error_deg`` (std, per Euler angle),
    standing in for the attitude filter's estimate."""
    p = np.asarray(u.start, float)
    speed = float(u.speed)
    yaw = np.deg2rad(float(u.yaw_deg))
    err = np.deg2rad(float(u.attitude_error_deg))
    turns = u.turns
    true, est = [], []
    for k in range(1, steps + 1):
        w = _turn_rate(turns, k - 1)
        # advance over (k-1, k]: exact arc
        if abs(w) > 1e-9:
            p = p + speed / w * np.array(
                [np.sin(yaw + w * dt) - np.sin(yaw), np.cos(yaw) - np.cos(yaw + w * dt), 0.0]
            )
        else:
            p = p + speed * dt * np.array([np.cos(yaw), np.sin(yaw), 0.0])
        yaw = yaw + w * dt
        w_now = _turn_rate(turns, k)
        roll = -np.arctan(speed * w_now / G)  # left turn (w > 0) banks left: roll < 0 in FLU
        v = speed * np.array([np.cos(yaw), np.sin(yaw), 0.0])
        R = euler_zyx(yaw, 0.0, roll)
        true.append(SensorPose(p.copy(), R, v))
        e = rng.standard_normal(3) * err
        est.append(SensorPose(p.copy(), euler_zyx(yaw + e[0], e[1], roll + e[2]), v))
    return true, est


def generate_run(sc: Any, rng: np.random.Generator, steps: int | None = None) -> RunData:
    """Truths, poses and detections for one run of a typed radar scenario (all randomness
    from ``rng``; ``steps`` overrides the scenario's)."""
    ndim = sc.ndim
    steps = int(steps or sc.steps)
    dt = float(sc.dt)
    truth_q = sc.motion.truth_noise
    targets = [(t.start, t.turns, t.q, t.born, t.died) for t in sc.targets]
    x0 = None
    if sc.mode == "filter":
        m0, P0 = prior(sc)
        n = 2 * ndim
        tgt = targets[0] if targets else ((), (), None, 0, None)
        start = np.asarray(tgt[0] or m0[:n], float)
        x0 = m0 + np.linalg.cholesky(P0) @ rng.standard_normal(m0.size)
        targets = [(start, *tgt[1:])]
    T, A = [], []
    for i, (start, turns, q, born, died) in enumerate(targets):
        if len(start) != 2 * ndim:
            raise InputError(f"targets[{i}].start = {list(start)!r}: must be {2 * ndim} "
                             f"numbers (the state [position, velocity] in {ndim}-D)")
        x, a = _truth_track(
            np.asarray(start, float), ndim, steps, dt, turns,
            float(truth_q if q is None else q), rng, int(born),
            int(steps if died is None else died),
        )
        T.append(x)
        A.append(a)
    truths = np.stack(T) if T else np.zeros((0, steps + 1, 2 * ndim))
    alive = np.stack(A) if A else np.zeros((0, steps + 1), bool)

    r = sc.radar
    radar = radar_model(r, ndim, state_dim(ndim, sc.motion))
    if r.platform == "uav":
        poses_true, poses_est = _uav_poses(sc.uav, steps, dt, rng)
    else:
        poses_true = poses_est = [radar.pose] * steps
    pd = float(r.pd)
    lam = float(r.clutter_rate)
    r_max = detection_range(r)
    lo, hi = clutter_box(r, radar)
    missed = sc.missed  # [[target, k_start, k_end]]: forced Pd = 0
    scans, origins = [], []
    for k in range(1, steps + 1):
        meas = radar.with_pose(poses_true[k - 1])
        idx = np.flatnonzero(alive[:, k])
        if idx.size:
            det = rng.random(idx.size) < pd
            for j, i in enumerate(idx):
                if any(int(t) == i and a <= k < b for t, a, b in missed):
                    det[j] = False
            idx = idx[det]
        Zt = meas.sample(truths[idx, k], rng) if idx.size else np.zeros((0, radar.dim))
        if idx.size:
            keep = Zt[:, 0] <= r_max
            Zt, idx = Zt[keep], idx[keep]
        nc = rng.poisson(lam) if lam > 0 else 0
        Zc = lo + (hi - lo) * rng.random((nc, radar.dim))
        Z = np.vstack([Zt, Zc])
        o = np.concatenate([idx, -np.ones(nc, int)])
        perm = rng.permutation(len(o))
        Z, o = Z[perm], o[perm]
        Z[:, 1] = wrap_angle(Z[:, 1])
        scans.append(Z)
        origins.append(o)
    return RunData(truths, alive, scans, origins, poses_true, poses_est, x0)


__all__ = [
    "RunData", "build_models", "clutter_box", "detection_range",
    "generate_run", "initial_prior", "motion_model", "prior", "radar_model", "state_dim",
]


# ------------------------------------------------------------------------------ checks
MAX_CLUTTER_PER_SCAN = 1e4  # mean false alarms per scan beyond which a run would not fit
MAX_DETECTIONS = 2e7  # mean detections (clutter) over the whole job that are allowed
