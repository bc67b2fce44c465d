"""Cost of recording a replay to MCAP: replay with and without :class:`McapSink`, side by
side (alternating runs, so both see the same machine load), and the file size.

    OPENBLAS_NUM_THREADS=1 python benchmarks/recording_cost.py [LOG] [--pairs N]
        [--rate-hz 0] [--seconds S]

Default: ``../shared/logs/sample.ulg`` (PX4, 248 Hz IMU) at ``rate_hz=0`` (every IMU
sample a filter step) with the three default filters (ekf, ukf, hybrid). Prints per run
the wall and CPU time, then the ratios (median with / median without, and of the fastest
runs by CPU time; the CPU-time ratio
is the robust one on a shared machine), the time spent inside the recorder (wall and
thread CPU time, timed around every sink call), the file size, MB per minute of data and
the write speed.

``--cli``: the command a user runs instead, ``uavest replay LOG --rate R --no-progress``
without and with ``--mcap``, in alternating subprocesses (wall and CPU time of each
process: start-up, log parsing, the replay, the table, the layout file), medians and
ratios.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from _shared_logs import SHARED_LOGS  # noqa: E402

from uavest.apps.replay import ReplayConfig, replay  # noqa: E402
from uavest.sinks.base import Sink  # noqa: E402
from uavest.sinks.mcap import McapSink  # noqa: E402


class Timed(Sink):
    """Wraps a sink and adds up the wall time (``seconds``) and the thread CPU time
    (``cpu``) spent in it (s)."""

    def __init__(self, inner: Sink) -> None:
        self.inner = inner
        self.seconds = 0.0
        self.cpu = 0.0

    def _t(self, name, *a):
        c, p = time.perf_counter(), time.thread_time()
        getattr(self.inner, name)(*a)
        self.cpu += time.thread_time() - p
        self.seconds += time.perf_counter() - c

    def open(self, info):
        self._t("open", info)

    def sample(self, s):
        self._t("sample", s)

    def start(self, *a):
        self._t("start", *a)

    def record(self, r):
        self._t("record", r)

    def close(self):
        self._t("close")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", nargs="?", default=str(SHARED_LOGS / "sample.ulg"))
    ap.add_argument("--pairs", type=int, default=2)
    ap.add_argument("--rate-hz", type=float, default=0.0)
    ap.add_argument("--frame-rate-hz", type=float, default=None,
                    help="McapSink frame_rate_hz (3-D channels per estimator; default the "
                    "sink's, 30 Hz; 0: every step)")
    ap.add_argument("--seconds", type=float, default=None,
                    help="replay only this many seconds of data")
    ap.add_argument("--cli", action="store_true",
                    help="time the `uavest replay` command in subprocesses instead")
    args = ap.parse_args(argv)
    if args.cli:
        return _cli(args)
    cfg = ReplayConfig(rate_hz=args.rate_hz)
    if args.seconds:
        from uavest.ingest import open_source

        t0 = next(iter(open_source(args.log))).t
        cfg = ReplayConfig(rate_hz=args.rate_hz, end=t0 + args.seconds)
    base, rec, inner, inner_cpu, cpu_b, cpu_r = [], [], [], [], [], []
    size = dur = steps = 0.0
    with tempfile.TemporaryDirectory() as d:
        for i in range(args.pairs):
            for with_rec in (False, True) if i % 2 == 0 else (True, False):
                path = Path(d) / f"run{i}.mcap"
                kw = {} if args.frame_rate_hz is None else {"frame_rate_hz":
                                                             args.frame_rate_hz or None}
                sinks = [Timed(McapSink(path, **kw))] if with_rec else []
                c, p = time.perf_counter(), time.process_time()
                doc = replay(args.log, cfg, sinks=sinks)
                wall = time.perf_counter() - c
                cpu = time.process_time() - p
                (rec if with_rec else base).append(wall)
                (cpu_r if with_rec else cpu_b).append(cpu)
                if with_rec:
                    inner.append(sinks[0].seconds)
                    inner_cpu.append(sinks[0].cpu)
                    size = path.stat().st_size
                dur, steps = float(doc["duration_s"]), int(doc["steps"])
                print(f"run {i} {'with   ' if with_rec else 'without'} recording: "
                      f"{wall:7.2f} s wall, {cpu:7.2f} s CPU ({steps} steps, {dur:.1f} s of data, "
                      f"{doc['filter_rate_hz']:.1f} Hz)", flush=True)
    b, r, s = statistics.median(base), statistics.median(rec), statistics.median(inner)
    print(f"filters: {', '.join(cfg.filters)}; log {args.log}")
    print(f"replay without recording  {b:7.2f} s (median of {len(base)})")
    print(f"replay with recording     {r:7.2f} s (median of {len(rec)})")
    print(f"ratio with / without      {r / b:7.3f} (wall)")
    cb, cr = statistics.median(cpu_b), statistics.median(cpu_r)
    print(f"CPU without / with        {cb:7.2f} s / {cr:7.2f} s: ratio {cr / cb:.3f} "
          "(process CPU time: less sensitive to other processes on the machine)")
    mb_, mr_ = min(cpu_b), min(cpu_r)
    print(f"CPU best without / with   {mb_:7.2f} s / {mr_:7.2f} s: ratio {mr_ / mb_:.3f} "
          "(fastest of each: the run least disturbed by other processes)")
    print(f"time inside the recorder  {s:7.2f} s = {100 * s / b:.1f} % of the replay "
          f"(ratio from it: {(b + s) / b:.3f})")
    sc = statistics.median(inner_cpu)
    n_rec = steps * len(cfg.filters)
    print(f"CPU inside the recorder   {sc:7.2f} s = {100 * sc / cb:.1f} % of the replay's CPU "
          f"(ratio from it: {(cb + sc) / cb:.3f}); {1e6 * sc / n_rec:.1f} us of CPU per "
          f"filter record (samples included)")
    mb = size / 1e6
    print(f"file {mb:.2f} MB for {dur:.1f} s of data = {60 * mb / dur:.2f} MB per minute; "
          f"{steps / dur:.0f} steps/s x 3 filters; write speed {mb / s:.2f} MB/s of recorder "
          f"time, {mb / r:.2f} MB/s of replay wall time")
    return 0


def _cli(args) -> int:
    """``uavest replay`` without and with ``--mcap``, alternating subprocesses."""
    rate = "0" if args.rate_hz == 0 else f"{args.rate_hz:g}"
    wall: dict[bool, list[float]] = {False: [], True: []}
    cpu: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as d:
        for i in range(args.pairs):
            for with_rec in (False, True) if i % 2 == 0 else (True, False):
                cmd = [sys.executable, "-m", "uavest", "replay", args.log, "--rate", rate,
                       "--no-progress"]
                if args.seconds:
                    from uavest.ingest import open_source

                    t0 = next(iter(open_source(args.log))).t
                    cmd += ["--end", repr(t0 + args.seconds)]
                if with_rec:
                    cmd += ["--mcap", str(Path(d) / f"run{i}.mcap")]
                r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                c = time.perf_counter()
                subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
                w = time.perf_counter() - c
                r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                u = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
                wall[with_rec].append(w)
                cpu[with_rec].append(u)
                print(f"run {i} {'with   ' if with_rec else 'without'} --mcap: {w:6.2f} s wall, "
                      f"{u:6.2f} s CPU", flush=True)
    m = statistics.median
    print(f"uavest replay {args.log} --rate {rate}: median of {args.pairs}")
    print(f"wall without / with  {m(wall[False]):6.2f} / {m(wall[True]):6.2f} s: ratio "
          f"{m(wall[True]) / m(wall[False]):.3f}")
    print(f"CPU  without / with  {m(cpu[False]):6.2f} / {m(cpu[True]):6.2f} s: ratio "
          f"{m(cpu[True]) / m(cpu[False]):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
