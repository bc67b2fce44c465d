"""Radar scenario generator: truths, sensor poses and detections from a scenario dict.

A scenario (``scenarios/radar_*.toml``, ``kind = "radar"``) is read by
:func:`build_models` and :func:`generate_run`; see ``docs/tracking.md`` for the format.
World frame ENU (m, m/s); scans at ``t_k = k dt``, k = 1..steps; truth index 0 is the
initial state at t = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def _get(sc: dict, table: str, key: str, default):
    return sc.get(table, {}).get(key, default)


def radar_model(sc: dict) -> RadarMeasurement:
    """The scenario's radar (noise from ``[radar]``; angles given in degrees)."""
    ndim = int(sc.get("ndim", 2))
    r = sc.get("radar", {})
    rr = r.get("sigma_rr")
    return RadarMeasurement(
        ndim=ndim,
        state_dim=state_dim(sc),
        sigma_range=float(r.get("sigma_range", 10.0)),
        sigma_az=np.deg2rad(float(r.get("sigma_az_deg", 1.0))),
        sigma_el=np.deg2rad(float(r.get("sigma_el_deg", 1.0))),
        sigma_rr=None if rr is None else float(rr),
        pose=SensorPose.fixed(
            ndim, r.get("position"), np.deg2rad(float(r.get("yaw_deg", 0.0)))
        ),
    )


def state_dim(sc: dict) -> int:
    ndim = int(sc.get("ndim", 2))
    return 2 * ndim + (1 if _get(sc, "motion", "model", "ncv") == "ct" else 0)


def motion_model(sc: dict):
    """The filters' motion model: ``ncv`` or ``ct`` (``[motion] model``, ``q``,
    ``q_omega``)."""
    ndim = int(sc.get("ndim", 2))
    m = sc.get("motion", {})
    q = float(m.get("q", 0.5))
    if m.get("model", "ncv") == "ct":
        return CoordinatedTurn(ndim, q, float(m.get("q_omega", 1e-4)))
    return NearlyConstantVelocity(ndim, q)


def build_models(sc: dict):
    """(motion model, radar model) for the filters."""
    return motion_model(sc), radar_model(sc)


def detection_range(sc: dict) -> float:
    """``radar.r_max`` (m): targets beyond it are not detected, clutter is drawn within."""
    return float(sc.get("radar", {}).get("r_max", 20000.0))


def clutter_box(sc: dict, radar: RadarMeasurement) -> tuple[Array, Array]:
    """(lo, hi) of the measurement-space box clutter is drawn uniformly in (range up to
    ``r_max``, full azimuth, elevation; range rate within +-``rr_max`` m/s)."""
    rr_max = float(sc.get("radar", {}).get("rr_max", 100.0))
    return radar.measurement_box(detection_range(sc), rr_max)


def prior(sc: dict) -> tuple[Array, Array]:
    """Filter-mode prior (m0, P0) in the filter's state space (``[prior] mean, std``)."""
    p = sc.get("prior", {})
    m0 = np.asarray(p["mean"], float)
    s0 = np.asarray(p["std"], float)
    n = state_dim(sc)
    if m0.size < n:  # CT: append a zero turn rate
        m0 = np.concatenate([m0, np.zeros(n - m0.size)])
        s0 = np.concatenate([s0, np.full(n - s0.size, float(p.get("omega_std", 0.05)))])
    return m0, np.diag(s0**2)


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


def _uav_poses(sc: dict, steps: int, dt: float, rng) -> tuple[list, list]:
    """True and estimated poses of a UAV-carried radar (``[uav]`` table).

    The UAV flies at constant speed and altitude with turn segments ``turns`` (deg/s);
    attitude is yaw = course, pitch 0, roll = coordinated-turn bank atan(v omega / g).
    The radar is body-fixed (FLU). The tracker gets the true position and an *estimated*
    attitude: truth plus white errors of ``attitude_error_deg`` (std, per Euler angle),
    standing in for the attitude filter's estimate."""
    u = sc.get("uav", {})
    p = np.asarray(u.get("start", [0.0, 0.0, 500.0]), float)
    speed = float(u.get("speed", 30.0))
    yaw = np.deg2rad(float(u.get("yaw_deg", 0.0)))
    err = np.deg2rad(float(u.get("attitude_error_deg", 0.2)))
    turns = u.get("turns", [])
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


def generate_run(sc: dict, rng: np.random.Generator, steps: int | None = None) -> RunData:
    """Truths, poses and detections for one run (all randomness from ``rng``)."""
    ndim = int(sc.get("ndim", 2))
    steps = int(steps or sc.get("steps", 100))
    dt = float(sc.get("dt", 1.0))
    mode = sc.get("mode", "tracker")
    m = sc.get("motion", {})
    truth_q = float(m.get("truth_q", m.get("q", 0.5)))
    targets = sc.get("targets", [])
    x0 = None
    if mode == "filter":
        m0, P0 = prior(sc)
        n = 2 * ndim
        tgt = targets[0] if targets else {}
        start = np.asarray(tgt.get("start", m0[:n]), float)
        x0 = m0 + np.linalg.cholesky(P0) @ rng.standard_normal(m0.size)
        targets = [{**tgt, "start": start}]
    T, A = [], []
    for tg in targets:
        x, a = _truth_track(
            np.asarray(tg["start"], float), ndim, steps, dt, tg.get("turns"),
            float(tg.get("q", truth_q)), rng, int(tg.get("born", 0)),
            int(tg.get("died", steps)),
        )
        T.append(x)
        A.append(a)
    truths = np.stack(T) if T else np.zeros((0, steps + 1, 2 * ndim))
    alive = np.stack(A) if A else np.zeros((0, steps + 1), bool)

    radar = radar_model(sc)
    r = sc.get("radar", {})
    if r.get("platform", "ground") == "uav":
        poses_true, poses_est = _uav_poses(sc, steps, dt, rng)
    else:
        poses_true = poses_est = [radar.pose] * steps
    pd = float(r.get("pd", 1.0))
    lam = float(r.get("clutter_rate", 0.0))
    r_max = detection_range(sc)
    lo, hi = clutter_box(sc, radar)
    missed = sc.get("missed", [])  # [[target, k_start, k_end]]: forced Pd = 0
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
    "RunData", "build_models", "generate_run", "motion_model", "prior", "radar_model",
    "state_dim",
]


# ------------------------------------------------------------------------------ checks
MOTION_MODELS = ("ncv", "ct")
MAX_CLUTTER_PER_SCAN = 1e4  # mean false alarms per scan beyond which a run would not fit
MAX_DETECTIONS = 2e7  # mean detections (clutter) over the whole job that are allowed


def check_radar(sc: dict, where: str, fail) -> None:
    """Ranges and shapes of a radar scenario's values (``fail(msg)`` raises)."""
    ndim = sc.get("ndim", 2)
    if ndim not in (2, 3) or isinstance(ndim, bool):
        fail(f"{where}ndim = {ndim!r}: must be 2 or 3")
    m = sc.get("motion", {})
    if not isinstance(m, dict):
        fail(f"{where}motion must be a table")
    model = m.get("model", "ncv")
    if model not in MOTION_MODELS:
        fail(f"{where}motion.model = {model!r}: unknown motion model; known: "
             f"{', '.join(MOTION_MODELS)}")
    r = sc.get("radar", {})
    if not isinstance(r, dict):
        fail(f"{where}radar must be a table")
    pd = r.get("pd", 1.0)
    if not (isinstance(pd, int | float) and 0.0 < pd <= 1.0) or isinstance(pd, bool):
        fail(f"{where}radar.pd = {pd!r}: must be a probability in (0, 1]")
    lam = r.get("clutter_rate", 0.0)
    if not isinstance(lam, int | float) or isinstance(lam, bool) or lam < 0:
        fail(f"{where}radar.clutter_rate = {lam!r}: must be a number >= 0 (false alarms "
             "per scan)")
    if lam > MAX_CLUTTER_PER_SCAN:
        gb = lam * 8 * 8 / 1e9
        fail(f"{where}radar.clutter_rate = {lam:g}: about {gb:.2g} GB of detections per "
             f"scan before association; at most {MAX_CLUTTER_PER_SCAN:g} per scan is "
             "supported")
    n = 2 * ndim
    p = sc.get("prior", {})
    if isinstance(p, dict):
        for key in ("mean", "std"):
            if key in p:
                v = p[key]
                if not isinstance(v, list) or len(v) not in (n, n + 1):
                    fail(f"{where}prior.{key} = {v!r}: must be a list of {n} numbers "
                         f"(the state [position, velocity] in {ndim}-D)")
        if "std" in p and any(x < 0 for x in p["std"] if isinstance(x, int | float)):
            fail(f"{where}prior.std = {p['std']!r}: standard deviations must be >= 0")
    t = sc.get("tracker", {})
    if isinstance(t, dict):
        for k in ("confirm_m", "confirm_n", "delete_misses"):
            v = t.get(k, 1)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                fail(f"{where}tracker.{k} = {v!r}: must be an integer >= 1")
        gp = t.get("gate_prob", 0.5)
        if not (isinstance(gp, int | float) and 0.0 < gp < 1.0):
            fail(f"{where}tracker.gate_prob = {gp!r}: must be a probability in (0, 1)")
