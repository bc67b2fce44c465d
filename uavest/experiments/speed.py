"""Speed benchmark: our UKF against FilterPy's ``UnscentedKalmanFilter`` and our hybrid
against our UKF, in one run, on the same model and data (UNGM by default).

Timing is the best of ``repeats`` passes over ``runs`` x ``steps`` predict + update +
estimate steps of the engine's runner (best-of removes scheduler noise; ``estimate()`` is
included: a user pays it every step). Filters are timed bare (no divergence guard), as
FilterPy's has none; the guarded cost is printed too. FilterPy is a benchmark-only
dependency (``pip install -e .[bench]``).
"""

from __future__ import annotations

import time

import numpy as np

from ..core.guard import Guarded
from ..core.hybrid import HybridShift
from ..core.unscented import UKF
from ..engine import FilterRunner, run
from .montecarlo import trial_steps
from .systems import System, simulate


def _time_ours(flt, sysm: System, Z, seed: int) -> float:
    """Seconds per predict + update + estimate of ``flt`` stepped by the engine's runner
    (bare: no guard unless ``flt`` is one)."""
    runs, T = Z.shape[:2]
    total = 0.0
    for r in range(runs):
        fr = FilterRunner("speed", flt, np.random.default_rng([seed, r]), guard=False)
        run(trial_steps(sysm, Z[r]), [fr])
        total += fr.seconds
    return total / (runs * T)


def _time_filterpy(sysm: System, Z, alpha: float, beta: float, kappa: float) -> float:
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    tr, me = sysm.transition, sysm.measurement
    n, m = tr.space.dim, me.dim
    runs, T = Z.shape[:2]
    clock = {"t": 0.0}

    def fx(x, dt):
        return tr.f(x[None, :], clock["t"], dt)[0]

    def hx(x):
        return me.h(x[None, :])[0]

    pts = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    ukf = UnscentedKalmanFilter(n, m, sysm.dt, hx, fx, pts)
    ukf.Q = tr.Q(0.0, sysm.dt)
    ukf.R = me.R
    t0 = time.perf_counter()
    for r in range(runs):
        ukf.x = sysm.filter_prior.x.copy()
        ukf.P = sysm.filter_prior.P.copy()
        for k in range(T):
            clock["t"] = (k + 1) * sysm.dt
            ukf.predict()
            ukf.update(Z[r, k])
    return (time.perf_counter() - t0) / (runs * T)


def speed(sysm: System, runs: int = 20, seed: int = 0, repeats: int = 5) -> dict:
    """Per-step times (microseconds) and the ratios the core issue asks for."""
    _, Z = simulate(sysm, runs, np.random.default_rng([seed, 0]))
    ukf = UKF()
    hyb = HybridShift()
    res = {"ours_ukf": [], "ours_ukf_guarded": [], "ours_hybrid": [], "filterpy_ukf": []}
    try:
        import filterpy  # noqa: F401

        have_fp = True
    except ImportError:
        have_fp = False
    for _ in range(repeats):
        res["ours_ukf"].append(_time_ours(ukf, sysm, Z, seed))
        res["ours_ukf_guarded"].append(_time_ours(Guarded(ukf), sysm, Z, seed))
        res["ours_hybrid"].append(_time_ours(hyb, sysm, Z, seed))
        if have_fp:
            res["filterpy_ukf"].append(_time_filterpy(sysm, Z, ukf.alpha, ukf.beta, ukf.kappa))
    us = {k: (min(v) * 1e6 if v else None) for k, v in res.items()}
    out = {
        "us_per_step": us,
        "hybrid_members": hyb.members(sysm.transition.space.dim),
        "hybrid_over_ukf": us["ours_hybrid"] / us["ours_ukf"],
        "ukf_over_filterpy": (us["ours_ukf"] / us["filterpy_ukf"]) if have_fp else None,
        "runs": runs,
        "steps": sysm.steps,
        "repeats": repeats,
    }
    if not have_fp:
        out["note"] = "filterpy not installed: pip install -e .[bench] for the comparison"
    return out
