"""The ensemble filters' covariance on a long-memory linear problem, side by side with
the Kalman filter's (docs/filters.md, "Long memory").

    OMP_NUM_THREADS=1 python benchmarks/ensemble_memory.py [--filters SPECS]
        [--trials 10] [--steps 5000] [--seed 0]

The problem is the navigation filter's position and velocity on their own, linear and
Gaussian: a 3-axis nearly-constant-velocity model predicted at 25 Hz with the
navigation model's accelerometer noise (0.005 m/s^2/sqrt(Hz)), a velocity measured at
5 Hz with 0.004 m/s std (an ArduCopter SITL receiver's velocity floor) and a position
with 0.3 m. The position is weakly observed and its process noise tiny, so its
covariance is the memory of thousands of updates: the Kalman filter's is exact, and an
ensemble's sampling error in its gains, which shrinks the spread a little at every
update (Houtekamer and Mitchell, "Data assimilation using an ensemble Kalman filter
technique", Monthly Weather Review 1998), is never refreshed.

Default filters (:data:`DEFAULT_FILTERS`, resolved as ``uavest replay`` resolves them
for the navigation model, the nav preset: the hybrid there has n_cloud 16 and tau 0.9,
M = 13 x 17 = 221 members here, 527 on the navigation state, and re-spreads its members
after each EnKF shift, ``reinflate``): ekf (the Kalman filter here, exact), ukf, the EnKF
(100 members) and ETKF, the hybrid, and without the re-spread; each also with all of each
measurement in its EnKF shift (``tau=1.0``: no confidence weights), and the hybrid
without the re-spread with 8 times its members (``n_cloud=128``: M = 1677).

Rows (the second half of each trial, the filters on the same seeded data): the position
RMSE (cm), the filter's own position std (cm, the root of the mean variance), the
position NEES mean (3 if consistent) and the share of steps with the NEES in its 95 %
band, averaged over the trials. Every random draw from uavest's seeding scheme
(``uavest.seeding.rng``: per run seed, trial and stream, a filter's numbers the same
whatever runs beside it).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from uavest.core.gaussian import Gaussian  # noqa: E402
from uavest.core.interfaces import LinearMeasurement, LinearTransition  # noqa: E402
from uavest.engine.build import build_filters  # noqa: E402
from uavest.models.motion import ncv_matrices  # noqa: E402
from uavest.presets import resolve_list  # noqa: E402
from uavest.seeding import filter_stream, rng  # noqa: E402

DEFAULT_FILTERS = ("ekf,ukf,enkf,etkf,hybrid,hybrid(reinflate=false),hybrid(tau=1.0),"
                   "hybrid(tau=1.0,reinflate=false),hybrid(n_cloud=128,reinflate=false)")
DT = 0.04  # s, the prediction step (25 Hz)
EVERY = 5  # predictions per measurement (5 Hz)
Q_ACC = 0.005**2  # (m/s^2)^2/Hz, the navigation profile's accelerometer noise
SD_VEL, SD_POS = 0.004, 0.3  # m/s, m
P0 = np.diag([0.04**2] * 3 + [0.02**2] * 3)


def trial(specs: str, seed: int, trial_no: int, steps: int
          ) -> dict[str, tuple[float, float, float, float]]:
    """Trial ``trial_no`` of a run seeded ``seed`` (uavest.seeding: the truth and
    measurements from its "truth" stream, each filter from its own): every filter of
    ``specs`` on the same data; per filter (RMSE cm, std cm, NEES mean, in-band share) over the
    second half."""
    F, Q = ncv_matrices(3, DT, Q_ACC)
    tr = LinearTransition(F, Q)
    mv = LinearMeasurement(np.hstack([np.zeros((3, 3)), np.eye(3)]), np.eye(3) * SD_VEL**2)
    mp = LinearMeasurement(np.hstack([np.eye(3), np.zeros((3, 3))]), np.eye(3) * SD_POS**2)
    g = rng(seed, trial_no, "truth")
    x = g.multivariate_normal(np.zeros(6), P0)
    Lq = np.linalg.cholesky(Q)
    xs, zs = [], []
    for k in range(steps):
        x = F @ x + Lq @ g.standard_normal(6)
        xs.append(x[:3].copy())
        zs.append((x[3:] + SD_VEL * g.standard_normal(3), x[:3] + SD_POS * g.standard_normal(3))
                  if k % EVERY == 0 else None)
    lo, hi = chi2.ppf([0.025, 0.975], 3)
    out = {}
    for sp, flt in build_filters(resolve_list(specs, "nav", dim=6)):
        fr = rng(seed, trial_no, filter_stream(sp.label))
        s = flt.init(Gaussian(np.zeros(6), P0), tr.space, fr)
        err, var, nees = [], [], []
        for k in range(steps):
            s = flt.predict(s, tr, k * DT, DT, None, fr)
            if zs[k] is not None:
                s, _ = flt.update(s, zs[k][0], mv, fr)
                s, _ = flt.update(s, zs[k][1], mp, fr)
            if k >= steps // 2:
                est = flt.estimate(s)
                e = est.x[:3] - xs[k]
                err.append(e)
                var.append(np.trace(est.P[:3, :3]) / 3)
                nees.append(e @ np.linalg.solve(est.P[:3, :3], e))
        ne = np.array(nees)
        out[sp.label] = (100 * float(np.sqrt(np.mean(np.square(err)))),
                         100 * float(np.sqrt(np.mean(var))), float(ne.mean()),
                         float(np.mean((ne >= lo) & (ne <= hi))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--filters", default=DEFAULT_FILTERS)
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    rows: dict[str, list[tuple[float, float, float, float]]] = {}
    for t in range(a.trials):
        for label, r in trial(a.filters, a.seed, t, a.steps).items():
            rows.setdefault(label, []).append(r)
    print(f"{a.trials} trials x {a.steps} steps of {DT} s, second half; position")
    print(f"{'filter':36s} {'RMSE cm':>8s} {'std cm':>7s} {'NEES':>7s} {'in95':>5s}")
    for label, rs in rows.items():
        m = np.mean(rs, axis=0)
        print(f"{label:36s} {m[0]:8.2f} {m[1]:7.2f} {m[2]:7.2f} {m[3]:5.2f}")


if __name__ == "__main__":
    main()
