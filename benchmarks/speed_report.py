"""Speed report (issue 13): every figure for this tree and for the code before the change,
measured in one run, with same-run ratios.

    OMP_NUM_THREADS=1 PYTHONPATH=$PWD python benchmarks/speed_report.py \
        [--base COMMIT] [--repeats 2] [--inner 3] [--runs 10] [--window 0]
        [--sections help,ungm,radar,tracker,replay] [--json out.json]

The pre-change code is taken from git (``git archive COMMIT uavest benchmarks`` into a
temporary directory) and both trees are run as subprocesses with PYTHONPATH pointing at
them, each by its own copy of this script's worker where it has one (so the worker speaks
its tree's API), alternately (old, new, old, new, ...), so machine load hits both; each
figure is the best of ``--repeats`` worker runs (per-step times are best-of inside a
worker too).
Comparisons with FilterPy and Stone Soup are made inside one worker process, interleaved
per run.

Sections (each for "new" and "old"):

* UNGM (``uavest bench ungm`` system, 100 steps): our UKF, EKF, EnKF-100 and hybrid (core
  default, M = 99) per predict + update + estimate, bare and guarded; FilterPy's UKF and
  EKF (Stone Soup has no UNGM model). hybrid / UKF with ``estimate()``.
* radar (``radar_far`` at 5 deg, single target, 100 scans): ours EKF, UKF, EnKF-100,
  hybrid (the radar preset: local update, n_cloud = 64, M = 585); FilterPy's EKF/UKF,
  Stone Soup's EKF/UKF (``benchmarks/radar_compare.py``'s runners).
* replay of ``sample.ulg`` (ekf, ukf, hybrid, attitude preset) at the default rate and at
  the full IMU rate (``rate_hz=0``), the whole log (or the first ``--window`` s; the
  source still reads the whole file then): real-time factor = log seconds / wall seconds.
* tracker (GNN, UKF tracks) per scan for 5, 20 and 50 targets plus 10 clutter points
  per scan (uniform in the radar's measurement box), 30 scans.
* start-up: ``python -m uavest --help`` wall time (best of 5).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT.parent / "shared" / "logs" / "sample.ulg"
DEFAULT_BASE = "28dbdd7"  # the tree issue 13 started from


# ------------------------------------------------------------------------------ worker


def _loop(f, motion, meas, prior, Z, rng, dt=1.0, t0=0.0):
    """Seconds for predict + update + estimate over the detections ``Z`` (None: coast)."""
    s = f.init(prior, motion.space, rng)
    c0 = time.perf_counter()
    for k, z in enumerate(Z):
        s = f.predict(s, motion, t0 + (k + 1) * dt, dt, None, rng)
        if z is not None:
            s, _ = f.update(s, z, meas, rng)
        f.estimate(s)
    return time.perf_counter() - c0


def _ungm(runs: int, repeats: int) -> dict:
    from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints
    from filterpy.kalman import UnscentedKalmanFilter as FUKF

    from uavest.core import Guarded, make_filter
    from uavest.experiments.systems import build_system, simulate
    from uavest.scenarios import load_scenario

    sysm = build_system(load_scenario("ungm", []))
    tr, me = sysm.transition, sysm.measurement
    _, Z = simulate(sysm, runs, np.random.default_rng([0, 0]))
    T = Z.shape[1]
    ours = {"ukf": make_filter("ukf"), "ekf": make_filter("ekf"),
            "enkf100": make_filter("enkf", members=100), "hybrid": make_filter("hybrid")}
    ours.update({f"{k}_guarded": Guarded(v) for k, v in list(ours.items())})

    def fp_ukf(z_run):
        pts = MerweScaledSigmaPoints(1, alpha=1.0, beta=2.0, kappa=0.0)
        clock = {"t": 0.0}
        f = FUKF(1, 1, sysm.dt, lambda x: me.h(x[None, :])[0],
                 lambda x, dt: tr.f(x[None, :], clock["t"], dt)[0], pts)
        f.Q, f.R = tr.Q(0.0, sysm.dt), me.R
        f.x, f.P = sysm.filter_prior.x.copy(), sysm.filter_prior.P.copy()
        c0 = time.perf_counter()
        for k in range(T):
            clock["t"] = (k + 1) * sysm.dt
            f.predict()
            f.update(z_run[k])
        return time.perf_counter() - c0

    class _FPEKF(ExtendedKalmanFilter):  # FilterPy's EKF with the UNGM's f
        t = 0.0

        def predict_x(self, u=0):
            self.x = tr.f(self.x[None, :], self.t, sysm.dt)[0]

    def fp_ekf(z_run):
        f = _FPEKF(1, 1)
        f.Q, f.R = tr.Q(0.0, sysm.dt), me.R
        f.x, f.P = sysm.filter_prior.x.copy(), sysm.filter_prior.P.copy()
        c0 = time.perf_counter()
        for k in range(T):
            f.t = (k + 1) * sysm.dt
            f.F = tr.F(f.x, f.t, sysm.dt)
            f.predict()
            f.update(z_run[k], me.H, lambda x: me.h(x[None, :])[0])
        return time.perf_counter() - c0

    impls = list(ours) + ["filterpy_ukf", "filterpy_ekf"]
    best = dict.fromkeys(impls, np.inf)
    for rep in range(repeats + 1):  # pass 0 warms up (lazy imports, caches): not counted
        tot = dict.fromkeys(impls, 0.0)
        for r in range(runs if rep else 1):
            for name, f in ours.items():
                tot[name] += _loop(f, tr, me, sysm.filter_prior, list(Z[r]),
                                   np.random.default_rng([0, r]), sysm.dt)
            tot["filterpy_ukf"] += fp_ukf(Z[r])
            tot["filterpy_ekf"] += fp_ekf(Z[r])
        for k in impls:
            if rep:
                best[k] = min(best[k], tot[k] / (runs * T))
    return {k: v * 1e6 for k, v in best.items()}


def _radar_far_5deg() -> tuple[object, float, float]:
    """radar_far at 5 deg: (scenario, dt s, q m^2/s^3), typed, or on a base tree before the
    typed scenarios (no ``load_typed``: a base without its own worker) the dict."""
    try:
        from uavest.scenarios import load_typed
    except ImportError:
        from uavest.scenarios import load_scenario

        d = load_scenario("radar_far", ["radar.sigma_az_deg=5"])
        return d, float(d.get("dt", 1.0)), float(d["motion"]["q"])
    sc = load_typed("radar_far", ["radar.sigma_az_deg=5"])
    return sc, float(sc.dt), float(sc.motion.q)


def _radar(runs: int, repeats: int) -> dict:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from radar_compare import filterpy_run, stonesoup_run

    from uavest.core import Guarded, make_filter
    from uavest.core.gaussian import Gaussian
    from uavest.experiments.radar import data_rng
    from uavest.presets import build
    from uavest.tracking.scenario import build_models, generate_run, prior

    sc, dt, q = _radar_far_5deg()
    motion, radar = build_models(sc)
    _, P0 = prior(sc)
    data = [generate_run(sc, data_rng(0, r)) for r in range(runs)]
    hyb = build("hybrid", "radar", 4)
    ours = {"ekf": make_filter("ekf"), "ukf": make_filter("ukf"),
            "enkf100": make_filter("enkf", members=100), "hybrid": hyb}
    ours.update({f"{k}_guarded": Guarded(v, strikes=10**9) for k, v in list(ours.items())})
    impls = list(ours) + ["filterpy_ekf", "filterpy_ukf", "stonesoup_ekf", "stonesoup_ukf"]
    best = dict.fromkeys(impls, np.inf)
    K = None
    for rep in range(repeats + 1):  # pass 0 warms up (lazy imports, caches): not counted
        tot = dict.fromkeys(impls, 0.0)
        for r, rd in enumerate(data if rep else data[:1]):
            Z = [s[o == 0][0] if np.any(o == 0) else None
                 for s, o in zip(rd.scans, rd.origins, strict=True)]
            K = len(Z)
            for name, f in ours.items():
                tot[name] += _loop(f, motion, radar, Gaussian(rd.x0, P0), Z,
                                   np.random.default_rng([1, r]), dt)
            for kind in ("ekf", "ukf"):
                tot[f"filterpy_{kind}"] += filterpy_run(kind, motion, radar, rd.x0, P0, Z,
                                                        dt)[2]
                tot[f"stonesoup_{kind}"] += stonesoup_run(kind, q, radar, rd.x0, P0, Z,
                                                          dt)[2]
        for k in impls:
            if rep:
                best[k] = min(best[k], tot[k] / (runs * K))
    out = {k: v * 1e6 for k, v in best.items()}
    out["hybrid_members"] = hyb.members(4)
    return out


def _replay(window: float) -> dict:
    from uavest.apps.replay import ReplayConfig, replay

    out = {}
    t0 = _log_t0()  # warm the reader's imports
    # and everything a replay loads once per process (scipy's LAPACK, numba's kernel cache
    # where installed): a 2 s replay, in both trees alike, so the timed replays measure
    # the replay, not the imports (a fleet evaluation or a live run pays them once)
    replay(str(LOG), ReplayConfig(filters=("ekf", "ukf", "hybrid"), end=t0 + 2.0))
    for name, rate in (("default", None), ("full", 0.0)):
        cfg = ReplayConfig(filters=("ekf", "ukf", "hybrid"), rate_hz=rate,
                           end=None if window <= 0 else _log_t0() + window)
        c = time.process_time()
        doc = replay(str(LOG), cfg)
        cpu = time.process_time() - c
        # real-time factor by process CPU time (log reading included): the wall clock of
        # a shared machine swings with other processes' load; both are printed
        out[name] = {"rtf": doc["duration_s"] / cpu, "cpu_s": cpu,
                     "rtf_wall": doc["duration_s"] / doc["wall_s"], "wall_s": doc["wall_s"],
                     "duration_s": doc["duration_s"], "steps": doc["steps"]}
    return out


def _log_t0() -> float:
    from uavest.ingest import open_source
    from uavest.ingest.types import ImuSample

    for s in open_source(str(LOG)):
        if isinstance(s, ImuSample):
            return float(s.t)
    return 0.0


def _tracker(repeats: int, scans: int = 30) -> dict:
    from uavest.core import make_filter
    from uavest.models.motion import NearlyConstantVelocity
    from uavest.models.radar import RadarMeasurement
    from uavest.tracking.tracker import Tracker, TrackerConfig

    out = {}
    for n in (5, 20, 50):
        rng = np.random.default_rng(n)
        motion = NearlyConstantVelocity(2, 0.5)
        radar = RadarMeasurement(2, sigma_range=10.0, sigma_az=np.deg2rad(1.0))
        ang = rng.uniform(-np.pi, np.pi, n)
        rad = rng.uniform(3000.0, 15000.0, n)
        X = np.stack([rad * np.cos(ang), rad * np.sin(ang),
                      rng.normal(0, 30, n), rng.normal(0, 30, n)], axis=1)
        lo, hi = radar.measurement_box(20000.0)
        scan_list = []
        for _ in range(scans):
            X = motion.f(X, 0.0, 1.0) + rng.normal(0, 0.5, X.shape) * [0.5, 0.5, 1, 1]
            Z = np.vstack([radar.sample(X, rng), lo + (hi - lo) * rng.random((10, 2))])
            scan_list.append(Z[rng.permutation(len(Z))])
        best = np.inf
        for rep in range(repeats + 1):  # pass 0 warms up: not counted
            tk = Tracker(make_filter("ukf"), motion, TrackerConfig(),
                         np.random.default_rng(0))
            for k, Z in enumerate(scan_list):
                tk.step(k + 1, float(k + 1), 1.0, Z, radar)
            if rep:
                best = min(best, tk.seconds / scans)
        out[f"{n}+10"] = {"ms_per_scan": best * 1e3, "live_tracks": len(tk.tracks)}
    return out


def _help_time(n: int = 5) -> float:
    env = dict(os.environ)
    best = np.inf
    for _ in range(n):
        c0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "uavest", "--help"], env=env, check=True,
                       capture_output=True)
        best = min(best, time.perf_counter() - c0)
    return best


def worker(section: str, a) -> dict:
    if section == "ungm":
        return _ungm(a.runs, a.inner)
    if section == "radar":
        return _radar(a.runs, a.inner)
    if section == "replay":
        return _replay(a.window)
    if section == "tracker":
        return _tracker(a.inner)
    if section == "help":
        return {"help_s": _help_time()}
    raise ValueError(section)


# ------------------------------------------------------------------------------ driver


def _old_tree(base: str, tmp: Path) -> Path:
    """``base``'s package and benchmarks in ``tmp/old`` (``git archive``), with
    ``tmp/shared`` linked to the shared logs beside this checkout, so that the base's own
    worker finds ``sample.ulg`` where it looks (``../shared/logs``)."""
    def archive(*paths: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", "-C", str(ROOT), "archive", base, *paths],
                              capture_output=True)

    p = archive("uavest", "benchmarks")
    if p.returncode != 0:  # a base without benchmarks/: this script's worker runs it
        p = archive("uavest")
        p.check_returncode()
    dest = tmp / "old"
    with tarfile.open(fileobj=io.BytesIO(p.stdout)) as tf:
        tf.extractall(dest, filter="data")
    if (ROOT.parent / "shared").is_dir():
        (tmp / "shared").symlink_to(ROOT.parent / "shared")
    return dest


def _worker_script(tree: Path) -> Path:
    """The tree's own ``benchmarks/speed_report.py`` (its worker speaks that tree's API:
    a base before an API change cannot run this tree's worker), else this script."""
    own = tree / "benchmarks" / "speed_report.py"
    return own if own.is_file() else Path(__file__).resolve()


def _run(tree: Path, section: str, a) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, str(_worker_script(tree)), "--worker", section,
           "--runs", str(a.runs), "--inner", str(a.inner), "--window", str(a.window)]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tree.parent)
    if p.returncode != 0:
        raise RuntimeError(f"{section} on {tree} failed:\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", default=DEFAULT_BASE)
    ap.add_argument("--repeats", type=int, default=2, help="worker runs per tree")
    ap.add_argument("--inner", type=int, default=3, help="best-of inside a worker")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--window", type=float, default=0.0,
                    help="replay only the first seconds of sample.ulg (0: the whole log, "
                    "the default; a window still reads the whole log, so ingest then "
                    "dominates the wall time)")
    ap.add_argument("--sections", default="help,ungm,radar,tracker,replay")
    ap.add_argument("--json", default=None)
    ap.add_argument("--worker", default=None)
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(worker(a.worker, a)))
        return
    res: dict = {"new": {}, "old": {}}
    with tempfile.TemporaryDirectory() as td:
        trees = {"old": _old_tree(a.base, Path(td)), "new": ROOT}
        for sec in a.sections.split(","):
            for _ in range(a.repeats):
                for which in ("old", "new"):
                    r = _run(trees[which], sec, a)
                    prev = res[which].get(sec)
                    res[which][sec] = r if prev is None else _keep_best(prev, r)
            print(f"[{sec} done]", file=sys.stderr, flush=True)
    report(res, a)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))


def _keep_best(a: dict, b: dict) -> dict:
    """Element-wise best of two worker results: smaller times, larger real-time factors."""
    out = {}
    for k, v in a.items():
        w = b[k]
        if isinstance(v, dict):
            out[k] = _keep_best(v, w)
        elif k in ("rtf",):
            out[k] = max(v, w)
        elif k in ("duration_s", "steps", "live_tracks", "hybrid_members"):
            out[k] = v
        else:
            out[k] = min(v, w)
    return out


def report(res: dict, a) -> None:
    new, old = res["new"], res["old"]
    lines = [f"speed report (base {a.base}; best of {a.repeats} worker runs x "
             f"{a.inner} passes; BLAS 1 thread)"]

    def row(label, n, o, unit):
        lines.append(f"  {label:26s} new {n:10.1f} {unit}   old {o:10.1f} {unit}   "
                     f"new/old {n / o:6.3f}")

    goals = []
    if "help" in new:
        n, o = new["help"]["help_s"], old["help"]["help_s"]
        lines.append("start-up: python -m uavest --help")
        row("--help", n * 1e3, o * 1e3, "ms")
        goals.append(("--help <= 0.8 s", f"{n:.2f} s", n <= 0.8))
    for sec in ("ungm", "radar"):
        if sec not in new:
            continue
        N, O = new[sec], old[sec]
        lines.append(f"{sec}: us per predict + update + estimate")
        for k in N:
            if k == "hybrid_members":
                continue
            row(k, N[k], O[k], "us")
        lines.append("  ratios within one worker process:")
        for lib in ("filterpy", "stonesoup"):
            for kind in ("ukf", "ekf"):
                key = f"{lib}_{kind}"
                if key in N:
                    lines.append(f"    our {kind} / {key:15s} {N[kind] / N[key]:6.3f}   "
                                 f"(old {O[kind] / O[key]:6.3f})")
        h = N["hybrid"] / N["ukf"]
        lines.append(f"    hybrid / ukf (estimate incl.) {h:6.3f}   "
                     f"(old {O['hybrid'] / O['ukf']:6.3f})")
        hg = N["hybrid_guarded"] / N["ukf_guarded"]
        lines.append(f"    guarded hybrid / guarded ukf  {hg:6.3f}   "
                     f"(old {O['hybrid_guarded'] / O['ukf_guarded']:6.3f})")
        goals.append((f"{sec}: hybrid/ukf <= {2.5 if sec == 'ungm' else 4}", f"{h:.2f}",
                      h <= (2.5 if sec == "ungm" else 4.0)))
        if sec == "radar":
            e = N["ekf"] / N["filterpy_ekf"]
            goals.append(("radar: our EKF / FilterPy EKF <= 1.0", f"{e:.2f}", e <= 1.0))
        u = N["ukf"] / N["filterpy_ukf"]
        goals.append((f"{sec}: our UKF / FilterPy UKF <= 0.2", f"{u:.3f}", u <= 0.2))
    if "tracker" in new:
        lines.append("tracker (GNN, UKF tracks), ms per scan, 10 clutter points per scan")
        for k in new["tracker"]:
            n, o = new["tracker"][k]["ms_per_scan"], old["tracker"][k]["ms_per_scan"]
            row(f"{k} targets (live {new['tracker'][k]['live_tracks']})", n, o, "ms")
        r = new["tracker"]["50+10"]["ms_per_scan"] / old["tracker"]["50+10"]["ms_per_scan"]
        goals.append(("tracker 50+10: new/old <= 0.4", f"{r:.3f}", r <= 0.4))
    if "replay" in new:
        lines.append(f"replay sample.ulg, ekf+ukf+hybrid, {a.window or 'whole'} s of log: "
                     "real-time factor (log s / process CPU s, log reading included, imports "
                     "warmed by a 2 s replay first; by the wall clock in brackets)")
        for k in ("default", "full"):
            n, o = new["replay"][k], old["replay"][k]
            lines.append(f"  {k:8s} rate  new {n['rtf']:6.2f}x  old {o['rtf']:6.2f}x   "
                         f"speed-up {n['rtf'] / o['rtf']:5.2f}  ({n['steps']} steps; wall "
                         f"new {n.get('rtf_wall', 0):.2f}x old {o.get('rtf_wall', 0):.2f}x)")
        f = new["replay"]["full"]["rtf"]
        d = new["replay"]["default"]["rtf"] / old["replay"]["default"]["rtf"]
        goals.append(("full-rate replay >= 5x real time", f"{f:.2f}x", f >= 5.0))
        goals.append(("default-rate replay >= 3x faster", f"{d:.2f}x", d >= 3.0))
    lines.append("goals:")
    for g, v, ok in goals:
        lines.append(f"  {'met ' if ok else 'MISS'}  {g:40s} {v}")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
