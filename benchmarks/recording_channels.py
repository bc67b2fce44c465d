"""The channel listing of docs/recording.md: records a replay of vtol.tlog and a radar
run (radar_uav, 40 scans, ekf/ukf/hybrid trackers), reads both back with the ``mcap``
reader and prints a Markdown table per recording: topic, schema name, schema encoding,
message count.

    python benchmarks/recording_channels.py [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


from _shared_logs import SHARED_LOGS  # noqa: E402


def table(path: Path) -> str:
    from uavest.report import read_recording

    rec = read_recording(path)
    rows = ["| topic | schema | encoding | messages |", "|---|---|---|---:|"]
    for topic in sorted(rec.counts):
        name, enc, _ = rec.schemas[topic]
        rows.append(f"| `{topic}` | `{name}` | {enc} | {rec.counts[topic]} |")
    size = path.stat().st_size / 1e6
    rows.append(f"\n{len(rec.counts)} channels, {sum(rec.counts.values())} messages, "
                f"{rec.chunks} chunks, {size:.2f} MB; metadata records: "
                f"{', '.join(sorted(rec.metadata))}")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    from uavest.apps.replay import ReplayConfig, replay
    from uavest.report.radar_demo import run_radar_demo
    from uavest.sinks.mcap import McapSink

    d = Path(args.out or tempfile.mkdtemp())
    d.mkdir(parents=True, exist_ok=True)
    vt = d / "vtol.mcap"
    replay(str(SHARED_LOGS / "vtol.tlog"), ReplayConfig(), sinks=[McapSink(vt)],
           command="uavest replay vtol.tlog --record vtol.mcap")
    print("### Replay of vtol.tlog (ekf, ukf, hybrid; default options)\n")
    print(table(vt))
    rd = d / "radar_uav.mcap"
    run_radar_demo([McapSink(rd)], "radar_uav", 40, ("ekf", "ukf", "hybrid"))
    print("\n### Radar run (radar_uav, 40 scans, ekf/ukf/hybrid trackers)\n")
    print(table(rd))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
