"""Each navigation filter's covariance against the first one's along the same replay: the
median over the steps (after the first ``--skip`` seconds) of the ratio of its mean
attitude, velocity and position variance to the first filter's at the same step, and its
own RMS position std. With the EKF first, it shows how far an ensemble's spread follows
the Gaussian filter's on real data (docs/filters.md, "Long memory"; docs/navigation.md).

    OMP_NUM_THREADS=1 python benchmarks/nav_spread.py LOG
        [--filters "ekf,hybrid,hybrid(reinflate=false)"] [--seed 0] [--skip 60]
        [--gnss-delay S]
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from uavest.apps.replay import ReplayConfig, replay_samples  # noqa: E402
from uavest.ingest import open_source  # noqa: E402


def spreads(log: str, filters: str, seed: int, skip: float, gnss_delay: float | None
            ) -> dict[str, tuple[float, float, float, float]]:
    """{label: (median attitude, velocity, position variance ratio to the first filter,
    RMS position std m)} over the steps ``skip`` s after the first."""
    return spread_table(replay_estimates(log, filters, seed, gnss_delay), skip)


def replay_estimates(log: str, filters: str, seed: int, gnss_delay: float | None) -> dict:
    """The navigation replay of ``log`` with ``filters``: {label: [(t s, x, P), ...]}."""
    src = open_source(log)
    cfg = ReplayConfig(filters=tuple(filters.split(",")), model="nav", seed=seed,
                       gnss_delay=gnss_delay)
    est: dict = replay_samples(src, cfg, params=src.params)[0]["nav"].est
    return est


def spread_table(est: dict, skip: float) -> dict[str, tuple[float, float, float, float]]:
    """:func:`spreads` of the estimates ``est`` (:func:`replay_estimates`)."""
    labels = list(est)
    per = {}
    for lab in labels:
        t = np.array([e[0] for e in est[lab]])
        P = np.array([e[2] for e in est[lab]])
        keep = t >= t[0] + skip
        if not keep.any():
            raise SystemExit(f"nav_spread: {lab} has no step {skip:g} s after its first "
                             f"({t[-1] - t[0]:.0f} s of steps): lower --skip")
        v = np.stack([np.trace(P[:, i:i + 3, i:i + 3], axis1=1, axis2=2) / 3
                      for i in (0, 3, 6)], axis=1)
        per[lab] = (t[keep], v[keep])
    t0, v0 = per[labels[0]]
    res = {}
    for lab in labels:
        t, v = per[lab]
        _, i0, i1 = np.intersect1d(t0, t, return_indices=True)
        r = np.median(v[i1] / v0[i0], axis=0)
        res[lab] = (float(r[0]), float(r[1]), float(r[2]), float(np.sqrt(np.mean(v[:, 2]))))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log")
    ap.add_argument("--filters", default="ekf,hybrid,hybrid(reinflate=false)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip", type=float, default=60.0, help="s after the first step")
    ap.add_argument("--gnss-delay", type=float, default=None)
    a = ap.parse_args()
    res = spreads(a.log, a.filters, a.seed, a.skip, a.gnss_delay)
    first = next(iter(res))
    print(f"variance / {first}'s at the same step (median), from {a.skip:g} s on")
    print(f"{'filter':28s} {'attitude':>8s} {'velocity':>8s} {'position':>8s} {'pos std m':>9s}")
    for lab, (ra, rv, rp, sd) in res.items():
        print(f"{lab:28s} {ra:8.2f} {rv:8.2f} {rp:8.2f} {sd:9.3f}")


if __name__ == "__main__":
    main()
