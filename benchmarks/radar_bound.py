"""Radar filters against the PCRLB: radar_far and radar_crossing at 1 and 5 deg bearing
noise, 100 runs each (the standard bound-comparison set-up of docs/tracking.md).

Columns: ``ratio`` = mean per-scan RMSE / mean per-scan PCRLB; ``rms`` = the same with
RMS over scans, sqrt(mean MSE / mean bound^2); ``cond`` = mean per-scan RMSE over the mean
conditional (per-run, oracle-linearised) bound, which is not a lower bound but shows how
much of the gap to the PCRLB is the unconditional bound's looseness (docs/tracking.md).
``--oracle`` adds a Kalman filter linearised at the true state (not realisable).

    python benchmarks/radar_bound.py [--runs 100] [--seed 0] [--filters ekf,ukf,hybrid]
                                     [--json out.json]

Same code path as ``uavest bench radar_far --set radar.sigma_az_deg=1`` etc.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from uavest.core.registry import split_filter_list
from uavest.eval.pcrlb import conditional_bounds, pcrlb, position_bound
from uavest.experiments.radar import _bound_measurement, data_rng, run_bench
from uavest.scenarios import load_typed
from uavest.tracking.scenario import build_models, generate_run, prior


def oracle_row(sc: dict, runs: int, seed: int) -> dict:
    """A Kalman filter linearised at the *true* state (no real filter can do this) on the
    same truths, detections and x0 as ``run_bench``: the measurement is replaced by its
    linearisation about the truth, z - h(x_true) + H x_true, so the filter is the exact
    KF of the linearised problem. Its ratios show how far even perfect linearisation
    points stay from the unconditional PCRLB."""
    motion, radar = build_models(sc)
    m0, P0 = prior(sc)
    rd = [generate_run(sc, data_rng(seed, r), None) for r in range(runs)]
    truths = np.stack([r.truths[0] for r in rd])
    det = np.stack([[np.any(o == 0) for o in r.origins] for r in rd]).astype(float)
    meas = _bound_measurement(radar, rd)
    J0 = np.linalg.inv(P0)
    B = position_bound(pcrlb(J0, truths, motion, meas, 1.0, detected=det), 2)
    C = conditional_bounds(J0, truths, motion, meas, 1.0, detected=det)
    Bc = np.sqrt(np.einsum("rkii->k", C[:, :, :2, :2]) / runs)
    K = len(B)
    F, Q = motion.F(m0, 1, 1.0), motion.Q(1, 1.0)
    E = np.zeros((runs, K))
    for r in range(runs):
        x, P = rd[r].x0.copy(), P0.copy()
        for k in range(1, K + 1):
            x, P = F @ x, F @ P @ F.T + Q
            z = rd[r].scans[k - 1][rd[r].origins[k - 1] == 0]
            if len(z):
                xt = truths[r, k]
                H = radar.H(xt)
                nu = radar.residual(z[0], radar.h(xt[None])[0]) + H @ (xt - x)
                S = H @ P @ H.T + radar.R
                Kg = np.linalg.solve(S, H @ P).T
                x, P = x + Kg @ nu, P - Kg @ S @ Kg.T
            E[r, k - 1] = np.sum((x[:2] - truths[r, k, :2]) ** 2)
    rm = np.sqrt(E.mean(axis=0))
    return {"pos_rmse": float(rm.mean()), "pcrlb_ratio": float(rm.mean() / B.mean()),
            "pcrlb_ratio_rms": float(np.sqrt(np.mean(rm**2) / np.mean(B**2))),
            "cond_ratio": float(rm.mean() / Bc.mean())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--filters", default="ekf,ukf,hybrid")
    ap.add_argument("--cases", default="radar_far:1,radar_far:5,radar_crossing:1,radar_crossing:5")
    ap.add_argument("--json", default=None)
    ap.add_argument("--oracle", action="store_true",
                    help="add the KF linearised at the true state (see oracle_row)")
    a = ap.parse_args()
    filters = split_filter_list(a.filters)
    out = {}
    hdr = (f"{'case':<20}{'filter':<40}{'pos_rmse':>9}{'vel_rmse':>9}{'pcrlb_p':>9}"
           f"{'ratio':>7}{'rms':>7}{'cond':>7}{'vratio':>7}{'nees':>8}{'band':>14}"
           f"{'us/step':>9}")
    print(hdr)
    print("-" * len(hdr))
    for case in a.cases.split(","):
        name, deg = case.split(":")
        sc = load_typed(name, [f"radar.sigma_az_deg={deg}"])
        res = run_bench(sc, filters, a.runs, a.seed, None)
        out[f"{name}@{deg}deg"] = res
        for lab, v in res.items():
            band = f"[{v['nees_band'][0]:.2f},{v['nees_band'][1]:.2f}]"
            print(f"{name + '@' + deg + 'deg':<20}{lab:<40}{v['pos_rmse']:>9.1f}"
                  f"{v['vel_rmse']:>9.2f}{v['pcrlb_pos']:>9.1f}{v['pcrlb_ratio']:>7.3f}"
                  f"{v['pcrlb_ratio_rms']:>7.3f}{v['cond_ratio']:>7.3f}"
                  f"{v['pcrlb_vel_ratio']:>7.3f}{v['nees_mean']:>8.2f}{band:>14}"
                  f"{v['us_per_step']:>9.0f}")
        if a.oracle:
            o = oracle_row(sc, a.runs, a.seed)
            res["oracle_kf"] = o
            print(f"{name + '@' + deg + 'deg':<20}{'oracle KF (linearised at truth)':<40}"
                  f"{o['pos_rmse']:>9.1f}{'':>9}{'':>9}{o['pcrlb_ratio']:>7.3f}"
                  f"{o['pcrlb_ratio_rms']:>7.3f}{o['cond_ratio']:>7.3f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
