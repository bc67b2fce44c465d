"""Our EKF/UKF against FilterPy's and Stone Soup's on the same truths and detections.

    python benchmarks/radar_compare.py [--runs 100] [--seed 0]
        [--cases radar_far:5,radar_crossing:5] [--set KEY=VALUE ...] [--json out.json]

Benchmark-only dependencies: ``filterpy``, ``stonesoup`` (``pip install -e .[bench]``).
All implementations use the same model: 2-D NCV with q from the scenario, range/bearing
(bearing counter-clockwise from east, wrapped in residuals and sigma-point means), UKF with
Van der Merwe points alpha=1, beta=2, kappa=0, the same x0 ~ N(m0, P0) per run. Time per
step is wall time of one predict + one update, measured in the same process one
implementation after the other (runs interleaved per run so that machine load hits all).
"""

from __future__ import annotations

import argparse
import json
import time
from datetime import datetime, timedelta

import numpy as np

from uavest.core import make_filter
from uavest.core.gaussian import Gaussian
from uavest.eval.pcrlb import pcrlb, position_bound
from uavest.eval.tracking import nees, nees_band
from uavest.experiments.radar import data_rng
from uavest.models.radar import wrap_angle
from uavest.tracking.scenario import build_models, generate_run, prior

# state permutation: ours [x, y, vx, vy] <-> Stone Soup [x, vx, y, vy]
PERM = np.array([0, 2, 1, 3])


def ours(name, motion, radar, x0, P0, Z, dt, guarded=False):
    from uavest.core import Guarded

    f = make_filter(name)
    if guarded:
        f = Guarded(f, strikes=10**9)
    rng = np.random.default_rng(0)
    s = f.init(Gaussian(x0, P0), motion.space, rng)
    K = len(Z)
    X, P = np.empty((K, 4)), np.empty((K, 4, 4))
    t0 = time.perf_counter()
    for k in range(K):
        s = f.predict(s, motion, (k + 1) * dt, dt, None, rng)
        if Z[k] is not None:  # missed detection: predict only
            s, _ = f.update(s, Z[k], radar, rng)
        g = f.estimate(s)
        X[k], P[k] = g.x, g.P
    return X, P, time.perf_counter() - t0


def filterpy_run(kind, motion, radar, x0, P0, Z, dt):
    from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints
    from filterpy.kalman import UnscentedKalmanFilter as FUKF

    F, Q, R = motion.F(x0, 0, dt), motion.Q(0, dt), radar.R

    def hx(x):
        return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])

    def hjac(x):
        r2 = x[0] ** 2 + x[1] ** 2
        r = np.sqrt(r2)
        return np.array([[x[0] / r, x[1] / r, 0, 0], [-x[1] / r2, x[0] / r2, 0, 0]])

    def resid(a, b):
        y = a - b
        y[1] = wrap_angle(y[1])
        return y

    if kind == "ekf":
        f = ExtendedKalmanFilter(dim_x=4, dim_z=2)
        f.x, f.P, f.F, f.Q, f.R = x0.copy(), P0.copy(), F, Q, R
        step = lambda z: (  # noqa: E731
            f.predict(), None if z is None else f.update(z, hjac, hx, residual=resid)
        )
    else:
        def fx(x, dt_):
            return F @ x

        def zmean(sig, Wm):
            return np.array(
                [Wm @ sig[:, 0], np.arctan2(Wm @ np.sin(sig[:, 1]), Wm @ np.cos(sig[:, 1]))]
            )

        pts = MerweScaledSigmaPoints(4, alpha=1.0, beta=2.0, kappa=0.0)
        f = FUKF(dim_x=4, dim_z=2, dt=dt, hx=hx, fx=fx, points=pts, z_mean_fn=zmean,
                 residual_z=resid)
        f.x, f.P, f.Q, f.R = x0.copy(), P0.copy(), Q, R
        step = lambda z: (f.predict(), None if z is None else f.update(z))  # noqa: E731
    K = len(Z)
    X, P = np.empty((K, 4)), np.empty((K, 4, 4))
    t0 = time.perf_counter()
    for k in range(K):
        step(Z[k])
        X[k], P[k] = f.x, f.P
    return X, P, time.perf_counter() - t0


def stonesoup_run(kind, q, radar, x0, P0, Z, dt):
    from stonesoup.models.measurement.nonlinear import CartesianToBearingRange
    from stonesoup.models.transition.linear import (
        CombinedLinearGaussianTransitionModel,
        ConstantVelocity,
    )
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor, UnscentedKalmanPredictor
    from stonesoup.types.angle import Bearing
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater, UnscentedKalmanUpdater

    tm = CombinedLinearGaussianTransitionModel([ConstantVelocity(q), ConstantVelocity(q)])
    sb, sr = np.sqrt(radar.R[1, 1]), np.sqrt(radar.R[0, 0])
    mm = CartesianToBearingRange(ndim_state=4, mapping=(0, 2),
                                 noise_covar=CovarianceMatrix(np.diag([sb**2, sr**2])))
    if kind == "ekf":
        pred, upd = ExtendedKalmanPredictor(tm), ExtendedKalmanUpdater(mm)
    else:
        pred = UnscentedKalmanPredictor(tm, alpha=1.0, beta=2.0, kappa=0.0)
        upd = UnscentedKalmanUpdater(mm, alpha=1.0, beta=2.0, kappa=0.0)
    t_start = datetime(2024, 1, 1)
    st = GaussianState(StateVector(x0[PERM]), CovarianceMatrix(P0[np.ix_(PERM, PERM)]),
                       timestamp=t_start)
    K = len(Z)
    X, P = np.empty((K, 4)), np.empty((K, 4, 4))
    t0 = time.perf_counter()
    for k in range(K):
        ts = t_start + timedelta(seconds=(k + 1) * dt)
        p = pred.predict(st, timestamp=ts)
        if Z[k] is None:  # missed detection: predict only
            st = p
        else:
            det = Detection(StateVector([Bearing(Z[k][1]), Z[k][0]]), timestamp=ts,
                            measurement_model=mm)
            st = upd.update(SingleHypothesis(p, det))
        X[k] = np.asarray(st.state_vector, float).ravel()[PERM]
        P[k] = np.asarray(st.covar, float)[np.ix_(PERM, PERM)]
    return X, P, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default="radar_far:5,radar_crossing:5")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scenario override for every case, repeatable (e.g. radar.pd=0.9)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    impls = ["ours_ekf", "ours_ukf", "ours_ukf_guarded", "filterpy_ekf", "filterpy_ukf",
             "stonesoup_ekf", "stonesoup_ukf"]
    # imported here, not at the top: speed_report imports this module's runners on base
    # trees from before the typed scenarios
    from uavest.scenarios import load_typed

    out = {}
    for case in a.cases.split(","):
        name, deg = case.split(":")
        sc = load_typed(name, [f"radar.sigma_az_deg={deg}", *a.set])
        motion, radar = build_models(sc)
        dt = float(sc.dt)
        q = float(sc.motion.q)
        m0, P0 = prior(sc)
        runs = [generate_run(sc, data_rng(a.seed, r)) for r in range(a.runs)]
        truths = np.stack([rd.truths[0] for rd in runs])
        K = truths.shape[1] - 1
        detected = np.array([[np.any(o == 0) for o in rd.origins] for rd in runs], float)
        bpos = position_bound(
            pcrlb(np.linalg.inv(P0), truths, motion, radar, dt, detected=detected), 2
        ).mean()
        err = {i: np.empty((a.runs, K, 4)) for i in impls}
        ne = {i: np.empty((a.runs, K)) for i in impls}
        sec = dict.fromkeys(impls, 0.0)
        for r, rd in enumerate(runs):
            # the target's detection per scan, None when missed (Pd < 1): predict only
            Z = [s[o == 0][0] if np.any(o == 0) else None
                 for s, o in zip(rd.scans, rd.origins, strict=True)]
            for i in impls:
                lib, kind = i.split("_")[0], i.split("_")[1]
                if lib == "ours":
                    X, P, s = ours(kind, motion, radar, rd.x0, P0, Z, dt, i.endswith("guarded"))
                elif lib == "filterpy":
                    X, P, s = filterpy_run(kind, motion, radar, rd.x0, P0, Z, dt)
                else:
                    X, P, s = stonesoup_run(kind, q, radar, rd.x0, P0, Z, dt)
                e = X - truths[r, 1:]
                err[i][r], ne[i][r], sec[i] = e, nees(e, P), sec[i] + s
        res = {}
        print(f"\n{name} @ {deg} deg, {a.runs} runs, PCRLB pos {bpos:.1f} m, NEES band "
              f"[{nees_band(4, a.runs)[0]:.2f}, {nees_band(4, a.runs)[1]:.2f}]")
        hdr = f"{'impl':<18}{'pos_rmse':>9}{'vel_rmse':>9}{'ratio':>7}{'nees':>8}{'us/step':>9}"
        print(hdr)
        print("-" * len(hdr))
        for i in impls:
            e = err[i]
            pos = np.sqrt(np.mean(np.sum(e[:, :, :2] ** 2, 2), 0)).mean()
            vel = np.sqrt(np.mean(np.sum(e[:, :, 2:] ** 2, 2), 0)).mean()
            us = 1e6 * sec[i] / (a.runs * K)
            res[i] = {"pos_rmse": float(pos), "vel_rmse": float(vel),
                      "pcrlb_ratio": float(pos / bpos), "nees_mean": float(ne[i].mean(0).mean()),
                      "us_per_step": us}
            print(f"{i:<18}{pos:>9.1f}{vel:>9.2f}{pos / bpos:>7.3f}{res[i]['nees_mean']:>8.2f}"
                  f"{us:>9.1f}")
        us = {i: res[i]["us_per_step"] for i in impls}
        sp = {
            "ukf_vs_stonesoup": us["stonesoup_ukf"] / us["ours_ukf"],
            "ukf_vs_filterpy": us["filterpy_ukf"] / us["ours_ukf"],
            "ekf_vs_stonesoup": us["stonesoup_ekf"] / us["ours_ekf"],
            "ekf_vs_filterpy": us["filterpy_ekf"] / us["ours_ekf"],
        }
        print("speed-up (their time / ours): " + ", ".join(f"{k} {v:.1f}x" for k, v in sp.items()))
        out[f"{name}@{deg}deg"] = {"pcrlb_pos": float(bpos), "results": res, "speedup": sp}
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
