"""The recording options every estimating command shares: ``--mcap PATH`` (a recording
Foxglove opens as it is), ``--foxglove [HOST:PORT]`` (the live view), ``--report DIR``
(``uavest report`` of the recording, in one go). See docs/recording.md."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import InputError
from ..sinks.base import Sink

__all__ = ["add_recording_options", "finish_recording", "recording_path", "recording_sinks"]


def add_recording_options(p: argparse.ArgumentParser, live_view: bool = True,
                          report: bool = True, mcap_default: str | None = None) -> None:
    p.add_argument("--mcap", default=None, metavar="PATH",
                   help="record everything to this MCAP file (Foxglove schemas; a layout "
                   "JSON is written beside it)" + (f"; default {mcap_default} (DIR/run.mcap "
                                                  "with --report DIR)"
                                                  if mcap_default else ""))
    p.set_defaults(mcap_default=mcap_default)
    if live_view:
        p.add_argument("--foxglove", nargs="?", const="127.0.0.1:8765", default=None,
                       metavar="HOST:PORT", help="serve the same channels live to the "
                       "Foxglove app (WebSocket, default 127.0.0.1:8765)")
    if report:
        p.add_argument("--report", metavar="DIR", help="write the HTML + Markdown report "
                       "of the run to DIR (records to DIR/run.mcap without --mcap)")


def _hostport(s: str) -> tuple[str, int]:
    host, _, port = s.rpartition(":")
    try:
        p = int(port)
    except ValueError:
        raise InputError(f"--foxglove expects HOST:PORT, got {s!r}") from None
    if not 0 <= p <= 65535:
        raise InputError(f"--foxglove: port must be 0..65535, got {p}")
    return host or "127.0.0.1", p


class Pace(Sink):
    """Holds the loop to ``speed`` x real time of the records' clock (a replay watched
    live in Foxglove)."""

    def __init__(self, speed: float) -> None:
        if not speed > 0:
            raise InputError(f"--speed must be > 0, got {speed}")
        self.speed = speed
        self.t0: float | None = None
        self.w0 = 0.0

    def record(self, rec) -> None:
        if self.t0 is None:
            self.t0, self.w0 = rec.t, time.monotonic()
            return
        wait = (rec.t - self.t0) / self.speed - (time.monotonic() - self.w0)
        if wait > 0:
            time.sleep(wait)


def recording_path(path: str, chosen: bool) -> tuple[str, str | None]:
    """Where to record and what to say about it. An existing file at a path the user
    chose (``--mcap``, ``--report DIR``) is overwritten with a warning naming it; at a
    default path (``uavest demo``'s ``uavest-demo.mcap``) the recording goes to the first
    free numbered name beside it (``uavest-demo-1.mcap``, ...), said on one line."""
    p = Path(path)
    if not p.exists():
        return path, None
    if chosen:
        return path, f"warning: overwriting the existing recording {p}"
    k = 1
    while (q := p.with_name(f"{p.stem}-{k}{p.suffix}")).exists():
        k += 1
    return str(q), f"{p} exists: recording to {q} instead (--mcap PATH to choose)"


def recording_sinks(args) -> list:
    """The sinks the options ask for (an MCAP recorder, the live view)."""
    sinks: list = []
    mcap = getattr(args, "mcap", None)
    chosen = mcap is not None
    if mcap is None and getattr(args, "report", None):
        mcap, chosen = str(Path(args.report) / "run.mcap"), True
    elif mcap is None:
        mcap = getattr(args, "mcap_default", None)
    if mcap:
        mcap, note = recording_path(mcap, chosen)
        if note:
            print(f"uavest: {note}", file=sys.stderr)
    args.mcap = mcap
    if mcap:
        from ..sinks.mcap import McapSink

        Path(mcap).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(McapSink(mcap))
    if getattr(args, "foxglove", None):
        from ..sinks.foxglove_live import FoxgloveLiveSink

        host, port = _hostport(args.foxglove)
        live = FoxgloveLiveSink(host=host, port=port)
        print(f"uavest: Foxglove live view on ws://{host}:{live.port} (open connection in "
              "the Foxglove app)")
        sinks.append(live)
        speed = getattr(args, "speed", None)
        if getattr(args, "paced", False):
            sinks.append(Pace(speed or 1.0))
    return sinks


def finish_recording(args) -> None:
    """After the run: say where the recording is; write the report if asked."""
    if getattr(args, "mcap", None):
        m = Path(args.mcap)
        layout = m.with_name(m.stem + ".layout.json")
        print(f"recording: {m} (open it in Foxglove; layout {layout})")
    if getattr(args, "report", None):
        from ..report import write_report
        from .progress import progress

        bar = progress(None, "report", False if getattr(args, "no_progress", False) else None,
                       lines=True)
        try:
            out = write_report(args.mcap, args.report, on_stage=bar.set_description)
        finally:
            bar.close()
        print(f"report: {out['html']}")
