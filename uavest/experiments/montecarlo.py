"""Monte Carlo harness: every filter sees the same seeded truths and measurements.

Seeding: truths and measurements come from ``SeedSequence([seed, 0])``; filter ``label``
in run ``r`` draws from ``SeedSequence([seed, 1, r, crc32(label)])``, so adding or
removing a filter changes no other filter's numbers.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable

import numpy as np

from ..core.guard import Guarded
from ..core.hybrid import Hybrid
from ..core.registry import make_filter, parse_filter_spec
from ..eval.metrics import mean_abs, nees, nees_band, rmse
from .systems import System, simulate

Array = np.ndarray

METRICS = (
    "rmse_mean", "rmse_median", "approx_error", "est_error", "nees_mean", "diverged_fraction",
    "us_per_step",
)


def filter_rng(seed: int, run: int, label: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, 1, run, zlib.crc32(label.encode())]))


def build_filter(spec: str, n: int) -> Guarded:
    """Filter from a spec, guarded. EnKF/ETKF default to the default hybrid's member
    count M = (2n+1)(N+1) so that ensemble sizes match unless the spec says otherwise."""
    name, _ = parse_filter_spec(spec)
    defaults = {}
    if name.removesuffix("_sh") in ("enkf", "etkf"):
        defaults["members"] = Hybrid().members(n)
    return Guarded(make_filter(spec, **defaults))


def run_one(flt, sysm: System, Z: Array, rng: np.random.Generator):
    """Run a (guarded) filter over one measurement sequence.

    Returns predicted means (T, n), estimates (T, n), covariances (T, n, n), number of
    divergence resets, and the filter's wall time in seconds.
    """
    tr, me = sysm.transition, sysm.measurement
    T = Z.shape[0]
    n = tr.space.dim
    pred = np.empty((T, n))
    est = np.empty((T, n))
    Ps = np.empty((T, n, n))
    t0 = time.perf_counter()
    s = flt.init(sysm.filter_prior, tr.space, rng)
    for k in range(T):
        t = (k + 1) * sysm.dt
        s = flt.predict(s, tr, t, sysm.dt, None, rng)
        pred[k] = flt.estimate(s).x
        s, _ = flt.update(s, Z[k], me, rng)
        g = flt.estimate(s)
        est[k] = g.x
        Ps[k] = g.P
    elapsed = time.perf_counter() - t0
    return pred, est, Ps, s.resets, elapsed


def evaluate(
    sysm: System,
    specs: list[str],
    runs: int,
    seed: int,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, dict]:
    """Per-filter metrics (see ``METRICS``) over ``runs`` shared truths."""
    X, Z = simulate(sysm, runs, np.random.default_rng(np.random.SeedSequence([seed, 0])))
    n = sysm.transition.space.dim
    out = {}
    for spec in specs:
        flt = build_filter(spec, n)
        rm, ap, es, ne, div, resets, tt = [], [], [], [], 0, 0, 0.0
        for r in range(runs):
            pred, est, Ps, nres, el = run_one(flt, sysm, Z[r], filter_rng(seed, r, spec))
            e = X[r] - est
            rm.append(rmse(e))
            ap.append(mean_abs(X[r] - pred))
            es.append(mean_abs(e))
            ne.append(float(np.mean(nees(e, Ps))))
            div += int(rm[-1] > sysm.divergence_rmse or nres > 0)
            resets += nres
            tt += el
            if progress:
                progress(spec, r + 1, runs)
        lo, hi = nees_band(n, runs)
        out[spec] = {
            "rmse_mean": float(np.mean(rm)),
            "rmse_median": float(np.median(rm)),
            "approx_error": float(np.mean(ap)),
            "est_error": float(np.mean(es)),
            "nees_mean": float(np.mean(ne)),
            "nees_median": float(np.median(ne)),
            "nees_band": [lo, hi],
            "diverged_fraction": div / runs,
            "resets": resets,
            "us_per_step": tt / (runs * sysm.steps) * 1e6,
        }
    return out


ABLATION_CELLS = (
    ("random", "equal"), ("expanded", "equal"), ("random", "confidence"), ("expanded", "confidence")
)


def ablation(sysm: System, runs: int, seed: int, progress=None) -> dict[str, dict]:
    """Seed 000's 2x2 (sampling x weights) for the literal and the consistent hybrid."""
    out = {}
    for family in ("hybrid_literal", "hybrid"):
        specs = [f"{family}(sampling={s}, weights={w})" for s, w in ABLATION_CELLS]
        res = evaluate(sysm, specs, runs, seed, progress)
        out[family] = {
            f"{s}+{w}": res[spec] for (s, w), spec in zip(ABLATION_CELLS, specs, strict=True)
        }
    return out
