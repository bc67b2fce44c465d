"""Speed-up of ``uavest evaluate`` with 2 workers over 1, and the per-input overhead of
the Dask path against the process pool, in one run.

Workloads:

- 40 logs: 4-second windows of ``logs/sim_200hz.tlog`` starting every 1.4 s (overlapping,
  so each window has different bytes: identical copies would share one content hash and
  be evaluated once), filters ekf,ukf,hybrid (attitude preset);
- 400 UNGM trials in shards of 25 (default filters ekf,ukf,hybrid; bench preset);
- overhead: near-empty tasks (1 trial of 1 step, ekf), 40 then 160 of them on 2 workers:
  (wall(160) - wall(40)) / 120 is the backend's cost of one input (submit, ship, run,
  return, store the result), without the fixed start-up costs.

Each configuration evaluates into a fresh result folder (nothing reused). Pool times
include starting the pool (a user pays it); the Dask LocalCluster is started before the
clock (a real cluster is already up) and its start is printed separately. The machine may
be shared: the load average is printed before and after; rerun for a second sample.

    PYTHONPATH=. python benchmarks/evaluate_speedup.py [--filters ekf,ukf,hybrid] [--quick]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from uavest.fleet import PoolBackend, build_plan, execute, summarize  # noqa: E402
from uavest.fleet.tools import cut_tlog  # noqa: E402

CPU: dict[str, list] = {}


def _timed(plan, out: Path, backend, tag: str | None = None) -> tuple[float, dict]:
    """Wall time of one evaluation; with ``tag`` also records (sum of the tasks' wall
    times / run wall = how many tasks ran at once, sum of the tasks' CPU seconds)."""
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    docs, stats = execute(plan, out, backend)
    wall = time.perf_counter() - t0
    assert stats.failed == 0, "a task failed"
    if tag:
        el = sum(d["elapsed_s"] for d in docs.values())
        cpu = sum(d["cpu_s"] for d in docs.values())
        CPU.setdefault(tag, []).append((el / wall, cpu))
    return wall, summarize(plan, docs, stats)


def _numbers(groups: dict) -> dict:
    drop = ("us_per_step", "us_per_step_mean", "wall_s", "realtime_factor")
    return {g: {lab: {k: v for k, v in a.items() if k not in drop}
                for lab, a in s["aggregate"].items()} for g, s in groups.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--filters", default="ekf,ukf,hybrid")
    ap.add_argument("--logs", type=int, default=40)
    ap.add_argument("--trials", type=int, default=400)
    ap.add_argument("--repeats", type=int, default=2,
                    help="repeat every measurement, interleaved; the best is reported")
    ap.add_argument("--quick", action="store_true", help="10 logs, 100 trials (a smoke run)")
    a = ap.parse_args()
    if a.quick:
        a.logs, a.trials = 10, 100
    filters = a.filters.split(",")
    import dask
    from distributed import Client, LocalCluster

    dask.config.set({"distributed.scheduler.allowed-failures": 1})
    tmp = Path(tempfile.mkdtemp(prefix="uavest-evalbench-"))
    print(f"load average before: {os.getloadavg()}; cores: {os.cpu_count()}")
    logs = tmp / "logs"
    logs.mkdir()
    for i in range(a.logs):
        cut_tlog(REPO / "logs" / "sim_200hz.tlog", logs / f"w{i:02d}.tlog", 1.4 * i,
                 1.4 * i + 4.0)
    plans = {
        f"{a.logs} logs": build_plan([str(logs)], filters=filters),
        f"{a.trials} UNGM trials": build_plan(["ungm"], trials=a.trials, shard_size=25,
                                              filters=filters),
    }
    empty = {k: build_plan(["ungm"], trials=k, shard_size=1, steps=1, filters=["ekf"],
                           seed=7) for k in (40, 160)}
    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           host="127.0.0.1", dashboard_address=":0")
    client = Client(cluster)
    dask_start = time.perf_counter() - t0
    from uavest.fleet import DaskBackend

    dask_b = DaskBackend(client)
    rows = []
    over: dict[int, tuple[list, list]] = {k: ([], []) for k in empty}
    times: dict[str, tuple[list, list, list]] = {k: ([], [], []) for k in plans}
    try:
        warm = build_plan(["ungm"], trials=2, shard_size=1, steps=1, filters=["ekf"], seed=9)
        _timed(warm, tmp / "warm", PoolBackend(2))  # start the forkserver once
        _timed(warm, tmp / "warm", dask_b)  # import uavest on the Dask workers once
        for rep in range(a.repeats):
            for name, plan in plans.items():
                t1, s1 = _timed(plan, tmp / "p1", PoolBackend(1), f"{name}|pool-1")
                t2, s2 = _timed(plan, tmp / "p2", PoolBackend(2), f"{name}|pool-2")
                td, sd = _timed(plan, tmp / "d2", dask_b, f"{name}|dask-2")
                same = _numbers(s1["groups"]) == _numbers(s2["groups"]) == _numbers(sd["groups"])
                assert same, "numbers differ between backends"
                for lst, t in zip(times[name], (t1, t2, td), strict=True):
                    lst.append(t)
                print(f"  [{rep + 1}/{a.repeats}] {name}: pool-1 {t1:.1f} s, pool-2 {t2:.1f} s, "
                      f"dask-2 {td:.1f} s (load {os.getloadavg()[0]:.1f})", flush=True)
            for k, plan in empty.items():
                over[k][0].append(_timed(plan, tmp / "p2", PoolBackend(2))[0])
                over[k][1].append(_timed(plan, tmp / "d2", dask_b)[0])
        for name, plan in plans.items():
            t1, t2, td = (min(x) for x in times[name])
            rows.append((name, len(plan.tasks()), t1, t2, td))
    finally:
        client.close()
        cluster.close()
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"\nDask LocalCluster start (not in the times): {dask_start:.1f} s; "
          f"times are the best of {a.repeats}")
    print(f"{'workload':28s} {'tasks':>5s} {'pool 1w s':>9s} {'pool 2w s':>9s} "
          f"{'2w/1w':>6s} {'dask 2w s':>9s} {'dask/pool2':>10s} {'ms/task pool2':>13s} "
          f"{'ms/task dask':>12s}")
    for name, n, t1, t2, td in rows:
        print(f"{name:28s} {n:5d} {t1:9.2f} {t2:9.2f} {t1 / t2:6.2f} {td:9.2f} "
              f"{td / t2:10.2f} {1e3 * t2 / n:13.1f} {1e3 * td / n:12.1f}")
    po = (min(over[160][0]) - min(over[40][0])) / 120
    do = (min(over[160][1]) - min(over[40][1])) / 120
    print(f"\nper-input overhead (empty tasks on 2 workers, (wall 160 - wall 40) / 120): "
          f"pool {1e3 * po:.1f} ms, dask {1e3 * do:.1f} ms, dask/pool {do / po:.2f}x, "
          f"dask - pool {1e3 * (do - po):+.1f} ms per input")
    print("  (best walls: " + ", ".join(f"{k} tasks pool {min(p):.2f} s dask {min(d):.2f} s"
                                        for k, (p, d) in over.items()) + ")")
    print(f"best of {a.repeats}; every run: " + "; ".join(
        f"{name}: " + " / ".join(",".join(f"{t:.1f}" for t in lst) for lst in ts)
        for name, ts in times.items()) + "  (pool-1 / pool-2 / dask-2 s)")
    print("\nconcurrency (sum of task walls / run wall) and CPU s of all tasks, per run:")
    for tag, v in CPU.items():
        print(f"  {tag:36s} " + "; ".join(f"{c:.2f} at once, {cpu:.1f} CPU s" for c, cpu in v))
    print(f"load average after: {os.getloadavg()} (shared machine: figures are noisy)")
    print("numbers: every aggregate identical across pool-1, pool-2 and dask-2")
    return 0


if __name__ == "__main__":
    sys.exit(main())
