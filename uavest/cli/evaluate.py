"""``uavest evaluate INPUTS...``: many logs or a Monte Carlo study, one report.

Registered by ``uavest.cli`` through :func:`add_evaluate_parser`.
"""

from __future__ import annotations

import argparse
import math
import sys

from ..errors import InputError

__all__ = ["add_evaluate_parser", "cmd_evaluate"]


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Entry point (errors reach ``uavest.cli.main``: one line, exit 2; Ctrl-C: 130,
    complete result files kept)."""
    from ..fleet import build_plan, make_backend
    from ..fleet.run import execute, summarize, terminal_report, write_outputs
    from .progress import progress

    if args.workers is not None and args.workers < 0:
        raise InputError(f"--workers must be >= 0 (0 = serial), got {args.workers}")
    if args.start is not None and not math.isfinite(args.start):
        raise InputError("--start must be a finite number of seconds")
    if args.end is not None and not math.isfinite(args.end):
        raise InputError("--end must be a finite number of seconds")
    replay = {k: v for k, v in (("start", args.start), ("end", args.end),
                                ("rate_hz", args.rate), ("model", args.model))
              if v is not None}
    filters = None
    if args.filters:
        from ..core.spec import split_filter_list

        filters = split_filter_list(args.filters)
    if args.trials is None and (args.sets or args.steps is not None):
        raise InputError("--set and --steps apply to Monte Carlo scenarios (with --trials)")
    plan = build_plan(args.inputs, filters=filters, replay=replay, trials=args.trials,
                      seed=args.seed, shard_size=args.shard_size, sets=args.sets,
                      steps=args.steps)
    backend = make_backend(args.workers, args.scheduler, ship=not args.shared_paths)
    detail = backend.describe()
    log = sys.stderr if args.quiet else sys.stdout
    ntasks = len(plan.tasks())
    print(f"uavest evaluate: {len(plan.inputs)} input(s), {ntasks} task(s) on {detail}; "
          f"results in {args.out}", file=log)
    if getattr(backend, "name", "") == "dask":
        link = backend.dashboard()
        print(f"dask dashboard: {link or 'not available'}", file=log)
    bar = progress(ntasks, "evaluate", False if args.no_progress else None, lines=True)
    try:
        docs, stats = execute(plan, args.out, backend, recompute=args.recompute,
                              retry_failed=args.retry_failed, bar=bar)
    finally:
        bar.close()
        backend.close()
    summary = summarize(plan, docs, stats, {"command": " ".join(sys.argv),
                                            "backend_detail": detail})
    paths = write_outputs(summary, args.out)
    if not args.quiet:
        print(terminal_report(summary))
        print(f"wrote {paths['html']}, {paths['json']}, {paths['rows_csv']}, "
              f"{paths['aggregate_csv']}")
    ok = summary["counts"]["ok"]
    return 0 if ok or not summary["failures"] else 1


def add_evaluate_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``evaluate`` on an argparse sub-parsers object (sets ``func``)."""
    p = subparsers.add_parser(
        "evaluate",
        help="evaluate filters over many logs or a Monte Carlo study, locally or on Dask",
        description="Replay every log (files, folders searched recursively for .tlog/.bin/"
        ".ulg, globs) or, with --trials, run a Monte Carlo study of a scenario in shards, "
        "on a local process pool (default), in-process (--workers 0) or a Dask cluster "
        "(--scheduler). Results are stored per input under --out, keyed by the input's "
        "content and the resolved configuration: a rerun skips what is done. Writes "
        "summary.json, rows.csv, aggregate.csv and report.html. See docs/evaluate.md.",
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="log files, folders or globs; with --trials: scenario names")
    p.add_argument("--filters", help="comma-separated filter specs (default: logs "
                   "ekf,ukf,hybrid in the attitude preset; Monte Carlo: the scenario's list)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: CPU count; 0 = serial in-process; "
                   "with --scheduler local: LocalCluster workers)")
    p.add_argument("--scheduler", metavar="ADDR",
                   help="Dask scheduler address, e.g. tcp://host:8786, or 'local' for a "
                   "LocalCluster (needs pip install 'uavest[dask]')")
    p.add_argument("--shared-paths", action="store_true",
                   help="with Dask: send log paths, not their bytes (workers see the "
                   "same files)")
    p.add_argument("--out", default="evaluate-out",
                   help="result folder (default evaluate-out)")
    p.add_argument("--trials", type=int, help="Monte Carlo trials of each scenario INPUT")
    p.add_argument("--shard-size", type=int, default=25,
                   help="trials per task (default 25)")
    p.add_argument("--steps", type=int, help="Monte Carlo time steps (default: scenario's)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario parameter (repeatable)")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--start", type=float, help="logs: start time (s, vehicle clock)")
    p.add_argument("--end", type=float, help="logs: end time (s, vehicle clock)")
    p.add_argument("--rate", type=float, help="logs: max filter rate in Hz (replay's "
                   "default; 0 = every IMU sample)")
    p.add_argument("--model", default="auto", choices=("auto", "nav", "attitude"),
                   help="logs: the estimator's model as in uavest replay (default auto: "
                   "navigation for a log with a raw GNSS fix stream, attitude-only "
                   "otherwise)")
    p.add_argument("--recompute", action="store_true",
                   help="ignore stored results and compute everything again")
    p.add_argument("--retry-failed", action="store_true",
                   help="run inputs that failed with an error in an earlier run again "
                   "(a task whose worker died is always run again)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_evaluate)
    return p


def main(argv: list[str] | None = None) -> int:
    """``python -m uavest.cli.evaluate ...``: the same as ``uavest evaluate ...`` (the
    command line's error handling), also before the command is registered in
    ``uavest.cli``."""
    from .. import cli

    orig = cli.build_parser

    def build() -> argparse.ArgumentParser:
        ap = orig()
        sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
        if "evaluate" not in sub.choices:
            add_evaluate_parser(sub)
        return ap

    cli.build_parser = build
    try:
        return cli.main(["evaluate", *(sys.argv[1:] if argv is None else argv)])
    finally:
        cli.build_parser = orig


if __name__ == "__main__":
    sys.exit(main())
