"""Where the radar hybrid's step goes: each compiled part against the numpy form it
replaces, timed side by side in one process (docs/speed.md, "Radar hybrid").

    OMP_NUM_THREADS=1 python benchmarks/radar_hybrid_parts.py [--repeats 15] [--seed 0]

Rows (microseconds per call, median of the repeats' per-call means, "numpy" the numpy
form (the fallback without numba), "compiled" the one used with numba, and their ratio
compiled / numpy):

* normals: the predict's process noise for the radar preset's M = 585 members, numpy's
  ``X + rng.standard_normal((M, 4)) @ L.T`` against the kernel drawing the same normals
  from the same generator (``_compiled_local.add_noise``);
* generator argument: a trivial numba kernel taking the ``Generator`` itself (numba
  unboxes it through ctypes at every call) against one taking its
  ``bitgen_pointers`` (a cached int array);
* linearise_rows: the radar's composed numpy default (``h_H_rows``, a circular mean,
  three residuals) against its compiled kernel;
* update: ``HybridLocal._update_numpy`` with the radar's composed numpy terms (the
  whole fallback without numba) against ``_update_compiled`` (model terms, gains,
  resampling, draws and moments);
* step: predict + update + estimate of the hybrid against our UKF's, the ratio the speed
  goal reads (docs/speed.md; radar_far at 5 deg, one run's detections).

Then the same for 3-D detections (range, azimuth, elevation: m = 3; radar_uav, its first
target seen from the UAV with the estimated pose of each scan, 6-D CV, M = 845 members):

* 3-D linearise_rows and 3-D local update, numpy against compiled, as above;
* 3-D step (predict + update + estimate, us per step) of the hybrid two ways: all numpy
  (no numba) and all compiled; the UKF's step on the same data, and hybrid / UKF.

``--only 2d`` / ``--only 3d`` runs one of the two sections.

Needs numba (``uavest[fast]``); every random draw from a seeded ``numpy.random.Generator``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402


def _per_call(fn, number: int, repeats: int) -> float:
    """Median over ``repeats`` of the mean time of ``number`` calls of ``fn`` (us)."""
    out = []
    for _ in range(repeats):
        c = time.perf_counter()
        for _ in range(number):
            fn()
        out.append((time.perf_counter() - c) / number)
    return float(np.median(out)) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--seed", type=int, default=0, help="seed of the members and draws")
    ap.add_argument("--only", choices=("2d", "3d"), default=None,
                    help="run one section (default: both)")
    a = ap.parse_args()
    if a.only != "3d":
        _radar2d(a)
    if a.only != "2d":
        _radar3d(a)


def _radar2d(a: argparse.Namespace) -> None:
    """The 2-D range / azimuth rows (the module doc)."""

    from numba import njit

    import uavest.core._compiled_local as nb
    from uavest.compiled import bitgen_pointers
    from uavest.core import hybrid, make_filter
    from uavest.core.gaussian import Gaussian
    from uavest.core.interfaces import Measurement
    from uavest.core.linalg import chol
    from uavest.core.states import Ensemble
    from uavest.experiments.radar import data_rng
    from uavest.models import radar as radar_mod
    from uavest.presets import build
    from uavest.scenarios import load_typed
    from uavest.tracking.scenario import build_models, generate_run, prior

    if not hybrid.LOCAL_KERNELS.get() or not radar_mod.RADAR_KERNELS.get():
        raise SystemExit("radar_hybrid_parts: needs numba (and UAVEST_NUMBA not 0)")
    sc = load_typed("radar_far", ["radar.sigma_az_deg=5"])
    motion, radar = build_models(sc)
    f = build("hybrid", "radar", 4)
    M = f.members(4)
    g = np.random.default_rng([a.seed, 0])
    X = g.standard_normal((M, 4)) * [100.0, 100.0, 5.0, 5.0] + [10000.0, 5000.0, 10.0, 10.0]
    w = g.dirichlet(np.full(M, 50.0))
    z = radar.h(X[:1])[0] + [30.0, 0.02]
    L = np.ascontiguousarray(chol(motion.Q(1.0, 1.0)))
    tg = nb.tag(4)
    rng = np.random.default_rng([a.seed, 1])
    R = a.repeats

    @njit
    def _takes_generator(r, x):  # pragma: no cover - compiled
        return x[0]

    @njit
    def _takes_pointers(p, x):  # pragma: no cover - compiled
        return x[0] + p[0] * 0.0

    _takes_generator(rng, X[0])
    _takes_pointers(bitgen_pointers(rng), X[0])
    E = Ensemble(X, motion.space)

    def numpy_update():
        """The whole numpy path (the fallback without numba): the radar's terms too."""
        kernel, radar_mod.RADAR_KERNELS.loaded = radar_mod.RADAR_KERNELS.loaded, False
        try:
            return f._update_numpy(Ensemble(X, motion.space, w), z, radar, rng)
        finally:
            radar_mod.RADAR_KERNELS.loaded = kernel

    rows = [
        ("normals (predict noise, M = 585)",
         lambda: X + np.dot(rng.standard_normal((M, 4)), L.T),
         lambda: nb.add_noise(bitgen_pointers(rng), X, L, tg), 300),
        ("numba's Generator argument / pointers",
         lambda: _takes_generator(rng, X[0]),
         lambda: _takes_pointers(bitgen_pointers(rng), X[0]), 3000),
        ("radar linearise_rows (M = 585)",
         lambda: Measurement.linearise_rows(radar, X, z, w),
         lambda: radar.linearise_rows(X, z, w), 300),
        ("local update (M = 585)", numpy_update,
         lambda: f._update_compiled(nb, Ensemble(X, motion.space, w), z, radar, rng),
         100),
    ]
    print(f"radar hybrid parts, us per call (median of {R} repeats; BLAS 1 thread)")
    print(f"  {'part':38s} {'numpy':>9s} {'compiled':>9s} {'ratio':>7s}")
    for name, ref, fast, number in rows:
        ref(), fast()
        to, tn = [], []
        for _ in range(R):  # interleaved: the machine's load hits both alike
            to.append(_per_call(ref, number, 1))
            tn.append(_per_call(fast, number, 1))
        o, n = float(np.median(to)), float(np.median(tn))
        print(f"  {name:38s} {o:9.2f} {n:9.2f} {n / o:7.3f}")
    del E

    _, P0 = prior(sc)
    rd = generate_run(sc, data_rng(a.seed, 0))
    Z = [s[o == 0][0] if np.any(o == 0) else None
         for s, o in zip(rd.scans, rd.origins, strict=True)]
    ukf = make_filter("ukf")

    def loop(filt) -> float:
        r = np.random.default_rng([a.seed, 2])
        s = filt.init(Gaussian(rd.x0, P0), motion.space, r)
        c = time.perf_counter()
        for k, zk in enumerate(Z):
            s = filt.predict(s, motion, float(k + 1), 1.0, None, r)
            if zk is not None:
                s, _ = filt.update(s, zk, radar, r)
            filt.estimate(s)
        return (time.perf_counter() - c) / len(Z) * 1e6

    loop(f), loop(ukf)
    th, tu = [], []
    for _ in range(R):
        th.append(loop(f))
        tu.append(loop(ukf))
    th, tu = np.array(th), np.array(tu)
    print(f"  step: hybrid {np.median(th):.1f} us, ukf {np.median(tu):.1f} us; hybrid / ukf "
          f"median of the repeats' ratios {np.median(th / tu):.2f}, of the fastest "
          f"{th.min() / tu.min():.2f}")


def _interleaved(fns, number: int, repeats: int) -> list[float]:
    """Median us per call of each of ``fns``, timed in turn ``repeats`` times (the
    machine's load hits all alike)."""
    for fn in fns:
        fn()
    t: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t[i].append(_per_call(fn, number, 1))
    return [float(np.median(x)) for x in t]


def _radar3d(a: argparse.Namespace) -> None:
    """The 3-D range / azimuth / elevation rows (the module doc)."""
    import uavest.core._compiled_local as nb
    from uavest.core import hybrid, make_filter
    from uavest.core.gaussian import Gaussian
    from uavest.core.interfaces import Measurement
    from uavest.core.states import Ensemble
    from uavest.experiments.radar import data_rng
    from uavest.models import radar as radar_mod
    from uavest.presets import build
    from uavest.scenarios import load_typed
    from uavest.tracking.scenario import build_models, generate_run

    if not hybrid.LOCAL_KERNELS.get() or not radar_mod.RADAR_KERNELS.get():
        raise SystemExit("radar_hybrid_parts: needs numba (and UAVEST_NUMBA not 0)")
    sc = load_typed("radar_uav", [])
    motion, radar = build_models(sc)
    rd = generate_run(sc, data_rng(a.seed, 0))
    Z = [s[o == 0][0] if np.any(o == 0) else None
         for s, o in zip(rd.scans, rd.origins, strict=True)]
    poses = rd.poses_est
    P0 = np.diag([50.0**2] * 3 + [20.0**2] * 3)
    g = np.random.default_rng([a.seed, 3])
    x0 = rd.truths[0, 0] + g.standard_normal(6) * np.sqrt(np.diag(P0))
    f = build("hybrid", "radar", 6)
    M = f.members(6)
    R = a.repeats
    # members around the target at scan 10, seen from that scan's pose
    k0 = 10
    rad = radar.with_pose(poses[k0])
    X = rd.truths[0, k0 + 1] + g.standard_normal((M, 6)) * [100.0, 100.0, 50.0, 5.0, 5.0, 2.0]
    w = g.dirichlet(np.full(M, 50.0))
    z = rad.h(X[:1])[0] + [30.0, 0.01, 0.01]
    rng = np.random.default_rng([a.seed, 4])
    kl, kr = hybrid.LOCAL_KERNELS, radar_mod.RADAR_KERNELS
    on = (kl.loaded, kr.loaded)

    def paths(local: bool, radar_terms: bool) -> None:
        kl.loaded = on[0] if local else False
        kr.loaded = on[1] if radar_terms else False

    def numpy_update():
        paths(True, False)
        try:
            return f._update_numpy(Ensemble(X, motion.space, w), z, rad, rng)
        finally:
            paths(True, True)

    print(f"\n3-D radar (range / azimuth / elevation, m = 3), radar_uav, M = {M}, us per "
          f"call (median of {R} repeats)")
    print(f"  {'part':38s} {'numpy':>9s} {'compiled':>9s} {'ratio':>7s}")
    rows = [
        (f"3-D radar linearise_rows (M = {M})",
         lambda: Measurement.linearise_rows(rad, X, z, w),
         lambda: rad.linearise_rows(X, z, w), 200),
        (f"3-D local update (M = {M})", numpy_update,
         lambda: f._update_compiled(nb, Ensemble(X, motion.space, w), z, rad, rng), 50),
    ]
    for name, ref, fast, number in rows:
        o, n = _interleaved((ref, fast), number, R)
        print(f"  {name:38s} {o:9.2f} {n:9.2f} {n / o:7.3f}")

    def loop(filt, mode: str = "compiled") -> float:
        paths(mode == "compiled", mode == "compiled")
        upd = filt.update
        r = np.random.default_rng([a.seed, 2])
        try:
            s = filt.init(Gaussian(x0, P0), motion.space, r)
            c = time.perf_counter()
            for k, zk in enumerate(Z):
                s = filt.predict(s, motion, float(k + 1), 1.0, None, r)
                if zk is not None:
                    s, _ = upd(s, zk, radar.with_pose(poses[k]), r)
                filt.estimate(s)
            return (time.perf_counter() - c) / len(Z) * 1e6
        finally:
            paths(True, True)

    ukf = make_filter("ukf")
    modes = ("numpy", "compiled")
    for m in modes:
        loop(f, m)
    loop(ukf)
    th: dict[str, list[float]] = {m: [] for m in modes}
    tu = []
    for _ in range(R):
        for m in modes:
            th[m].append(loop(f, m))
        tu.append(loop(ukf))
    u = np.array(tu)
    med = {m: float(np.median(v)) for m, v in th.items()}
    print(f"  3-D step ({len(Z)} scans), us per step: hybrid all numpy {med['numpy']:.1f}, "
          f"compiled {med['compiled']:.1f}; ukf {np.median(u):.1f}")
    print(f"  3-D step compiled / all numpy {med['compiled'] / med['numpy']:.3f}")
    for m in modes:
        h = np.array(th[m])
        print(f"  3-D step hybrid ({m}) / ukf: median of the repeats' ratios "
              f"{np.median(h / u):.2f}, of the fastest {h.min() / u.min():.2f}")


if __name__ == "__main__":
    main()
