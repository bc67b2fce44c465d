"""``uavest report RUN.mcap [--out DIR]``: the HTML + Markdown report of a recording
(:func:`uavest.report.write_report`). Registered by the main CLI through
:func:`add_report_parser`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["add_report_parser", "cmd_report"]


def add_report_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``report`` sub-command to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser(
        "report",
        help="HTML/Markdown report with plots of an MCAP recording",
        description="Read an MCAP recording (--mcap PATH or --report DIR of replay, "
                    "run, demo, track) back, recompute RMSE, NEES, "
                    "NIS (attitude) or GOSPA and track counts (radar) from it, and write "
                    "a self-contained HTML page and a Markdown summary.")
    _add_args(p)
    return p


def _add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", help="the .mcap file (a torn file of a killed run works too)")
    p.add_argument("--out", help="output directory (default: beside the recording)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress (default: a bar on a terminal, else one line per "
                   "stage once the report has taken 2 s)")
    p.set_defaults(func=cmd_report)


def cmd_report(args) -> int:
    from ..report import write_report

    path = Path(args.recording)
    if not path.is_file():
        print(f"uavest report: no such file: {path}", file=sys.stderr)
        return 2
    from .progress import progress

    bar = progress(None, "report", False if args.no_progress else None, lines=True)
    try:
        paths = write_report(path, args.out, on_stage=bar.set_description)
    finally:
        bar.close()
    print(f"html: {paths['html']}")
    print(f"markdown: {paths['markdown']}")
    print(f"metrics: {paths['metrics']}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m uavest.cli.report_cmd RUN.mcap``)."""
    ap = argparse.ArgumentParser(prog="uavest report")
    _add_args(ap)
    args = ap.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
