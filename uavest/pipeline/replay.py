"""Replay a flight log through attitude filters side by side (``uavest replay``).

Pipeline: :func:`uavest.ingest.read_log` -> :func:`build_steps` (filter steps from the IMU
stream) -> one :class:`_Run` per filter (each a :class:`uavest.core.Guarded` filter on the
attitude models of :mod:`uavest.models.attitude`) -> optional RTS smoothing
(:mod:`uavest.pipeline.smooth`) -> scoring against the reference
(:mod:`uavest.eval.attitude`).

Filter steps. A step k covers (t_{k-1}, t_k]; it predicts with the gyro over that interval
and then updates with the accelerometer (mean specific force of the step) and the latest
magnetometer sample of the step, if any. Two ways of turning gyro samples into the step's
rate, chosen by ``integration``:

* ``"hold"``: each sample is the mean rate over the interval ending at it (integrated /
  filtered full-rate IMUs: PX4 ``sensor_combined``, DataFlash ``IMU``); consecutive
  samples are pre-integrated exactly (product of their rotations) when the filter runs
  slower than the IMU (``rate_hz``).
* ``"trapezoid"``: samples are instantaneous rates (MAVLink ``RAW_IMU`` streamed at a
  few Hz): the step uses the mean of the rates at both ends.

``"auto"`` picks trapezoid below 20 Hz, else hold. ``rate_hz`` (default
:data:`DEFAULT_MAX_RATE_HZ`) caps the filter rate; ``rate_hz=0`` runs at the IMU rate.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core import EKF, ETKF, KF, UKF, EnKF, Ensemble, Gaussian, Guarded, make_filter
from ..core.registry import make_filter_in_context, split_filter_list
from ..eval.attitude import nees_attitude, rmse_deg, select_reference
from ..geometry.rotation import (
    AttitudeSpace,
    quat_exp,
    quat_log,
    quat_mul,
    quat_rotate,
    quat_slerp_interp,
)
from ..models.attitude import (
    AttitudeNoise,
    GravityDirection,
    GyroTransition,
    MagField,
    MagHeading,
    Stacked,
    declination_from_params,
    inclination_from_samples,
    initial_attitude,
    mag_reference,
    noise_for_source,
)
from .smooth import ensemble_cross, rts_backward

Array = np.ndarray

__all__ = [
    "DEFAULT_FILTERS",
    "DEFAULT_MAX_RATE_HZ",
    "ReplayConfig",
    "Steps",
    "add_replay_parser",
    "build_steps",
    "replay",
    "run_filters",
]

DEFAULT_FILTERS = ("ekf", "ukf", "hybrid")
DEFAULT_MAX_RATE_HZ = 25.0
#: Attitude defaults for the hybrid and hybrid_sh (spec parameters override them): cloud
#: size M = 13 * (n_cloud + 1) = 221 members, and tau = 0.9 (90 % of each measurement by
#: the EnKF shift, 10 % by the confidence weights). Both were chosen on vtol.tlog, which is
#: also the log the results are scored on (docs/attitude.md gives the sweep): over seeds
#: 0-3, tau = 0.3 is overconfident (NEES 5-7) and worse, tau = 0.6 in between; n_cloud = 8
#: let filtered yaw exceed 4 degrees on one seed of four, 16 on none.
HYBRID_ATTITUDE_DEFAULTS = {"n_cloud": 16, "tau": 0.9}


@dataclass(frozen=True)
class Steps:
    """Filter steps built from a log. ``t`` (J+1,) s: t[0] the initial time, step k ends at
    t[k]; ``dt`` (J,) s; ``gyro`` (J, 3) rad/s mean rate of each step (body FRD, bias not
    removed); ``accel`` (J, 3) m/s^2 mean specific force; ``mag`` (J, 3) gauss latest
    field in the step or NaN; ``accel0``/``mag0`` the samples used for initialisation."""

    t: Array
    dt: Array
    gyro: Array
    accel: Array
    mag: Array
    accel0: Array
    mag0: Array | None
    integration: str
    factor: int
    accel_ned: Array | None = None  # (J, 3) m/s^2 NED vehicle acceleration or NaN


def velocity_acceleration(
    t_v: Array, vel_ned: Array, t: Array, max_gap: float = 1.0
) -> Array:
    """Causal vehicle acceleration (m/s^2, NED) at times ``t`` from a velocity series:
    backward difference of the last two velocity samples at or before each time
    (NaN where there are none, or they are more than ``max_gap`` s apart)."""
    out = np.full((t.shape[0], 3), np.nan)
    ok_v = np.isfinite(vel_ned).all(axis=1)
    t_v, vel_ned = t_v[ok_v], vel_ned[ok_v]
    if t_v.shape[0] < 2:
        return out
    i = np.searchsorted(t_v, t, side="right") - 1
    ok = i >= 1
    i1 = np.where(ok, i, 1)
    dtv = t_v[i1] - t_v[i1 - 1]
    ok &= (dtv > 1e-3) & (dtv <= max_gap) & (t - t_v[i1] <= max_gap)
    out[ok] = (vel_ned[i1[ok]] - vel_ned[i1[ok] - 1]) / dtv[ok, None]
    return out


@dataclass
class ReplayConfig:
    """Options of :func:`replay` (see the CLI help for meanings)."""

    filters: tuple[str, ...] = DEFAULT_FILTERS
    start: float | None = None
    end: float | None = None
    smooth: bool = False
    seed: int = 0
    rate_hz: float | None = None  # None -> DEFAULT_MAX_RATE_HZ cap; 0 -> IMU rate
    integration: str = "auto"
    declination: float | None = None  # rad; None -> log params, else 0
    noise: dict = field(default_factory=dict)  # AttitudeNoise overrides
    imu: str | None = None
    use_mag: bool = True
    accel_comp: str = "auto"  # "auto": velocity-based if the log has velocity; "none"
    mag_mode: str = "field"  # "field" (3-D direction) or "heading" (horizontal only)
    mag_delay: float = 0.0  # s, magnetometer sample age (see run_filters)


def _preintegrate(t: Array, gyro: Array, edges: Array) -> Array:
    """Mean rate over each (t[edges[k-1]], t[edges[k]]] from held samples (exact product
    of per-sample rotations), vectorised over steps; returns (len(edges)-1, 3)."""
    dts = np.diff(t, prepend=t[0])
    dq = quat_exp(gyro * dts[:, None])
    J = len(edges) - 1
    q = np.tile([1.0, 0.0, 0.0, 0.0], (J, 1))
    lo, hi = edges[:-1] + 1, edges[1:] + 1
    span = int(np.max(hi - lo)) if J else 0
    for o in range(span):
        i = lo + o
        ok = i < hi
        if ok.all():
            q = quat_mul(q, dq[i])
        else:
            q[ok] = quat_mul(q[ok], dq[i[ok]])
    dtk = t[edges[1:]] - t[edges[:-1]]
    return quat_log(q) / np.maximum(dtk, 1e-12)[:, None]


def build_steps(
    t: Array,
    gyro: Array,
    accel: Array,
    mag_t: Array | None = None,
    mag_field: Array | None = None,
    rate_hz: float | None = None,
    integration: str = "auto",
) -> Steps:
    """Filter steps from IMU arrays (t s, gyro rad/s, accel m/s^2, body FRD) and an
    optional magnetometer (t s, field gauss). See the module docstring."""
    N = t.shape[0]
    if N < 2:
        raise ValueError(f"need at least 2 IMU samples to replay, got {N}")
    rate = (N - 1) / max(float(t[-1] - t[0]), 1e-9)
    if integration == "auto":
        integration = "trapezoid" if rate < 20.0 else "hold"
    if integration not in ("hold", "trapezoid"):
        raise ValueError(f"integration must be auto, hold or trapezoid, not {integration!r}")
    cap = DEFAULT_MAX_RATE_HZ if rate_hz is None else float(rate_hz)
    factor = 1 if cap <= 0 or integration == "trapezoid" else max(1, round(rate / cap))
    edges = np.arange(0, N, factor)
    if edges[-1] != N - 1:
        edges = np.append(edges, N - 1)
    te = t[edges]
    if integration == "trapezoid":
        w = 0.5 * (gyro[edges[:-1]] + gyro[edges[1:]])
        acc = accel[edges[1:]]
    else:
        w = _preintegrate(t, gyro, edges)
        cs = np.vstack([np.zeros(3), np.cumsum(accel, axis=0)])
        acc = (cs[edges[1:] + 1] - cs[edges[:-1] + 1]) / np.diff(edges)[:, None]
    J = len(edges) - 1
    mag = np.full((J, 3), np.nan)
    mag0 = None
    if mag_t is not None and mag_field is not None and len(mag_t):
        idx = np.searchsorted(mag_t, te[1:], side="right") - 1
        ok = (idx >= 0) & (mag_t[np.maximum(idx, 0)] > te[:-1])
        mag[ok] = mag_field[idx[ok]]
        i0 = int(np.searchsorted(mag_t, te[0], side="right")) - 1
        mag0 = mag_field[max(i0, 0)]
    return Steps(te, np.diff(te), w, acc, mag, accel[0], mag0, integration, factor)


class _Run:
    """One filter's forward pass with the records the smoother needs."""

    def __init__(self, spec: str, prior: Gaussian, J: int, rng, smooth: bool) -> None:
        self.label = spec
        self.kind = spec.split("(")[0].strip()
        self.f = Guarded(make_filter_in_context(spec, HYBRID_ATTITUDE_DEFAULTS))
        self.space = AttitudeSpace()
        self.rng = rng
        self.s = self.f.init(prior, self.space, rng)
        self.smooth = smooth
        self.x = np.empty((J + 1, 7))
        self.P = np.empty((J + 1, 6, 6))
        self.x[0], self.P[0] = prior.x, prior.P
        if smooth:
            self.xp = self.x.copy()
            self.Pp = self.P.copy()
            self.C = np.zeros((J + 1, 6, 6))
        self.seconds = 0.0
        self.smooth_seconds = 0.0

    def step(self, k: int, model, t, dt, u, meas) -> None:
        c0 = time.perf_counter()
        s0 = self.s
        self.s = self.f.predict(s0, model, t, dt, u, self.rng)
        if self.smooth:
            c1 = time.perf_counter()
            self._record_cross(k, s0, model, t, dt, u)
            c0 += time.perf_counter() - c1
        for z, m in meas:
            self.s, _ = self.f.update(self.s, z, m, self.rng)
        # after an update the guard has just checked (and stored) this very estimate
        g = self.s.last_good if meas and not self.s.reset else self.f.estimate(self.s)
        self.x[k], self.P[k] = g.x, g.P
        self.seconds += time.perf_counter() - c0

    def _record_cross(self, k: int, s0, model, t, dt, u) -> None:
        c1 = time.perf_counter()
        gf = Gaussian(self.x[k - 1], self.P[k - 1])
        core, inner0 = _unwrap(self.f, s0)
        _, inner1 = _unwrap(self.f, self.s)
        gp = self.f.estimate(self.s)
        if isinstance(core, (EKF, KF)) and not self.s.reset:
            C = gf.P @ model.F(gf.x, t, dt, u).T
        elif (
            isinstance(inner0, Ensemble)
            and isinstance(inner1, Ensemble)
            and not self.s.reset
            and inner0.M == inner1.M
            and _keeps_members(core, inner0)
        ):
            C = ensemble_cross(inner0, inner1, gf.x, gp.x)
        else:  # sigma-point cross-covariance (UKF, and fallback for the others)
            ukf = core if isinstance(core, UKF) else UKF()
            gp, C = ukf.predict_cross(gf, model, t, dt, u)
        self.xp[k], self.Pp[k], self.C[k] = gp.x, gp.P, C
        self.smooth_seconds += time.perf_counter() - c1

    def smoothed(self) -> tuple[Array, Array]:
        c0 = time.perf_counter()
        out = rts_backward(self.space, self.x, self.P, self.xp, self.Pp, self.C)
        self.smooth_seconds += time.perf_counter() - c0
        return out

    @property
    def resets(self) -> int:
        return int(self.s.resets)


def _unwrap(f, s):
    """The innermost filter of wrappers (Guarded, SageHusa: ``.filter``) and its state."""
    while hasattr(f, "filter"):
        f, s = f.filter, s.inner
    return f, s


def _keeps_members(f, E: Ensemble) -> bool:
    """True if ``f.predict(E)`` propagates these very members (row j stays member j), so
    the member-wise cross-covariance is meaningful. Filters that know ask themselves
    (:meth:`uavest.core.Hybrid.keeps_members`); EnKF/ETKF always propagate every member;
    any other (e.g. a resampling PF) is not trusted and gets the sigma-point fallback."""
    keeps = getattr(f, "keeps_members", None)
    if keeps is not None:
        return bool(keeps(E))
    return isinstance(f, (EnKF, ETKF))


def _progress(i: int, n: int) -> None:
    w = 30
    done = int(w * i / max(n, 1))
    sys.stderr.write(f"\rreplay [{'#' * done}{'.' * (w - done)}] {i}/{n}")
    if i >= n:
        sys.stderr.write("\n")
    sys.stderr.flush()


def run_filters(
    steps: Steps,
    specs: tuple[str, ...] | list[str],
    noise: AttitudeNoise,
    declination: float = 0.0,
    seed: int = 0,
    smooth: bool = False,
    use_mag: bool = True,
    progress: bool = False,
    mag_mode: str = "field",
    mag_delay: float = 0.0,
) -> tuple[list[_Run], float]:
    """Run the filters side by side over ``steps``; returns (runs, wall seconds).

    All filters see the same measurement models. The prior: roll/pitch from the first
    accel sample, yaw from the first magnetometer sample (declination applied), zero
    bias, covariance from ``noise.init_*``. ``mag_mode`` "field" uses the 3-D field
    direction with the inclination estimated from the first second of accel+mag samples
    (no reference used), "heading" only its horizontal projection. ``mag_delay`` (s):
    the magnetometer sample is taken as that much older than its time stamp and rotated
    forward by the step's gyro rate, ``m_now = Exp(-omega * delay) m`` (body frame).
    """
    if mag_mode not in ("field", "heading"):
        raise ValueError(f"mag_mode must be field or heading, not {mag_mode!r}")
    mref = None
    if use_mag and mag_mode == "field":
        first = (steps.t[1:] <= steps.t[0] + 1.0) & np.isfinite(steps.mag[:, 0])
        if steps.mag0 is not None:
            acc = np.vstack([steps.accel0, steps.accel[first]])
            fld = np.vstack([steps.mag0, steps.mag[first]])
        else:
            acc, fld = steps.accel[first], steps.mag[first]
        mref = mag_reference(declination, inclination_from_samples(acc, fld))
    q0 = initial_attitude(steps.accel0, steps.mag0 if use_mag else None, declination)
    P0 = np.diag(
        [noise.init_tilt**2, noise.init_tilt**2, noise.init_yaw**2] + [noise.init_bias**2] * 3
    )
    prior = Gaussian(np.concatenate([q0, np.zeros(3)]), P0)
    J = steps.dt.shape[0]
    # each filter's stream from (seed, its label): its numbers do not depend on which
    # other filters run beside it
    runs = [
        _Run(spec, prior, J, np.random.default_rng([seed, zlib.crc32(spec.encode())]), smooth)
        for spec in specs
    ]
    model = GyroTransition(noise)
    acc_ned = steps.accel_ned
    every = max(1, J // 200)
    wall0 = time.perf_counter()
    for k in range(1, J + 1):
        meas = []
        a = GravityDirection.from_accel(
            steps.accel[k - 1], noise, accel_ned=None if acc_ned is None else acc_ned[k - 1]
        )
        if a is not None:
            meas.append(a)
        if use_mag and np.isfinite(steps.mag[k - 1, 0]):
            fld = steps.mag[k - 1]
            if mag_delay:
                fld = quat_rotate(quat_exp(-mag_delay * steps.gyro[k - 1]), fld)
            m = (
                MagField.from_field(fld, noise, mref)
                if mref is not None
                else MagHeading.from_field(fld, noise, declination)
            )
            if m is not None:
                meas.append(m)
        if len(meas) > 1:
            meas = [Stacked.of(meas)]
        t, dt, u = float(steps.t[k]), float(steps.dt[k - 1]), steps.gyro[k - 1]
        for r in runs:
            r.step(k, model, t, dt, u, meas)
        if progress and (k % every == 0 or k == J):
            _progress(k, J)
    smooth_time = sum(r.smooth_seconds for r in runs)
    return runs, time.perf_counter() - wall0 - smooth_time


def _score(q: Array, P: Array | None, ref_q: Array, mask: Array, truth: bool) -> dict:
    d = rmse_deg(q, ref_q, mask)
    if truth and P is not None and mask.any():
        n = nees_attitude(q[mask], P[mask], ref_q[mask])
        d["nees_mean"] = float(np.mean(n))
    return d


def replay(path: str | Path, cfg: ReplayConfig | None = None, progress: bool = False) -> dict:
    """Replay ``path`` with ``cfg``; returns the JSON-ready result document."""
    from ..ingest import read_log

    cfg = cfg or ReplayConfig()
    data = read_log(path, imu=cfg.imu, start=cfg.start, end=cfg.end)
    if len(data.imu) < 2:
        raise ValueError(f"{path}: fewer than 2 IMU samples in the chosen window")
    noise = noise_for_source(data.imu.source).with_(**cfg.noise)
    decl = cfg.declination
    decl_src = "option"
    if decl is None:
        decl = declination_from_params(data.params)
        decl_src = "log parameters" if decl is not None else "none (0)"
        decl = decl or 0.0
    mag = data.mag if cfg.use_mag else None
    steps = build_steps(
        data.imu.t, data.imu.gyro, data.imu.accel,
        None if mag is None else mag.t, None if mag is None else mag.field,
        cfg.rate_hz, cfg.integration,
    )
    comp_src = None
    if cfg.accel_comp not in ("auto", "none"):
        raise ValueError(f"accel_comp must be auto or none, not {cfg.accel_comp!r}")
    if cfg.accel_comp == "auto":
        for name, pos in data.positions.items():
            if len(pos) >= 2 and np.isfinite(pos.vel_ned).all(axis=1).sum() >= 2:
                steps = replace(
                    steps, accel_ned=velocity_acceleration(pos.t, pos.vel_ned, steps.t[1:])
                )
                comp_src = name
                break
    runs, wall = run_filters(
        steps, cfg.filters, noise, decl, cfg.seed, cfg.smooth, mag is not None, progress,
        cfg.mag_mode, cfg.mag_delay,
    )
    ref_name, ap_name = select_reference(data.references)
    doc: dict = {
        "log": str(path),
        "format": data.format,
        "imu_source": data.imu.source,
        "mag_source": None if mag is None else mag.source,
        "reference": ref_name,
        "reference_kind": None if ref_name is None else data.references[ref_name].kind,
        "imu_rate_hz": data.imu_rate_hz,
        "filter_rate_hz": (len(steps.dt)) / max(float(steps.t[-1] - steps.t[0]), 1e-9),
        "integration": steps.integration,
        "preintegrated_samples_per_step": steps.factor,
        "duration_s": data.duration,
        "steps": int(len(steps.dt)),
        "declination_rad": decl,
        "declination_source": decl_src,
        "accel_compensation": comp_src,
        "mag_mode": cfg.mag_mode if mag is not None else None,
        "mag_delay_s": cfg.mag_delay,
        "seed": cfg.seed,
        "noise": {k: float(getattr(noise, k)) for k in noise.__dataclass_fields__},
        "filters": {},
    }
    tk = steps.t[1:]
    truth = ref_name is not None and data.references[ref_name].kind == "truth"
    if ref_name is not None:
        ref = data.references[ref_name]
        ref_q, mask = quat_slerp_interp(ref.t, ref.q, tk)
    for r in runs:
        row: dict = {}
        if ref_name is not None:
            row.update(_score(r.x[1:, :4], r.P[1:], ref_q, mask, truth))
        row["us_per_step"] = 1e6 * r.seconds / max(len(tk), 1)
        row["resets"] = r.resets
        if cfg.smooth:
            xs, Ps = r.smoothed()
            srow = _score(xs[1:, :4], Ps[1:], ref_q, mask, truth) if ref_name else {}
            srow["us_per_step"] = 1e6 * r.smooth_seconds / max(len(tk), 1)
            row["smoothed"] = srow
        doc["filters"][r.label] = row
    if ref_name is not None:
        for name, label in ((ap_name, "autopilot"), ("AHRS2", "ahrs2"), ("AHR2", "ahrs2")):
            if name is None or name == ref_name or name not in data.references:
                continue
            o = data.references[name]
            q_o, m_o = quat_slerp_interp(o.t, o.q, tk)
            row = rmse_deg(q_o, ref_q, mask & m_o)
            row["source"] = name
            doc["filters"].setdefault(label, row)
    doc["bad_data"] = data.stats.as_dict()
    doc["guard_resets"] = {r.label: r.resets for r in runs}
    doc["wall_s"] = wall
    doc["realtime_factor"] = data.duration / wall if wall > 0 else float("inf")
    return doc


# ---------------------------------------------------------------------------------- CLI


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.2f}" if abs(v) < 1e5 else f"{v:.3g}"
    return str(v)


def format_table(doc: dict) -> str:
    """Human-readable table of a :func:`replay` result."""
    cols = ["roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "nees_mean", "us_per_step"]
    heads = ["roll", "pitch", "yaw", "NEES", "us/step"]
    lines = [f"{'filter':24s} " + " ".join(f"{h:>8s}" for h in heads)]
    for name, row in doc["filters"].items():
        lines.append(f"{name[:24]:24s} " + " ".join(f"{_fmt(row.get(c)):>8s}" for c in cols))
        if "smoothed" in row:
            s = row["smoothed"]
            lines.append(
                f"{'  smoothed':24s} " + " ".join(f"{_fmt(s.get(c)):>8s}" for c in cols)
            )
    return "\n".join(lines)


def _parse_noise(items: list[str]) -> dict:
    known = set(AttitudeNoise.__dataclass_fields__)
    out = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"--noise expects KEY=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        if k.strip() not in known:
            raise ValueError(f"unknown noise parameter {k!r}; known: {', '.join(sorted(known))}")
        out[k.strip()] = float(v)
    return out


def cmd_replay(args: argparse.Namespace) -> int:
    """Entry point of ``uavest replay``; errors -> one line on stderr, exit code 2."""
    try:
        specs = tuple(split_filter_list(args.filters)) if args.filters else DEFAULT_FILTERS
        if not specs:
            raise ValueError("--filters is empty")
        dup = sorted({s for s in specs if specs.count(s) > 1})
        if dup:  # results are keyed by label: a repeat would overwrite the first
            raise ValueError(f"--filters lists {', '.join(dup)} more than once")
        for s in specs:
            make_filter(s)  # validate early
        cfg = ReplayConfig(
            filters=specs, start=args.start, end=args.end, smooth=args.smooth, seed=args.seed,
            rate_hz=args.rate, integration=args.integration,
            declination=None if args.declination is None else math.radians(args.declination),
            noise=_parse_noise(args.noise), imu=args.imu, use_mag=not args.no_mag,
            accel_comp=args.accel_comp, mag_mode=args.mag_mode, mag_delay=args.mag_delay,
        )
        if Path(args.log).is_dir():
            raise ValueError(f"{args.log} is a directory, not a log file")
        if not Path(args.log).is_file():
            raise ValueError(f"no such log file: {args.log}")
        doc = replay(args.log, cfg, progress=not args.no_progress and sys.stderr.isatty())
    except (ValueError, OSError, np.linalg.LinAlgError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        print(f"uavest replay: error: {msg}", file=sys.stderr)
        return 2
    ref = doc["reference"]
    kind = doc["reference_kind"]
    print(
        f"{doc['log']}: {doc['format']}, IMU {doc['imu_source']} at {doc['imu_rate_hz']:.1f} Hz,"
        f" {doc['duration_s']:.1f} s, {doc['steps']} filter steps at "
        f"{doc['filter_rate_hz']:.1f} Hz ({doc['integration']})"
    )
    if ref is None:
        print("reference: none in this log (RMSE not available)")
    else:
        what = "truth" if kind == "truth" else f"{kind} estimate, not truth"
        print(f"reference: {ref} ({what}); RMSE in degrees, Euler ZYX, wrapped")
    print(format_table(doc))
    bad = doc["bad_data"]
    parts = [f"{k} {bad[k]}" for k in bad
             if isinstance(bad[k], int) and bad[k] and k != "bad_total"]
    print(f"bad data: {bad['bad_total']}" + (f" ({', '.join(parts)})" if parts else ""))
    print(f"replay speed: {doc['realtime_factor']:.1f}x real time "
          f"({len(doc['guard_resets'])} filters together, {doc['wall_s']:.2f} s)")
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=2, default=_json_default) + "\n")
        print(f"wrote {args.json}")
    return 0


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def add_replay_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``replay`` on an argparse sub-parsers object (sets ``func``)."""
    p = subparsers.add_parser(
        "replay",
        help="replay a flight log through attitude filters and score them",
        description="Run attitude filters side by side over a log (tlog, DataFlash .BIN, "
        "ULog) and report roll/pitch/yaw RMSE against the log's truth (SITL) or, without "
        "truth, against the autopilot's own estimate.",
    )
    p.add_argument("log", help="log file (.tlog, .bin, .ulg)")
    p.add_argument("--filters", default=",".join(DEFAULT_FILTERS),
                   help="comma-separated filter specs (default: ekf,ukf,hybrid), e.g. "
                   "'ekf,ukf,hybrid(n_cloud=32)'")
    p.add_argument("--json", help="write the results as JSON to this path")
    p.add_argument("--start", type=float, help="start time (s, vehicle clock)")
    p.add_argument("--end", type=float, help="end time (s, vehicle clock)")
    p.add_argument("--smooth", action="store_true",
                   help="also run the forward-backward (RTS) smoother and score it")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--rate", type=float, default=None,
                   help=f"max filter rate in Hz (default {DEFAULT_MAX_RATE_HZ:g}; gyro is "
                   "pre-integrated exactly between steps); 0 = every IMU sample")
    p.add_argument("--integration", default="auto", choices=("auto", "hold", "trapezoid"),
                   help="gyro sample interpretation (default auto: trapezoid below 20 Hz)")
    p.add_argument("--declination", type=float, default=None,
                   help="magnetic declination in degrees, east positive (default: from the "
                   "log's COMPASS_DEC / ATT_MAG_DECL, else 0)")
    p.add_argument("--noise", action="append", default=[], metavar="KEY=VALUE",
                   help="override a noise parameter (repeatable), e.g. --noise mag_noise=0.1")
    p.add_argument("--imu", help="IMU source name (default: the ingest's choice)")
    p.add_argument("--accel-comp", default="auto", choices=("auto", "none"),
                   help="remove the vehicle's own acceleration (causal difference of the "
                   "log's velocity) from the accelerometer before using it as gravity "
                   "(default auto: when the log has velocity)")
    p.add_argument("--mag-mode", default="field", choices=("field", "heading"),
                   help="magnetometer as 3-D field direction (default) or heading only")
    p.add_argument("--mag-delay", type=float, default=0.0,
                   help="magnetometer sample age in s, compensated with the gyro (default 0)")
    p.add_argument("--no-mag", action="store_true", help="do not use the magnetometer")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_replay)
    return p
