"""Same-run speed comparison: the streaming engine against the code before it (commit
05bb455, the batch pipeline), on this machine, alternating old and new.

    python benchmarks/engine_vs_batch.py [--rounds 3] [--logs ../shared/logs]
                                         [--old-commit 05bb455] [--skip-replay]

The old code is taken from the repository's own history (``git archive 05bb455 uavest
scenarios`` into a temporary directory) and every measurement, old or new, runs in its own
subprocess (PYTHONPATH = that tree), one at a time, old and new alternating for
``--rounds`` rounds; the medians over rounds and the ratios new/old are printed. BLAS is
pinned to one thread in the subprocesses.

(a) UKF step time on the UNGM, on the same data (the new tree's trial data, saved once and
    loaded by both): ``bare`` = the same predict + update loop (defined here, identical for
    both trees) over each tree's UKF; ``bare+estimate`` = that loop plus ``estimate()``
    each step; ``own`` = each tree's own speed-benchmark loop (old:
    ``uavest.bench.speed._time_ours``, predict + update; new:
    ``uavest.experiments.speed._time_ours``, the engine's ``FilterRunner``, predict +
    update + estimate). Best of 5 passes of 20 runs x 100 steps within a subprocess.
(b) Replay of each log with ekf, ukf, hybrid (old ``uavest.pipeline.replay.replay``, new
    ``uavest.apps.replay.replay``, default configuration, seed 0): the replay speed each
    reports (``realtime_factor``: log duration / the wall time it measures; the old one
    excludes reading the log, the new one streams the log through the filters, so its
    wall time includes parsing and scoring) and the end-to-end wall time of the call
    including reading (like for like), plus each filter's us per step.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_SPEED = r"""
import json, sys, time
import numpy as np
tree, zpath = sys.argv[1], sys.argv[2]
if tree == "old":
    from uavest.bench.scenario import load_scenario
    from uavest.bench.systems import build_system
    from uavest.bench.speed import _time_ours
else:
    from uavest.scenarios import load_scenario
    from uavest.experiments.systems import build_system
    from uavest.experiments.speed import _time_ours
from uavest.core.unscented import UKF

sysm = build_system(load_scenario("ungm"))
Z = np.load(zpath)["Z"]
tr, me = sysm.transition, sysm.measurement
ukf = UKF()

def bare(flt, with_estimate):
    runs, T = Z.shape[:2]
    t0 = time.perf_counter()
    for r in range(runs):
        rng = np.random.default_rng([0, r])
        s = flt.init(sysm.filter_prior, tr.space, rng)
        for k in range(T):
            s = flt.predict(s, tr, (k + 1) * sysm.dt, sysm.dt, None, rng)
            s, _ = flt.update(s, Z[r, k], me, rng)
            if with_estimate:
                flt.estimate(s)
    return (time.perf_counter() - t0) / (runs * T)

res = {"bare": [], "bare+estimate": [], "own": []}
for _ in range(5):
    res["bare"].append(bare(ukf, False))
    res["bare+estimate"].append(bare(ukf, True))
    res["own"].append(_time_ours(ukf, sysm, Z, 0))
print(json.dumps({k: min(v) * 1e6 for k, v in res.items()}))
"""

_REPLAY = r"""
import json, sys, time
tree, log = sys.argv[1], sys.argv[2]
if tree == "old":
    from uavest.pipeline.replay import ReplayConfig, replay
else:
    from uavest.apps.replay import ReplayConfig, replay
cfg = ReplayConfig(filters=("ekf", "ukf", "hybrid"))
t0 = time.perf_counter()
doc = replay(log, cfg)
total = time.perf_counter() - t0
out = {"realtime_factor": doc["realtime_factor"], "wall_s": doc["wall_s"],
       "total_s": total, "duration_s": float(doc.get("duration_s") or 0.0)}
for k in ("ekf", "ukf", "hybrid"):
    row = doc["filters"][k]
    out["us_" + k] = row["us_per_step"]
    out["yaw_" + k] = row.get("yaw_rmse_deg")
print(json.dumps(out))
"""


def old_tree(commit: str, dest: Path) -> Path:
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "uavest", "scenarios"],
                         capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(dest, filter="data")
    return dest


def child(tree: str, path: Path, script: str, *args: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(path), OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", script, tree, *args], env=env, cwd=path,
                         capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"{tree} child failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def medians(rows: list[dict]) -> dict:
    return {k: statistics.median(r[k] for r in rows) for k in rows[0]
            if all(isinstance(r[k], (int, float)) for r in rows)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--logs", default=str(ROOT.parent / "shared" / "logs"))
    ap.add_argument("--old-commit", default="05bb455")
    ap.add_argument("--skip-replay", action="store_true")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    trees: dict[str, Path] = {"new": ROOT}
    result: dict = {"old_commit": args.old_commit, "rounds": args.rounds}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_p = Path(tmp)
        trees["old"] = old_tree(args.old_commit, tmp_p / "old")
        # the same UNGM data for both trees: the new tree's trial data, 20 runs
        zpath = tmp_p / "ungm_Z.npz"
        subprocess.run([sys.executable, "-c", (
            "import sys, numpy as np\n"
            "from uavest.scenarios import load_scenario\n"
            "from uavest.experiments.systems import build_system\n"
            "from uavest.experiments.montecarlo import trial_data\n"
            "s = build_system(load_scenario('ungm'))\n"
            "np.savez(sys.argv[1], Z=np.stack([trial_data(s, 0, r)[1] for r in range(20)]))\n"
        ), str(zpath)], env=dict(os.environ, PYTHONPATH=str(ROOT)), check=True)
        speed = {"old": [], "new": []}
        for i in range(args.rounds):
            for tree in ("old", "new"):
                speed[tree].append(child(tree, trees[tree], _SPEED, str(zpath)))
                print(f"round {i + 1} speed {tree}: "
                      + ", ".join(f"{k} {v:.1f}" for k, v in speed[tree][-1].items()),
                      flush=True)
        result["ukf_us_per_step"] = {t: medians(v) for t, v in speed.items()}
        result["ukf_rounds"] = speed
        logs = [] if args.skip_replay else ["sample.ulg", "vtol.tlog"]
        for log in logs:
            path = Path(args.logs) / log
            if not path.is_file():
                print(f"{path}: not present, skipped")
                continue
            rep = {"old": [], "new": []}
            for i in range(args.rounds):
                for tree in ("old", "new"):
                    rep[tree].append(child(tree, trees[tree], _REPLAY, str(path.resolve())))
                    r = rep[tree][-1]
                    print(f"round {i + 1} replay {log} {tree}: realtime "
                          f"{r['realtime_factor']:.1f}x, total {r['total_s']:.2f} s",
                          flush=True)
            result[log] = {"rounds": rep, "median": {t: medians(v) for t, v in rep.items()}}
    print()
    print(f"UKF on the UNGM, us per step (median over {args.rounds} rounds of best-of-5; "
          f"old = {args.old_commit}):")
    print(f"{'loop':<15} {'old':>8} {'new':>8} {'new/old':>8}")
    u = result["ukf_us_per_step"]
    for k in ("bare", "bare+estimate", "own"):
        print(f"{k:<15} {u['old'][k]:8.1f} {u['new'][k]:8.1f} {u['new'][k] / u['old'][k]:8.2f}")
    print(f"new engine runner (own) / old bench loop (own, no estimate): "
          f"{u['new']['own'] / u['old']['own']:.2f}; "
          f"new runner / new bare+estimate: {u['new']['own'] / u['new']['bare+estimate']:.2f}")
    for log in logs:
        if log not in result:
            continue
        m = result[log]["median"]
        print(f"\nreplay {log}, ekf+ukf+hybrid, medians over {args.rounds} rounds:")
        print(f"{'quantity':<28} {'old':>9} {'new':>9} {'new/old':>8}")
        for k, lab in (("realtime_factor", "realtime factor (reported)"),
                       ("total_s", "end-to-end s (incl. read)"),
                       ("us_ekf", "ekf us/step"), ("us_ukf", "ukf us/step"),
                       ("us_hybrid", "hybrid us/step")):
            print(f"{lab:<28} {m['old'][k]:9.2f} {m['new'][k]:9.2f} "
                  f"{m['new'][k] / m['old'][k]:8.2f}")
        rt_total = {t: m[t]["duration_s"] / m[t]["total_s"] for t in ("old", "new")}
        print(f"{'realtime incl. read':<28} {rt_total['old']:9.2f} {rt_total['new']:9.2f} "
              f"{rt_total['new'] / rt_total['old']:8.2f}")
        print("yaw RMSE old / new: " + ", ".join(
            f"{k} {m['old']['yaw_' + k]:.3f} / {m['new']['yaw_' + k]:.3f}"
            for k in ("ekf", "ukf", "hybrid")))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
