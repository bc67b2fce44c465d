"""Where the hybrid earns its place (issue 19 item 4): EKF, UKF and the hybrid on the
navigation model (GNSS-aided INS), side by side on the same seeded simulated flights.

    OMP_NUM_THREADS=1 python benchmarks/nav_hybrid.py [--runs 50] [--seed 0]
        [--cases heading,outage,magdist] [--filters ekf,ukf,hybrid] [--gate mag,gnss]
        [--filter-rate 25] [--mag-rate 12.5] [--mag-dip 64] [--jobs 1] [--json out.json]

Cases (uavest/experiments/nav.py, ``CASES``): (a) ``heading``: no magnetometer, the
true initial yaw uniform in [-pi, pi), every filter starts at yaw 0 with std pi/sqrt(3);
(b) ``outage``: 30 s without GNSS mid-flight, magnetometer on; (c) ``magdist``: the
magnetometer heading off by 30 deg for 20 s. One table per case; every trial r of every
filter sees the same flight and start (``uavest.seeding`` streams of (seed, r)), so the
numbers do not depend on ``--runs``, ``--jobs`` or the other filters (cost apart).
Filters are resolved in the ``nav`` preset (what ``uavest replay`` runs with the
navigation model: ``hybrid`` = n_cloud 16, tau 0.9, re-spread, M = 527 members on the
15-dim state; ``ukf`` = alpha 0.1) and guarded.

Columns: ``conv s`` median time to converge (yaw error < 5 deg from then to the end; inf
when not converged), ``n/c`` trials not converged at the end (divergences), ``conv|ok``
mean time over the converged ones; RMSE in the case's window (roll / pitch / yaw deg,
3-D velocity m/s, horizontal position m), ``max pos`` median over trials of the largest
horizontal error in the window (m); ``NEES`` mean of the 9-dof (attitude, velocity,
position) NEES, ``in95`` fraction of steps inside its per-step 95 % band [2.70, 19.0];
``resets`` guard resets (all trials), ``rej/run`` gated measurements per trial (0 without
``--gate``); ``us/step`` mean cost per filter step, ``xUKF`` median over trials of the
ratio to the UKF's in the same trial.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from functools import partial

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from uavest.core.registry import split_filter_list  # noqa: E402
from uavest.experiments import nav  # noqa: E402


def _trial(r: int, case: str, specs: list[str], seed: int, sim: nav.NavSim) -> dict:
    return nav.run_trial(nav.CASES[case], specs, seed, r, sim)


def _fmt(v: float, nd: int = 2) -> str:
    return "inf" if v == math.inf else f"{v:.{nd}f}"


def table(title: str, agg: dict[str, dict]) -> str:
    """The printed table of one case."""
    head = (f"{'filter':18s} {'conv s':>6s} {'n/c':>4s} {'conv|ok':>7s} {'roll':>6s} "
            f"{'pitch':>6s} {'yaw':>6s} {'vel':>6s} {'pos':>7s} {'maxpos':>7s} {'NEES':>8s} "
            f"{'in95':>5s} {'resets':>6s} {'rej/run':>7s} {'us/step':>7s} {'xUKF':>5s}")
    lines = [title, head]
    for lab, a in agg.items():
        lines.append(
            f"{lab:18s} {_fmt(a['converge_median_s'], 1):>6s} {a['not_converged']:4d} "
            f"{_fmt(a['converge_mean_s'], 1):>7s} {a['roll_deg']:6.2f} {a['pitch_deg']:6.2f} "
            f"{a['yaw_deg']:6.2f} {a['vel_mps']:6.2f} {a['pos_m']:7.2f} {a['max_pos_m']:7.2f} "
            f"{a['nees_mean']:8.1f} {a['nees_in_band']:5.2f} {a['resets']:6d} "
            f"{a['rejected_per_run']:7.1f} {a['us_per_step']:7.0f} {a['cost_vs_ukf']:5.2f}")
    for lab, a in agg.items():
        if a["reset_reasons"]:
            why = ", ".join(f"{k} x{v}" for k, v in sorted(a["reset_reasons"].items()))
            lines.append(f"  {lab} resets: {why}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=50, help="Monte Carlo trials per case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default="heading,outage,magdist",
                    help=f"comma list of {', '.join(nav.CASES)}")
    ap.add_argument("--filters", default="ekf,ukf,hybrid",
                    help="filter specs (nav preset); include ukf for the xUKF column")
    ap.add_argument("--gate", default="", help="gate these aiding sensors: gnss, mag")
    ap.add_argument("--filter-rate", type=int, default=nav.NavSim().filter_rate,
                    help="filter steps per s (IMU at 200 Hz averaged into them)")
    ap.add_argument("--mag-rate", type=float, default=nav.NavSim().mag_rate,
                    help="magnetometer samples per s (filter rate a whole multiple)")
    ap.add_argument("--mag-dip", type=float, default=nav.NavSim().mag_dip,
                    help="inclination of the simulated field, deg")
    ap.add_argument("--jobs", type=int, default=1, help="processes (trials are independent)")
    ap.add_argument("--json", help="write the tables (and the settings) to this file")
    a = ap.parse_args(argv)
    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    bad = [c for c in cases if c not in nav.CASES]
    gate = tuple(g.strip() for g in a.gate.split(",") if g.strip())
    if bad or a.runs < 1 or a.jobs < 1 or any(g not in ("gnss", "mag") for g in gate):
        print(f"nav_hybrid: bad --cases/--runs/--jobs/--gate ({', '.join(bad) or a.gate}); "
              f"cases: {', '.join(nav.CASES)}; gate: gnss, mag", file=sys.stderr)
        return 2
    specs = split_filter_list(a.filters)
    try:
        sim = replace(nav.NavSim(), gate=gate, filter_rate=a.filter_rate,
                      mag_rate=a.mag_rate, mag_dip=a.mag_dip)
    except ValueError as e:
        print(f"nav_hybrid: {e}", file=sys.stderr)
        return 2
    cmd = "python benchmarks/nav_hybrid.py " + " ".join(sys.argv[1:] if argv is None else argv)
    print(f"{cmd}\n{a.runs} runs per case, seed {a.seed}, IMU {sim.imu_rate} Hz -> filter "
          f"{sim.filter_rate} Hz, GNSS {sim.gnss_rate:g} Hz, mag {sim.mag_rate:g} Hz "
          f"(dip {sim.mag_dip:g} deg), "
          f"gate: {', '.join(gate) or 'none'}; preset {nav.PRESET}\n")
    out: dict = {"command": cmd, "runs": a.runs, "seed": a.seed, "filters": specs,
                 "gate": list(gate), "filter_rate": sim.filter_rate, "cases": {}}
    pool = ProcessPoolExecutor(a.jobs) if a.jobs > 1 else None
    try:
        for c in cases:
            t0 = time.perf_counter()
            fn = partial(_trial, case=c, specs=specs, seed=a.seed, sim=sim)
            rows = list(pool.map(fn, range(a.runs)) if pool else map(fn, range(a.runs)))
            agg = nav.aggregate(rows)
            case = nav.CASES[c]
            title = (f"{case.title}; {case.duration:g} s flight, scored "
                     f"{case.window[0]:g}-{min(case.window[1], case.duration):g} s "
                     f"({time.perf_counter() - t0:.0f} s wall)")
            print(table(title, agg) + "\n", flush=True)
            out["cases"][c] = {"title": case.title, "window": list(case.window),
                               "duration": case.duration, "table": agg}
    finally:
        if pool:
            pool.shutdown()
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
