"""The recorder's own cost per record and per sample, without the filters: capture the
sink calls of a replay once (samples, starts, records), then feed the same calls to
McapSink implementations side by side (alternating, best of N), so the ratio does not
depend on the machine's load.

    OPENBLAS_NUM_THREADS=1 python benchmarks/recorder_per_record.py [LOG] [--seconds 10]
        [--rate-hz 0] [--repeats 5] [--old REV] [--frame-rate-hz 30] [--profile]

``--old REV`` (e.g. ``main``) loads the Foxglove channels (``uavest/sinks/foxglove/``, or
``foxglove_channels.py`` before the package) and ``uavest/sinks/mcap.py`` of that git
revision into temporary modules and times them on the same calls (the old sink with its
own defaults).
Prints the CPU time of all calls per filter record (the recorder's whole cost divided by
the filter records; samples and the error messages they release included), of the
records alone (no samples, so no reference and no error channel), and the ratios.
``--profile`` prints a cProfile of the current sink.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from _shared_logs import SHARED_LOGS  # noqa: E402

from uavest.apps.replay import ReplayConfig, replay  # noqa: E402
from uavest.engine.records import StepRecord  # noqa: E402
from uavest.sinks.base import Sink  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


class Capture(Sink):
    """Every sink call of a run, in order."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, tuple]] = []

    def open(self, info):
        self.calls.append(("open", (info,)))

    def sample(self, s):
        self.calls.append(("sample", (s,)))

    def start(self, *a):
        self.calls.append(("start", a))

    def record(self, r):
        self.calls.append(("record", (r,)))


def _git_show(rev: str, path: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{path}"],
                          check=True, capture_output=True, text=True).stdout


def _load(name: str, path: Path, package: bool = False):
    spec = importlib.util.spec_from_file_location(
        f"uavest.sinks.{name}", path,
        submodule_search_locations=[str(path.parent)] if package else None)
    m = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = m
    spec.loader.exec_module(m)
    return m


def old_sink_class(rev: str, tmp: Path):
    """McapSink of git revision ``rev`` (its own Foxglove channels: the package
    ``uavest/sinks/foxglove/`` or, before it, the one file ``foxglove_channels.py``), as
    temporary modules of the ``uavest.sinks`` package (so their relative imports
    resolve)."""
    mc = _git_show(rev, "uavest/sinks/mcap.py")
    files = subprocess.run(["git", "-C", str(ROOT), "ls-tree", "--name-only", rev,
                            "uavest/sinks/foxglove/"],
                           check=True, capture_output=True, text=True).stdout.split()
    if files:  # the package: every module under uavest.sinks._old_foxglove
        d = tmp / "_old_foxglove"
        d.mkdir()
        for f in files:
            (d / Path(f).name).write_text(_git_show(rev, f))
        mc = mc.replace("from .foxglove import", "from ._old_foxglove import")
        mc = mc.replace("from .foxglove.", "from ._old_foxglove.")
        _load("_old_foxglove", d / "__init__.py", package=True)
    else:
        p = tmp / "_old_foxglove_channels.py"
        p.write_text(_git_show(rev, "uavest/sinks/foxglove_channels.py"))
        mc = mc.replace("from .foxglove_channels import", "from ._old_foxglove_channels import")
        _load("_old_foxglove_channels", p)
    p = tmp / "_old_mcap.py"
    p.write_text(mc)
    return _load("_old_mcap", p).McapSink


def feed(sink, calls) -> float:
    """Hand the calls to ``sink`` (then close it); seconds of process CPU."""
    c = time.process_time()
    for name, a in calls:
        getattr(sink, name)(*a)
    sink.close()
    return time.process_time() - c


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", nargs="?", default=str(SHARED_LOGS / "sample.ulg"))
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate-hz", type=float, default=0.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--old", default=None, metavar="REV")
    ap.add_argument("--frame-rate-hz", type=float, default=-1.0,
                    help="frame_rate_hz of the current sink (default: its default; 0: every "
                    "step)")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args(argv)
    from uavest.ingest import open_source
    from uavest.sinks.mcap import McapSink

    t0 = next(iter(open_source(args.log))).t
    cap = Capture()
    replay(args.log, ReplayConfig(rate_hz=args.rate_hz, end=t0 + args.seconds), sinks=[cap])
    calls = cap.calls
    n_rec = sum(1 for n, a in calls if n == "record" and isinstance(a[0], StepRecord))
    n_smp = sum(1 for n, _ in calls if n == "sample")
    print(f"captured {len(calls)} calls: {n_rec} filter records, {n_smp} samples "
          f"({args.seconds:g} s of {args.log}, rate_hz {args.rate_hz:g})")
    kw = {} if args.frame_rate_hz < 0 else {"frame_rate_hz": args.frame_rate_hz or None}
    rec_only = [c for c in calls if c[0] in ("open", "start", "record")]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        impls = {"new": lambda p: McapSink(p, **kw)}
        if args.old:
            old = old_sink_class(args.old, d)
            impls[f"old ({args.old})"] = lambda p: old(p)
        if args.profile:
            import cProfile
            import pstats

            pr = cProfile.Profile()
            s = McapSink(d / "prof.mcap", **kw)
            pr.enable()
            feed(s, calls)
            pr.disable()
            pstats.Stats(pr).sort_stats(os.environ.get("PROFILE_SORT", "tottime")).print_stats(25)
        best: dict[str, dict[str, float]] = {k: {"all": 1e9, "rec": 1e9} for k in impls}
        size: dict[str, int] = {}
        for i in range(args.repeats):
            for name, mk in (impls.items() if i % 2 == 0 else reversed(impls.items())):
                p = d / f"{i}.mcap"
                best[name]["all"] = min(best[name]["all"], feed(mk(p), calls))
                size[name] = p.stat().st_size
                best[name]["rec"] = min(best[name]["rec"], feed(mk(p), rec_only))
        for name, b in best.items():
            us_all = 1e6 * b["all"] / n_rec
            us_rec = 1e6 * b["rec"] / n_rec
            print(f"{name:14s} all calls {b['all']:6.3f} s CPU = {us_all:6.1f} us per filter "
                  f"record (samples, errors and all); records alone {us_rec:6.1f} us each; "
                  f"file {size[name] / 1e6:.2f} MB")
        if args.old:
            names = list(best)
            a, b = best[names[0]], best[names[1]]
            print(f"new / old: all calls {a['all'] / b['all']:.3f}, per record "
                  f"{a['rec'] / b['rec']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
