"""Seeded Monte Carlo of the navigation model (GNSS-aided INS): EKF, UKF and the hybrid
(Cui, Sun and Wen, "A Novel Data Sampling Driven Kalman Filter Is Designed by Combining
the Characteristic Sampling of UKF and the Random Sampling of EnKF", Sensors 2022, as
:mod:`uavest.core.hybrid` implements it) side by side on the same simulated flights
(issue 19 item 4, docs/navigation.md "Where the hybrid earns its place").

A trial is a pure function (:func:`run_trial`): ``(case, filter specs, seed, trial) ->
{label: per-trial metrics}``. Every random draw comes from :func:`uavest.seeding.rng`
streams of ``(seed, trial)``: ``"truth"`` (initial heading, true IMU biases and their
random walk), ``"imu"``, ``"gnss"``, ``"mag"`` (sensor noise), ``"x0"`` (the filters'
common start error) and ``"filter:<label>"`` (a filter's own draws: ensemble members).
So every filter of a trial sees the very same flight and the same start, and trial r is
the same whatever ``--runs`` is.

The flight (:func:`flight`): a multicopter-like vehicle hovers, accelerates, flies
straight legs and coordinated turns at constant height. The truth is analytic on a fine
grid (forward acceleration and yaw rate piecewise constant with linear ramps; speed,
yaw and position integrated by the trapezoid rule); the attitude is the coordinated one
(body z along the negative specific force, so roll and pitch follow from the
acceleration). IMU at ``imu_rate`` (gyro from the attitude increments, specific force
``R^T (a_n - g)``), both with white noise and biases from :class:`NavNoise` (densities,
random walks, initial bias std); GNSS position / velocity at ``gnss_rate``; magnetometer
heading at ``mag_rate``. The filters step at ``filter_rate`` on the mean of the IMU
samples of each step (the rates' mean over the step: the noise density is kept).

Aiding is gated (chi-square at ``gate_prob`` per measurement, on each filter's own
Gaussian estimate: ``S = H P H^T + R``) and rejections are counted. Every filter is
wrapped in :class:`~uavest.core.guard.Guarded`; its resets are counted.

Metrics per filter and trial (:func:`trial_metrics`), in the case's scoring window
unless said otherwise: attitude RMSE (Euler angle differences, deg), 3-D velocity RMSE
(m/s), horizontal position RMSE (m), NEES of the 9 attitude / velocity / position error
dimensions (mean, and the fraction of steps inside the per-step two-sided 95 % band of
chi-square with 9 dof), the time to converge (the first time after which the yaw error
stays below 5 deg to the end of the flight; ``inf`` when the last step's is above),
guard resets (with the guard's reasons), gated measurements and the cost (us per filter
step, timed around the filter's calls only).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.gaussian import Gaussian
from ..core.guard import Guarded, nis_gate
from ..geometry.navigation import NavSpace
from ..geometry.rotation import (
    _log_rows_into,
    _qmul_rows,
    euler_to_quat,
    quat_rotate_inv,
    quat_to_euler,
    wrap_pi,
)
from ..models.attitude import MagHeading
from ..models.navigation import GnssPosition, GnssVelocity, ImuTransition, NavNoise, OnNav
from ..presets import build, resolve_list
from ..seeding import filter_stream, rng

Array = np.ndarray
SP = NavSpace()

#: the yaw error below which a filter counts as converged (and stays), rad
CONVERGED_YAW = math.radians(5.0)
#: the filters' preset: the one ``uavest replay`` uses with the navigation model (hybrid
#: n_cloud = 16, tau = 0.9, re-spread after each shift)
PRESET = "nav"
#: strength of the simulated Earth field, gauss (declination 0)
MAG_STRENGTH = 0.48


@dataclass(frozen=True)
class NavCase:
    """One benchmark case.

    name: short key; title: one line for the table.
    duration: flight length, s (the profile is cut there).
    mag: the filters get magnetometer headings.
    unknown_heading: the true initial yaw is uniform in [-pi, pi) and every filter
        starts at yaw 0 with std ``pi / sqrt(3)`` (the uniform's); otherwise the start
        yaw error is drawn from ``N(0, init_yaw)`` and the filters are told that std.
    outage: (start, end) of a GNSS outage, s, or None.
    mag_disturbance: (start, end, angle rad) of a heading offset of the magnetometer,
        or None.
    window: (start, end) of the scoring window of the RMSE and NEES, s.
    """

    name: str
    title: str
    duration: float
    mag: bool
    unknown_heading: bool = False
    outage: tuple[float, float] | None = None
    mag_disturbance: tuple[float, float, float] | None = None
    window: tuple[float, float] = (0.0, math.inf)


CASES: dict[str, NavCase] = {
    "heading": NavCase(
        "heading", "(a) unknown heading: no magnetometer, true yaw uniform, filters at yaw 0",
        duration=40.0, mag=False, unknown_heading=True, window=(0.0, 40.0)),
    "outage": NavCase(
        "outage", "(b) 30 s GNSS outage (15-45 s), magnetometer on",
        duration=55.0, mag=True, outage=(15.0, 45.0), window=(15.0, 55.0)),
    "magdist": NavCase(
        "magdist", "(c) magnetometer heading off by 30 deg for 20 s (15-35 s)",
        duration=45.0, mag=True, mag_disturbance=(15.0, 35.0, math.radians(30.0)),
        window=(15.0, 45.0)),
}


@dataclass(frozen=True)
class NavSim:
    """Sensor rates (Hz), filter rate (Hz; the IMU, GNSS and magnetometer rates are whole
    multiples / divisors of it: the filter steps on the mean of ``imu_rate /
    filter_rate`` IMU samples, aiding arrives every ``filter_rate / rate`` steps), the
    noise of the simulated sensors and of the filters (one :class:`NavNoise`), the GNSS
    noise (std, m and m/s), the field's inclination (``mag_dip``, deg, down positive;
    64 deg as in central Europe), the sensors whose measurements are gated (``gate``:
    any of "gnss", "mag"; none by default) and the gate probability."""

    imu_rate: int = 200
    filter_rate: int = 25
    gnss_rate: float = 5.0
    mag_rate: float = 12.5
    noise: NavNoise = field(default_factory=NavNoise)
    gnss_pos_std: tuple[float, float, float] = (0.5, 0.5, 1.0)
    gnss_vel_std: float = 0.1
    mag_dip: float = 64.0
    gate: tuple[str, ...] = ()
    gate_prob: float = 0.999

    def __post_init__(self) -> None:
        for a, b in ((self.imu_rate, self.filter_rate), (self.filter_rate, self.gnss_rate),
                     (self.filter_rate, self.mag_rate)):
            if b <= 0 or not float(a / b).is_integer():
                raise ValueError(f"rate {a} Hz is not a whole multiple of {b} Hz")

    def every(self, rate: float) -> int:
        """Filter steps between two samples of a sensor at ``rate`` Hz."""
        return int(round(self.filter_rate / rate))


@dataclass(frozen=True)
class Flight:
    """One simulated flight at the filter's steps: ``t`` (T+1,) s, truth ``x`` (T+1, 16)
    on :class:`NavSpace`, IMU input ``u`` (T, 6) for step k (t_k -> t_k+1, gyro rad/s,
    specific force m/s^2, body FRD), GNSS ``gnss`` {step index: (p NED m, v NED m/s)}
    after step k's predict (outage removed), magnetometer ``mag`` {step index: body
    field, gauss}, and the filters' common prior ``prior``."""

    t: Array
    x: Array
    u: Array
    gnss: dict[int, tuple[Array, Array]]
    mag: dict[int, Array]
    prior: Gaussian


# ----------------------------------------------------------------------------- truth


def _ramped(t: Array, pieces: Sequence[tuple[float, float]], ramp: float) -> Array:
    """A piecewise-constant profile ``pieces`` [(start time s, value)] with linear ramps of
    ``ramp`` s between the values (vectorised over ``t``)."""
    out = np.zeros_like(t)
    prev = 0.0
    for t0, v in pieces:
        out += (v - prev) * np.clip((t - t0) / ramp, 0.0, 1.0)
        prev = v
    return out


#: forward acceleration m/s^2, yaw rate rad/s and down acceleration m/s^2, piecewise
#: [(start s, value)] with ramps: hover 5 s, accelerate to 10 m/s, then S-turns
#: (+-0.3 rad/s, bank ~17 deg) with climbs and descents of ~1.5 m/s (the horizontal
#: acceleration keeps turning in NED and the specific force's magnitude changes, so yaw,
#: tilt and the accelerometer bias are all observable)
ACCEL = ((5.0, 2.0), (10.0, 0.0))
YAW_RATE = ((12.0, 0.3), (18.0, -0.3), (24.0, 0.3), (30.0, -0.3), (36.0, 0.3), (42.0, -0.3),
            (48.0, 0.3), (54.0, 0.0))
DOWN_ACCEL = ((8.0, -1.0), (10.0, 0.0), (16.0, 1.0), (18.0, 0.0), (26.0, -1.0), (28.0, 0.0),
              (34.0, 1.0), (36.0, 0.0), (44.0, -1.0), (46.0, 0.0), (50.0, 1.0), (52.0, 0.0))


def _cumtrapz(y: Array, dt: float, y0: Array | float = 0.0) -> Array:
    out = np.empty_like(y)
    out[0] = 0.0
    np.cumsum(0.5 * dt * (y[1:] + y[:-1]), axis=0, out=out[1:])
    return out + y0


def truth_profile(duration: float, rate: int, yaw0: float, g: float
                  ) -> tuple[Array, Array, Array]:
    """Analytic truth on the grid ``k / rate`` s, k = 0..duration*rate: (t (N,) s,
    x (N, 10) = [q body FRD -> NED, v NED m/s, p NED m], a_n (N, 3) NED m/s^2), for the
    profile :data:`ACCEL` / :data:`YAW_RATE` starting at yaw ``yaw0`` rad with gravity
    ``g`` m/s^2 (module docstring)."""
    N = int(round(duration * rate)) + 1
    t = np.arange(N) / rate
    dt = 1.0 / rate
    along = _ramped(t, ACCEL, 1.0)
    r = _ramped(t, YAW_RATE, 2.0)
    ad = _ramped(t, DOWN_ACCEL, 1.0)
    V = _cumtrapz(along, dt)
    vd = _cumtrapz(ad, dt)
    psi = _cumtrapz(r, dt, yaw0)
    c, s = np.cos(psi), np.sin(psi)
    v = np.stack([V * c, V * s, vd], axis=1)
    a = np.stack([along * c - V * r * s, along * s + V * r * c, ad], axis=1)
    p = _cumtrapz(v, dt, np.zeros(3))
    # coordinated attitude: body z along -(a - g); in the heading frame
    # a - g = (along, V r, a_D - g) = -|s| (sin th cos ph, -sin ph, cos th cos ph)
    sx = along
    sy = V * r
    sz = ad - g
    ns = np.sqrt(sx * sx + sy * sy + sz * sz)
    roll = np.arcsin(sy / ns)
    pitch = np.arctan2(-sx, -sz)
    q = euler_to_quat(roll, pitch, psi)
    return t, np.concatenate([q, v, p], axis=1), a


def flight(case: NavCase, sim: NavSim, seed: int, r: int) -> Flight:
    """The simulated flight of trial ``r`` of ``case`` (module docstring)."""
    n = sim.noise
    tr = ImuTransition(n)
    g_truth, g_imu, g_gnss, g_mag, g_x0 = (rng(seed, r, s) for s in
                                           ("truth", "imu", "gnss", "mag", "x0"))
    yaw0 = g_truth.uniform(-np.pi, np.pi)
    fine = 2 * sim.imu_rate  # IMU samples at the midpoints of the fine grid's pairs
    t_f, x_f, a_f = truth_profile(case.duration, fine, yaw0, tr.g)
    dti = 1.0 / sim.imu_rate
    q = x_f[:, :4]
    # gyro: the attitude increment over each IMU interval (exact truth increment)
    qi = q[0::2]
    dq = _qmul_rows(qi[:-1] * np.array([1.0, -1.0, -1.0, -1.0]), qi[1:])
    w = np.empty((dq.shape[0], 3))
    _log_rows_into(dq, w)
    w /= dti
    qm, am = q[1::2], a_f[1::2]  # at the interval midpoints
    fb = quat_rotate_inv(qm, am - np.array([0.0, 0.0, tr.g]))
    Ni = w.shape[0]
    # biases: initial from the filter prior's std, random walk with the model's density
    bg = (g_truth.normal(size=3) * n.init_gyro_bias
          + np.cumsum(g_truth.normal(size=(Ni, 3)), axis=0) * n.gyro_bias_walk * math.sqrt(dti))
    ba = (g_truth.normal(size=3) * n.init_accel_bias
          + np.cumsum(g_truth.normal(size=(Ni, 3)), axis=0) * n.accel_bias_walk * math.sqrt(dti))
    gyro = w + bg + g_imu.normal(size=(Ni, 3)) * (n.gyro_noise / math.sqrt(dti))
    acc = fb + ba + g_imu.normal(size=(Ni, 3)) * (n.accel_noise / math.sqrt(dti))
    d = sim.imu_rate // sim.filter_rate
    T = Ni // d
    u = np.concatenate([gyro[:T * d].reshape(T, d, 3).mean(1),
                        acc[:T * d].reshape(T, d, 3).mean(1)], axis=1)
    step = 2 * d  # fine-grid points per filter step
    xs = x_f[: T * step + 1: step]
    bgs = np.vstack([bg[:1], bg[d - 1: T * d: d]])
    bas = np.vstack([ba[:1], ba[d - 1: T * d: d]])
    x = np.concatenate([xs, bgs, bas], axis=1)
    t = t_f[: T * step + 1: step]
    # GNSS after the predict to step k (k >= 1), outage removed
    kg = np.arange(0, T + 1, sim.every(sim.gnss_rate))[1:]
    zp = x[kg, 7:10] + g_gnss.normal(size=(kg.size, 3)) * np.array(sim.gnss_pos_std)
    zv = x[kg, 4:7] + g_gnss.normal(size=(kg.size, 3)) * sim.gnss_vel_std
    gnss = {int(k): (zp[i], zv[i]) for i, k in enumerate(kg)
            if case.outage is None or not case.outage[0] <= t[k] < case.outage[1]}
    mag: dict[int, Array] = {}
    if case.mag:
        km = np.arange(0, T + 1, sim.every(sim.mag_rate))[1:]
        delta = g_mag.normal(size=km.size) * n.mag_noise
        if case.mag_disturbance is not None:
            t0, t1, ang = case.mag_disturbance
            delta = delta + np.where((t[km] >= t0) & (t[km] < t1), ang, 0.0)
        dip = math.radians(sim.mag_dip)
        hz, vt = MAG_STRENGTH * math.cos(dip), MAG_STRENGTH * math.sin(dip)
        # the field turned by delta about down: the heading the magnetometer gives
        m_n = np.stack([np.cos(delta) * hz, np.sin(delta) * hz, np.full(km.size, vt)], axis=1)
        m_b = quat_rotate_inv(x[km, :4], m_n)
        mag = {int(k): m_b[i] for i, k in enumerate(km)}
    prior = _prior(case, n, x[0], g_x0)
    return Flight(t, x, u, gnss, mag, prior)


def _prior(case: NavCase, n: NavNoise, x0: Array, g: np.random.Generator) -> Gaussian:
    """The filters' common start: the truth moved by a draw from the prior they are told
    (consistent start), except the unknown-heading case's yaw (filters at yaw 0)."""
    yaw_sd = math.pi / math.sqrt(3.0) if case.unknown_heading else n.init_yaw
    sd = np.array([n.init_tilt] * 2 + [yaw_sd] + [n.init_vel] * 3 + [n.init_pos] * 3
                  + [n.init_gyro_bias] * 3 + [n.init_accel_bias] * 3)
    e = g.normal(size=15) * sd
    if case.unknown_heading:
        e[2] = 0.0
    x = SP.retract(x0, e[None, :])[0]
    if case.unknown_heading:  # yaw 0, the true roll and pitch moved by the tilt draw
        rpy = quat_to_euler(x[:4])
        x[:4] = euler_to_quat(rpy[0], rpy[1], 0.0)
    return Gaussian(x, np.diag(sd**2))


# --------------------------------------------------------------------------- filters


def _gated(f, s, z: Array, model, chi2: float, g: np.random.Generator) -> tuple[object, bool]:
    """Update ``s`` with ``z`` unless its NIS on the filter's Gaussian estimate exceeds
    ``chi2`` (``inf``: no gate, nothing computed); (state, accepted)."""
    if chi2 == math.inf:
        return f.update(s, z, model, g)[0], True
    est = f.estimate(s)
    nu = np.atleast_1d(model.residual(z, model.h(est.x)))
    H = model.H(est.x)
    S = H @ est.P @ H.T + model.R
    try:
        d2 = float(nu @ np.linalg.solve(S, nu))
    except np.linalg.LinAlgError:
        d2 = math.inf
    if not (math.isfinite(d2) and d2 <= chi2):
        return s, False
    return f.update(s, z, model, g)[0], True


def run_filter(f, fl: Flight, sim: NavSim, g: np.random.Generator) -> dict:
    """Run one (guarded) filter over a flight: estimates ``x`` (T+1, 16), ``P`` (T+1,
    15, 15), resets, rejected measurements, seconds inside the filter's calls."""
    n = sim.noise
    tr = ImuTransition(n)
    dt = 1.0 / sim.filter_rate
    Rp = np.diag(np.square(sim.gnss_pos_std))
    Rv = np.eye(3) * sim.gnss_vel_std**2
    Rm = np.array([[n.mag_noise**2]])
    mp, mv = GnssPosition(Rp), GnssVelocity(Rv)
    c3 = nis_gate(3, sim.gate_prob) if "gnss" in sim.gate else math.inf
    c1 = nis_gate(1, sim.gate_prob) if "mag" in sim.gate else math.inf
    T = fl.u.shape[0]
    X = np.empty((T + 1, 16))
    P = np.empty((T + 1, 15, 15))
    sec = time.perf_counter()
    s = f.init(fl.prior, SP, g)
    e = f.estimate(s)
    X[0], P[0] = e.x, e.P
    rejected = 0
    reasons: dict[str, int] = {}

    def note(s) -> None:  # the guard's reason of a reset, without its numbers
        if s.reset:
            why = s.reason.split(":")[0].split(" (")[0]
            reasons[why] = reasons.get(why, 0) + 1

    for k in range(T):
        s = f.predict(s, tr, fl.t[k + 1], dt, fl.u[k], g)
        note(s)
        j = k + 1
        if j in fl.gnss:
            zp, zv = fl.gnss[j]
            s, ok1 = _gated(f, s, zp, mp, c3, g)
            note(s)
            s, ok2 = _gated(f, s, zv, mv, c3, g)
            note(s)
            rejected += (not ok1) + (not ok2)
        if j in fl.mag:
            s, ok = _gated(f, s, np.zeros(1), OnNav(MagHeading(fl.mag[j], Rm)), c1, g)
            note(s)
            rejected += not ok
        e = f.estimate(s)
        X[j], P[j] = e.x, e.P
    sec = time.perf_counter() - sec
    return {"x": X, "P": P, "resets": int(s.resets), "reasons": reasons,
            "rejected": int(rejected), "seconds": sec, "steps": T}


# --------------------------------------------------------------------------- metrics

#: per-step two-sided 95 % band of chi-square with 9 dof
NEES_BAND_9 = (2.7003895, 19.0227678)


def trial_metrics(case: NavCase, fl: Flight, out: dict) -> dict:
    """Per-trial metrics of one filter's run (module docstring)."""
    xe, xt, P = out["x"], fl.x, out["P"]
    de = wrap_pi(quat_to_euler(xe[:, :4]) - quat_to_euler(xt[:, :4]))
    yaw = np.abs(de[:, 2])
    bad = np.nonzero(yaw >= CONVERGED_YAW)[0]
    if bad.size == 0:
        conv = 0.0
    elif bad[-1] == len(yaw) - 1:
        conv = math.inf
    else:
        conv = float(fl.t[bad[-1] + 1])
    w = (fl.t >= case.window[0]) & (fl.t < case.window[1])
    e = SP.local(xe[w], xt[w])[:, :9]
    Pw = P[w][:, :9, :9]
    ne = np.einsum("ti,ti->t", e, np.linalg.solve(Pw, e[..., None])[..., 0])
    ms = np.mean(de[w] ** 2, axis=0)
    return {
        "converge_s": conv,
        "final_yaw_deg": float(np.degrees(yaw[-1])),
        "mse_att": ms,  # rad^2 roll, pitch, yaw
        "mse_vel": float(np.mean(np.sum(e[:, 3:6] ** 2, axis=1))),
        "mse_pos": float(np.mean(np.sum(e[:, 6:8] ** 2, axis=1))),
        "max_pos": float(np.sqrt(np.max(np.sum(e[:, 6:8] ** 2, axis=1)))),
        "nees": float(np.mean(ne)),
        "nees_in": float(np.mean((ne >= NEES_BAND_9[0]) & (ne <= NEES_BAND_9[1]))),
        "resets": out["resets"],
        "reset_reasons": out["reasons"],
        "rejected": out["rejected"],
        "us_per_step": 1e6 * out["seconds"] / out["steps"],
    }


def run_trial(case: NavCase, specs: Sequence[str], seed: int, r: int,
              sim: NavSim | None = None) -> dict[str, dict]:
    """Per-filter metrics of trial ``r`` (a pure function of its arguments, apart from
    ``us_per_step``): every filter of ``specs`` (resolved in the ``nav`` preset,
    wrapped in the guard) on the same flight and start."""
    sim = sim or NavSim()
    fl = flight(case, sim, seed, r)
    out = {}
    for sp in resolve_list(list(specs), PRESET, SP.dim):
        f = Guarded(build(sp))
        res = run_filter(f, fl, sim, rng(seed, r, filter_stream(sp.label)))
        out[sp.label] = trial_metrics(case, fl, res)
    return out


def trial_rows(case: NavCase, specs: Sequence[str], seed: int, trials: Iterable[int],
               sim: NavSim | None = None,
               progress: Callable[[int], None] | None = None) -> list[dict[str, dict]]:
    """:func:`run_trial` for each trial index."""
    rows = []
    for r in trials:
        rows.append(run_trial(case, specs, seed, r, sim))
        if progress:
            progress(r)
    return rows


def aggregate(rows: list[dict[str, dict]], ref: str | None = "ukf") -> dict[str, dict]:
    """The table over trial rows: time to converge (median over all trials, inf counted
    as not converged; mean over the converged), RMSE pooled over the trials (root of the
    mean of per-trial mean squares), NEES mean, fraction in band, resets and rejections
    (totals), divergences (trials not converged at the end), cost (mean us per step and
    the median over trials of the ratio to ``ref``'s in the same trial)."""
    out = {}
    for lab in rows[0]:
        c = [row[lab] for row in rows]
        conv = np.array([x["converge_s"] for x in c])
        ok = np.isfinite(conv)
        att = np.sqrt(np.mean([x["mse_att"] for x in c], axis=0))
        ratio = (float(np.median([x["us_per_step"] / row[ref]["us_per_step"]
                                  for x, row in zip(c, rows, strict=True)]))
                 if ref in rows[0] else math.nan)
        out[lab] = {
            "runs": len(c),
            "converge_median_s": float(np.median(conv)),
            "converge_mean_s": float(np.mean(conv[ok])) if ok.any() else math.inf,
            "not_converged": int((~ok).sum()),
            "roll_deg": float(np.degrees(att[0])),
            "pitch_deg": float(np.degrees(att[1])),
            "yaw_deg": float(np.degrees(att[2])),
            "vel_mps": float(np.sqrt(np.mean([x["mse_vel"] for x in c]))),
            "pos_m": float(np.sqrt(np.mean([x["mse_pos"] for x in c]))),
            "max_pos_m": float(np.median([x["max_pos"] for x in c])),
            "nees_mean": float(np.mean([x["nees"] for x in c])),
            "nees_in_band": float(np.mean([x["nees_in"] for x in c])),
            "resets": int(sum(x["resets"] for x in c)),
            "reset_reasons": _sum_counts(x["reset_reasons"] for x in c),
            "rejected_per_run": float(np.mean([x["rejected"] for x in c])),
            "us_per_step": float(np.mean([x["us_per_step"] for x in c])),
            "cost_vs_ukf": ratio,
        }
    return out


def _sum_counts(ds: Iterable[dict[str, int]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for d in ds:
        for k, v in d.items():
            out[k] = out.get(k, 0) + v
    return out
