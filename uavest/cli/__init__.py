"""The command line: a thin layer that parses, builds a configuration and calls.

``uavest`` with no command prints the help and the quick-start line. Every command exits
with 2 and one line on stderr for bad usage or bad input (``uavest.errors.InputError``,
``OSError``; never a traceback), 130 on Ctrl-C, and 1 with one line
"internal error: <Type>: <message>" for any other exception (a bug of ours; ``-v`` adds the
traceback); ``-v`` shows warnings and resets as they happen (``logging``), ``-q`` only
errors.
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
import logging  # noqa: E402
import sys  # noqa: E402

from .. import __version__  # noqa: E402

QUICK_START = ("quick start: uavest demo   (the built-in simulator and the live estimator over "
               "loopback UDP, 30 s)")

log = logging.getLogger("uavest")


def _bench_parser(sub) -> None:
    p = sub.add_parser(
        "bench",
        help="Monte Carlo benchmark of filters on a scenario",
        description="Run filters side by side on the same seeded truths and measurements. "
        "Trial r draws from (seed, r, stream), so it is the same whatever --runs is.",
    )
    p.add_argument("scenario", nargs="?", default="ungm",
                   help="scenario name (see 'uavest list') or a .toml path")
    p.add_argument("--filters", help="comma-separated filter specs, e.g. "
                   "'ukf,ukf(alpha=0.001),hybrid' (default: the scenario's list)")
    p.add_argument("--runs", type=int, help="Monte Carlo runs (default: scenario's)")
    p.add_argument("--steps", type=int, help="time steps per run (default: scenario's)")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--json", help="write results as JSON to this path")
    p.add_argument("--ablation", action="store_true",
                   help="also run the hybrid paper's 2x2 ablation (sampling x weights; "
                   "Cui, Sun and Wen, Sensors 2022)")
    p.add_argument("--speed", action="store_true",
                   help="speed benchmark instead: our UKF vs FilterPy's, hybrid vs UKF")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario parameter (repeatable), e.g. --set model.Q=5")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--trial", type=int, default=0, metavar="K",
                   help="the Monte Carlo trial --mcap / --report record (default 0; "
                   "must be < --runs)")
    from .record import add_recording_options

    add_recording_options(p, live_view=False)
    p.set_defaults(func=_lazy("bench", "cmd_bench"), filters_preset="bench")


def _lazy(module: str, name: str):
    """A command's entry point, imported only when that command runs (fast --help)."""

    def call(args):
        import importlib

        return getattr(importlib.import_module(f"uavest.cli.{module}"), name)(args)

    return call


def cmd_list(args) -> int:
    from ..core.registry import FILTER_NAMES
    from ..presets import describe_presets
    from ..scenarios import list_scenarios

    print("scenarios:", ", ".join(list_scenarios()))
    print("filters:  ", ", ".join(FILTER_NAMES))
    print(describe_presets())
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="uavest",
        description="UAV state estimation: attitude from the IMU and radar target tracks, "
        "with EKF, UKF, EnKF, a hybrid UKF/EnKF and a particle filter side by side.",
        epilog=QUICK_START,
    )
    ap.add_argument("--version", action="version", version=f"uavest {__version__}")
    ap.add_argument("-v", "--verbose", action="count", default=0,
                    help="show warnings and filter resets as they happen (-vv: debug)")
    ap.add_argument("-q", "--quiet", action="store_true", help="only errors on stderr")
    sub = ap.add_subparsers(dest="command")
    _bench_parser(sub)
    pl = sub.add_parser("list", help="list scenarios, filters and what each filter "
                        "name resolves to in each command")
    pl.set_defaults(func=cmd_list)
    from .evaluate import add_evaluate_parser
    from .replay import add_replay_parser
    from .report_cmd import add_report_parser
    from .run import add_demo_parser, add_run_parser
    from .sim import add_sim_parser
    from .track import add_track_parser

    add_demo_parser(sub)
    add_run_parser(sub)
    add_track_parser(sub)
    add_replay_parser(sub)
    add_sim_parser(sub)
    add_report_parser(sub)
    add_evaluate_parser(sub)
    return ap


class _OneLine(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"uavest: {record.levelname.lower()}: {record.getMessage()}"


def _setup_logging(verbose: int, quiet: bool) -> tuple:
    """One-line messages on stderr for the ``uavest`` loggers; returns what it replaced,
    for :func:`_restore_logging` (``main`` called in-process must leave logging as it was)."""
    level = logging.ERROR if quiet else (logging.WARNING if verbose == 0 else
                                         logging.INFO if verbose == 1 else logging.DEBUG)
    h = logging.StreamHandler(sys.stderr)
    h.setFormatter(_OneLine())
    root = logging.getLogger("uavest")
    saved = (root.handlers[:], root.level, root.propagate)
    root.handlers[:] = [h]
    root.setLevel(level)
    root.propagate = False
    return saved


def _restore_logging(saved: tuple) -> None:
    root = logging.getLogger("uavest")
    root.handlers[:], level, root.propagate = saved
    root.setLevel(level)


def _preset_for(args) -> tuple[str, int | None]:
    """(preset, state dimension) the command's ``--filters`` are resolved in and for:
    ``uavest replay`` / ``run`` / ``demo`` the attitude preset on the attitude state
    (tangent dimension 6); ``uavest track`` and ``uavest bench`` on a radar scenario the
    radar preset (``experiments.radar``) on the scenario's motion model, ``bench`` on any
    other scenario the bench preset on its system. The dimension is None when the
    scenario cannot be loaded (the command reports that itself)."""
    preset = args.filters_preset
    if preset == "attitude":
        from ..geometry.rotation import AttitudeSpace

        return preset, AttitudeSpace.dim
    scenario = getattr(args, "scenario", None)
    if not scenario:
        return preset, None
    from ..errors import InputError
    from ..scenarios import load_typed

    sets = getattr(args, "sets", None) or getattr(args, "set", None) or ()
    try:
        sc = load_typed(scenario, sets)
        if sc.kind == "radar":
            from ..tracking.scenario import state_dim

            return "radar", state_dim(sc.ndim, sc.motion)
        if preset == "bench":
            from ..experiments.systems import build_system

            return preset, build_system(sc).transition.space.dim
    except (InputError, OSError):  # a bad scenario is reported by the command itself
        pass
    return preset, None


def _check_filters(args) -> None:
    """Resolve ``--filters`` once, against the command's preset and for its state, into
    ``args.filter_specs`` (FilterSpecs the command passes down; None without
    ``--filters``); bad specs fail here (one line, exit 2) before any work."""
    if not hasattr(args, "filters_preset"):
        return
    text = getattr(args, "filters", None)
    if text is None:
        args.filter_specs = None
        return
    from ..presets import resolve_list

    preset, dim = _preset_for(args)
    if dim is None:  # the scenario is bad: check the specs, the command reports the rest
        resolve_list(text, preset, dim=1)
        from ..core.spec import split_filter_list

        args.filter_specs = split_filter_list(text)
        return
    if preset == "attitude":
        _check_model_filters(args, text, dim)
        return
    args.filter_specs = resolve_list(text, preset, dim)


def _check_model_filters(args, text: str, dim: int) -> None:
    """``--filters`` of replay / run / demo, whose preset is their model's: "hybrid" and
    "hybrid(reinflate=false)" are one filter in the attitude preset and two in the nav
    preset. With ``--model`` given the list is checked in its preset here; with ``auto``
    a slip in both presets fails here, one in only the nav or the attitude preset once
    the model is chosen (:func:`uavest.apps.replay.model_filters`)."""
    from ..core.spec import SpecError
    from ..models.navigation import nav_dim
    from ..presets import resolve_list

    model = getattr(args, "model", "attitude")
    if model == "nav":
        resolve_list(text, "nav", nav_dim({}))
    elif model == "auto":
        try:
            resolve_list(text, "nav", nav_dim({}))
        except SpecError:
            resolve_list(text, "attitude", dim)  # raises if the attitude preset refuses too
    args.filter_specs = resolve_list(text, "attitude", dim, distinct=model == "attitude")


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        ap.print_help()
        print(f"\n{QUICK_START}")
        return 0
    try:
        args = ap.parse_args(argv)
    except SystemExit as e:  # argparse: usage errors exit 2 with a message already
        return int(e.code or 0)
    if not hasattr(args, "func"):
        ap.print_help()
        return 2
    saved = _setup_logging(args.verbose, args.quiet)
    try:
        return _call(args)
    finally:
        _restore_logging(saved)


def _one_line(e: BaseException) -> str:
    """The first line of ``e``'s message (at most 300 characters); an ``OSError`` as
    ``filename: reason`` ("out/x.json: No such file or directory") without the errno."""
    if isinstance(e, OSError) and e.strerror:
        where = e.filename if e.filename is not None else ""
        msg = f"{where}: {e.strerror}" if where != "" else e.strerror
    else:
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return msg if len(msg) <= 300 else msg[:300] + "..."


def _call(args) -> int:
    """Run the command. Bad usage or input (the project's :class:`~uavest.errors.InputError`
    and its subclasses; an ``OSError``: a missing file, no permission, a refused
    connection) -> one line on stderr and 2. Any other exception is a bug of ours, never
    "bad input": one line naming it and 1; with ``-v`` the traceback first."""
    from ..errors import InputError

    try:
        _check_filters(args)
        return int(args.func(args) or 0)
    except (InputError, OSError) as e:
        print(f"uavest {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("uavest: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - reported as ours, with the traceback on -v
        if args.verbose:
            import traceback

            traceback.print_exc(file=sys.stderr)
        hint = "please report" if args.verbose else "run with -v for the traceback; please report"
        print(f"uavest {args.command}: internal error: {type(e).__name__}: {_one_line(e)} "
              f"({hint})", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
