"""Speed of the navigation model in replay: us per step of each filter (without the
warm-up steps) and the real-time factor of a replay with that filter alone (log duration
/ wall time, reading the log included), on a 200 Hz log at the default filter rate, and
the hybrid's step against the UKF's, and a speed index of the machine (a Python loop
and small numpy calls) to compare runs made on different days.

The log: ``logs/sim_200hz.tlog`` (the project's simulator, RAW_IMU at 200 Hz, GPS_RAW_INT
at 5 Hz; see logs/README.md). The filters take turns, each replayed ``--repeat`` times
(2) in this process; the first round warms up (numba compilation and first-use caches)
and each filter's best later run is reported, with its real-time factor. The machine
may be shared: the load average is printed before and after.

    PYTHONPATH=. python benchmarks/nav_speed.py [--log PATH] [--rate HZ]
        [--filters ekf,ukf,hybrid] [--repeat N]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

from uavest.apps.replay import ReplayConfig, replay  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def machine_index() -> str:
    """The machine's speed at this benchmark's kind of work, to compare runs made on
    different days (the shared machines' speed moves 2-3x): the best of 5 of a Python loop
    of 10^6 additions and of 10^4 numpy calls on 3-vectors, ms."""
    import time

    import numpy as np

    def best(f) -> float:
        out = []
        for _ in range(5):
            t = time.perf_counter()
            f()
            out.append(time.perf_counter() - t)
        return 1e3 * min(out)

    def loop() -> None:
        s = 0
        for i in range(10**6):
            s += i

    def calls() -> None:
        v = np.ones(3)
        for _ in range(10**4):
            np.isfinite(v).all()

    return (f"machine: 10^6 Python additions {best(loop):.0f} ms, 10^4 numpy calls "
            f"{best(calls):.1f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", default=str(ROOT / "logs" / "sim_200hz.tlog"))
    ap.add_argument("--rate", type=float, default=None,
                    help="filter rate cap, Hz (0: every sample)")
    ap.add_argument("--filters", default="ekf,ukf,hybrid")
    ap.add_argument("--model", default="nav", choices=("nav", "attitude"))
    ap.add_argument("--repeat", type=int, default=2,
                    help="replays of each filter, the filters taking turns; the first "
                         "warms up, the best of the rest is reported (a shared machine's "
                         "noise only ever slows a run down)")
    a = ap.parse_args()
    if a.repeat < 2:
        ap.error("--repeat must be at least 2 (the first replay warms up)")
    print(f"load average before: {os.getloadavg()[0]:.2f}; {machine_index()}")
    rows: dict[str, tuple[float, float, float, float]] = {}
    for k in range(a.repeat):
        for f in a.filters.split(","):
            doc = replay(a.log, ReplayConfig(filters=(f,), rate_hz=a.rate, model=a.model))
            r = doc["filters"][f]
            if k and (f not in rows or r["us_per_step"] < rows[f][0]):
                rows[f] = (r["us_per_step"], doc["realtime_factor"], doc["filter_rate_hz"],
                           doc["imu_rate_hz"])
    print(f"{'filter':8s} {'us/step':>9s} {'x real time':>11s}  (filter Hz, IMU Hz)")
    for f, (us, rt, fr, ir) in rows.items():
        print(f"{f:8s} {us:9.0f} {rt:11.1f}  ({fr:.1f}, {ir:.1f})")
    if "hybrid" in rows and "ukf" in rows:
        print(f"hybrid / ukf step: {rows['hybrid'][0] / rows['ukf'][0]:.2f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
