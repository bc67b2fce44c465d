"""Command line: ``uavest bench``, ``uavest track``, ``uavest replay``, ``uavest list``.

``uavest`` with no arguments runs the main job on its embedded default: the UNGM
benchmark of all filters (a built-in simulated scenario; no hardware, no SITL).
"""

from __future__ import annotations

import os

# The filters do many small (n <= ~10) matrix operations. A multi-threaded BLAS only adds
# synchronisation to those: on 2 busy cores the hybrid's step went from ~0.5 ms to 7-15 ms.
# Pin BLAS to one thread for the command line (before numpy loads); a user's explicit
# setting wins. Library users keep control of their own process.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402

from ..core.registry import FILTER_NAMES, split_filter_list  # noqa: E402
from ..scenarios import ScenarioError, list_scenarios, load_scenario  # noqa: E402
from .report import Progress, table, write_json  # noqa: E402


def _bench_parser(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="Monte Carlo benchmark of filters on a scenario",
        description="Run filters side by side on the same seeded truths and measurements.",
    )
    p.add_argument("scenario", nargs="?", default="ungm",
                   help="scenario name (ungm, nonlinear2d, linear_cv, radar_*) or a .toml path")
    p.add_argument("--filters", help="comma-separated filter specs, e.g. "
                   "'ukf,ukf(alpha=0.001),hybrid' (default: the scenario's list); known: "
                   + ", ".join(FILTER_NAMES))
    p.add_argument("--runs", type=int, help="Monte Carlo runs (default: scenario's)")
    p.add_argument("--steps", type=int, help="time steps per run (default: scenario's)")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--json", help="write results as JSON to this path")
    p.add_argument("--ablation", action="store_true",
                   help="also run seed 000's 2x2 ablation (sampling x weights)")
    p.add_argument("--speed", action="store_true",
                   help="speed benchmark instead: our UKF vs FilterPy's, hybrid vs UKF")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario parameter (repeatable), e.g. --set model.Q=5")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    sc = load_scenario(args.scenario, args.sets)
    if args.steps is not None:
        sc["steps"] = args.steps
    runs = args.runs if args.runs is not None else int(sc.get("runs", 100))
    specs = split_filter_list(args.filters) if args.filters else list(sc.get("filters", []))
    progress = Progress(False if args.no_progress else None)
    doc = {"scenario": sc["name"], "source": sc.get("source"), "runs": runs, "seed": args.seed,
           "steps": sc.get("steps"), "overrides": args.sets}
    if sc["kind"] == "radar":
        from ..experiments.radar import run_bench

        doc["filters"] = run_bench(sc, specs, runs, args.seed, args.steps)
        cols = ["pos_rmse", "vel_rmse", "pcrlb_pos", "pcrlb_ratio", "pcrlb_ratio_rms",
                "cond_ratio", "nees_mean", "nees_band",
                "nees_in_band_fraction",
                "gospa", "id_swaps", "false_tracks", "track_breaks", "diverged_fraction",
                "us_per_step"]
    else:
        from ..experiments.montecarlo import METRICS, ablation, evaluate
        from ..experiments.systems import build_system

        sysm = build_system(sc)
        if args.speed:
            from ..experiments.speed import speed

            res = speed(sysm, runs=min(runs, 20), seed=args.seed)
            doc["speed"] = res
            us = res["us_per_step"]
            print(f"speed on {sc['name']} ({res['runs']} runs x {res['steps']} steps, "
                  f"best of {res['repeats']}), microseconds per predict+update:")
            for k, v in us.items():
                print(f"  {k:18s} {v:8.1f}" if v is not None else f"  {k:18s}        -")
            if res["ukf_over_filterpy"] is not None:
                print(f"  our UKF / FilterPy UKF = {res['ukf_over_filterpy']:.3f}")
            else:
                print("  " + res["note"])
            print(f"  hybrid (M={res['hybrid_members']}) / our UKF = "
                  f"{res['hybrid_over_ukf']:.3f}")
            if args.json:
                write_json(args.json, doc)
            return 0
        doc["filters"] = evaluate(sysm, specs, runs, args.seed, progress)
        cols = list(METRICS) + ["resets"]
        if args.ablation:
            doc["ablation"] = ablation(sysm, runs, args.seed, progress)
    print(f"scenario {sc['name']} ({sc.get('source')}), {runs} runs x {sc.get('steps')} steps, "
          f"seed {args.seed}")
    print(table(doc["filters"], cols))
    if "ablation" in doc:
        for fam, cells in doc["ablation"].items():
            print(f"\nablation ({fam}): sampling x weights")
            print(table(cells, ["approx_error", "est_error", "rmse_mean", "nees_mean",
                                "diverged_fraction"], first="cell"))
    if args.json:
        write_json(args.json, doc)
        print(f"\nwrote {args.json}")
    return 0


def cmd_list(args) -> int:
    print("scenarios:", ", ".join(list_scenarios()))
    print("filters:  ", ", ".join(FILTER_NAMES))
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="uavest",
        description="UAV state estimation: EKF, UKF, EnKF, hybrid and particle filters side "
        "by side. With no command: the UNGM benchmark of all filters.",
    )
    sub = ap.add_subparsers(dest="command")
    _bench_parser(sub)
    pl = sub.add_parser("list", help="list scenarios and filters")
    pl.set_defaults(func=cmd_list)
    from ..pipeline.replay import add_replay_parser
    from .track import add_track_parser

    add_track_parser(sub)
    add_replay_parser(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        argv = ["bench", "ungm"]
    args = ap.parse_args(argv)
    if not hasattr(args, "func"):
        ap.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ScenarioError, ValueError, OSError) as e:
        print(f"uavest: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("uavest: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
