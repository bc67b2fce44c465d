"""Fused numpy vs compiled (numba) attitude-manifold kernels, side by side in one process.

    python -m venv --system-site-packages /tmp/nbvenv && /tmp/nbvenv/bin/pip install numba
    OMP_NUM_THREADS=1 /tmp/nbvenv/bin/python benchmarks/numba_kernels.py [--reps 2000]

numba is an optional extra of uavest (``uavest[fast]``; ``pip install -e .`` alone runs
the fused numpy kernels). For 13 rows (the UKF's sigma points) and 221 rows (the attitude
hybrid's members) this times the numpy kernels of :mod:`uavest.geometry.rotation`
(``_np_retract_rows``, ``_np_local_rows``, ``_np_gyro_propagate``, ``_np_mean``) against
the compiled ones of :mod:`uavest.geometry._compiled` (checked equal to 1e-12 first),
best of 5 passes of ``--reps`` calls each, and prints microseconds per call and the ratio
compiled / numpy. The first calls (compile, or load numba's on-disk cache) are timed
separately.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from uavest.geometry import rotation as rot  # noqa: E402


def _best(fn, reps: int) -> float:
    best = math.inf
    for _ in range(5):
        c = time.perf_counter()
        for _ in range(reps):
            fn()
        best = min(best, (time.perf_counter() - c) / reps)
    return best * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=2000)
    a = ap.parse_args(argv)
    try:
        import numba
    except ImportError:
        print("numba is not installed here (see this script's docstring); nothing measured")
        return 0
    c = time.perf_counter()
    from uavest.geometry import _compiled as nb

    rng = np.random.default_rng(0)
    u, dt = np.array([0.1, -0.2, 0.3]), 1 / 248
    print(f"numba {numba.__version__}, numpy {np.__version__}; us per call, best of 5 x "
          f"{a.reps}")
    print(f"{'kernel':16s} {'rows':>5s} {'numpy':>8s} {'numba':>8s} {'numba/numpy':>12s}")
    for M in (13, 221):
        q = rng.normal(size=4)
        x = np.concatenate([q / np.linalg.norm(q), rng.normal(0, 0.01, 3)])
        dx = rng.normal(0, 0.05, (M, 6))
        X = rot._np_retract_rows(x, dx)
        w = np.full(M, 1.0 / M)
        x1 = x[None, :]
        cases = [
            ("retract_rows", (rot._np_retract_rows, (x, dx)), (nb.retract_rows, (x1, dx))),
            ("local_rows", (rot._np_local_rows, (x, X)), (nb.local_rows, (x1, X))),
            ("gyro_propagate", (rot._np_gyro_propagate, (X, u, dt)),
             (nb.gyro_propagate, (X, u, dt))),
            ("mean", (rot._np_mean, (X, w, X[0])), (nb.mean, (X, w, X[0]))),
        ]
        for name, (fn_np, args_np), (fn_nb, args_nb) in cases:
            out = fn_nb(*args_nb)  # the first call compiles (or loads numba's cache)
            if M == 13 and name == "mean":
                print(f"(first calls, compile or cache load: {time.perf_counter() - c:.1f} s)")
            np.testing.assert_allclose(out, fn_np(*args_np), rtol=0, atol=1e-12)
            tn = _best(lambda f=fn_np, g=args_np: f(*g), a.reps)
            tb = _best(lambda f=fn_nb, g=args_nb: f(*g), a.reps)
            print(f"{name:16s} {M:5d} {tn:8.2f} {tb:8.2f} {tb / tn:12.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
