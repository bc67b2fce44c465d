"""``uavest bench SCENARIO``: Monte Carlo comparison of filters (and ``--speed``)."""

from __future__ import annotations

import sys
from dataclasses import replace

from ..errors import InputError
from ..scenarios import load_typed, resolved
from ..sinks.jsonout import write_json
from ..sinks.table import table
from .progress import progress
from .record import finish_recording, recording_sinks

__all__ = ["cmd_bench"]


def _positive(name: str, v: int | None) -> None:
    if v is not None and v < 1:
        raise InputError(f"--{name} must be >= 1, got {v}")


def cmd_bench(args) -> int:
    _positive("runs", args.runs)
    _positive("steps", args.steps)
    sc = load_typed(args.scenario, args.sets)
    if args.steps is not None:
        sc = replace(sc, steps=args.steps)
    runs = args.runs if args.runs is not None else sc.runs
    specs = args.filter_specs or list(sc.filters)
    from ..experiments.resources import check

    if sc.kind != "linear_cv":
        from .replay import reject_linear_only

        reject_linear_only(specs, f"bench {sc.name}", "a nonlinear model")
    check(sc, specs, runs, sc.steps, "bench")
    recording = bool(getattr(args, "mcap", None) or getattr(args, "report", None))
    trial = int(getattr(args, "trial", 0) or 0)
    if recording and args.speed:
        raise InputError("--mcap/--report record a Monte Carlo trial; not with --speed")
    if recording and not 0 <= trial < runs:
        raise InputError(f"--trial must be in 0..{runs - 1} (--runs {runs}), got {trial}")
    sinks = recording_sinks(args) if recording else []
    doc = {"run": {"command": " ".join(sys.argv), "seed": args.seed,
                   "scenario": resolved(sc)},
           "scenario": sc.name, "source": sc.source, "runs": runs,
           "seed": args.seed, "steps": sc.steps, "overrides": args.sets}
    bar = progress(runs * (9 if args.ablation else 1), f"bench {sc.name}",
                   False if args.no_progress else None)
    if sc.kind == "radar":
        from ..experiments.radar import run_bench, trial_info

        rec = None
        if sinks:
            rspecs = specs or list(sc.filters)
            rec = (trial, sinks, trial_info(sc, rspecs, args.seed, trial, " ".join(sys.argv)))
        doc["filters"] = run_bench(sc, specs, runs, args.seed, args.steps, rec)
        cols = ["pos_rmse", "vel_rmse", "pcrlb_pos", "pcrlb_ratio", "pcrlb_ratio_rms",
                "cond_ratio", "nees_mean", "nees_band", "nees_in_band_fraction",
                "gospa", "id_swaps", "false_tracks", "track_breaks", "diverged_fraction",
                "us_per_step"]
    else:
        from ..experiments.montecarlo import METRICS, ablation, evaluate
        from ..experiments.systems import build_system

        sysm = build_system(sc)
        if args.speed:
            return _speed(args, sysm, sc, runs, doc)
        from ..experiments.montecarlo import trial_info

        rec = None
        if sinks:
            rec = (trial, sinks, trial_info(sysm, specs, args.seed, trial, sc.name,
                                            " ".join(sys.argv)))
            rec[2].scenario = doc["run"]["scenario"]
        doc["filters"] = evaluate(sysm, specs, runs, args.seed, bar.update, rec)
        cols = list(METRICS) + ["resets"]
        if args.ablation:
            doc["ablation"] = ablation(sysm, runs, args.seed, bar.update)
    bar.close()
    print(f"scenario {sc.name} ({sc.source}), {runs} runs x {sc.steps} steps, "
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
    if recording:
        print(f"recorded trial {trial}")
        finish_recording(args)
    return 0


def _speed(args, sysm, sc, runs, doc) -> int:
    from ..experiments.speed import speed

    res = speed(sysm, runs=min(runs, 20), seed=args.seed)
    doc["speed"] = res
    us = res["us_per_step"]
    print(f"speed on {sc.name} ({res['runs']} runs x {res['steps']} steps, "
          f"best of {res['repeats']}), microseconds per predict+update+estimate:")
    for k, v in us.items():
        print(f"  {k:18s} {v:8.1f}" if v is not None else f"  {k:18s}        -")
    if res["ukf_over_filterpy"] is not None:
        print(f"  our UKF / FilterPy UKF = {res['ukf_over_filterpy']:.3f}")
    else:
        print("  " + res["note"])
    print(f"  hybrid (M={res['hybrid_members']}) / our UKF = {res['hybrid_over_ukf']:.3f}")
    if args.json:
        write_json(args.json, doc)
    return 0
