"""Radar filters against the PCRLB: radar_far and radar_crossing at 1 and 5 deg bearing
noise, 100 runs each (the standard bound-comparison set-up of docs/tracking.md).

Columns: ``ratio`` = mean per-scan RMSE / mean per-scan PCRLB; ``rms`` = the same with
RMS over scans, sqrt(mean MSE / mean bound^2); ``cond`` = mean per-scan RMSE over the mean
conditional (per-run, oracle-linearised) bound, which is not a lower bound but shows how
much of the gap to the PCRLB is the unconditional bound's looseness (docs/tracking.md).

    python benchmarks/radar_bound.py [--runs 100] [--seed 0] [--filters ekf,ukf,hybrid]
                                     [--json out.json]

Same code path as ``uavest bench radar_far --set radar.sigma_az_deg=1`` etc.
"""

from __future__ import annotations

import argparse
import json

from uavest.bench.scenario import load_scenario
from uavest.core.registry import split_filter_list
from uavest.tracking.bench import run_bench


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--filters", default="ekf,ukf,hybrid")
    ap.add_argument("--cases", default="radar_far:1,radar_far:5,radar_crossing:1,radar_crossing:5")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    filters = split_filter_list(a.filters)
    out = {}
    hdr = (f"{'case':<20}{'filter':<40}{'pos_rmse':>9}{'vel_rmse':>9}{'pcrlb_p':>9}"
           f"{'ratio':>7}{'rms':>7}{'cond':>7}{'vratio':>7}{'nees':>8}{'band':>14}"
           f"{'us/step':>9}")
    print(hdr)
    print("-" * len(hdr))
    for case in a.cases.split(","):
        name, deg = case.split(":")
        sc = load_scenario(name, [f"radar.sigma_az_deg={deg}"])
        res = run_bench(sc, filters, a.runs, a.seed, None)
        out[f"{name}@{deg}deg"] = res
        for lab, v in res.items():
            band = f"[{v['nees_band'][0]:.2f},{v['nees_band'][1]:.2f}]"
            print(f"{name + '@' + deg + 'deg':<20}{lab:<40}{v['pos_rmse']:>9.1f}"
                  f"{v['vel_rmse']:>9.2f}{v['pcrlb_pos']:>9.1f}{v['pcrlb_ratio']:>7.3f}"
                  f"{v['pcrlb_ratio_rms']:>7.3f}{v['cond_ratio']:>7.3f}"
                  f"{v['pcrlb_vel_ratio']:>7.3f}{v['nees_mean']:>8.2f}{band:>14}"
                  f"{v['us_per_step']:>9.0f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
