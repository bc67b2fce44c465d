"""The live path under load: does the estimator keep up in real time?

The simulator (a subprocess, ``uavest sim``) sends IMU at 250 Hz and ADS-B for 10
aircraft over loopback UDP; the live estimator (this process, pinned to one core) runs
ekf, ukf and hybrid for attitude and for tracking, with the virtual radar scanning at
10 Hz. Printed: steps and scans made vs due, the latency from a sample entering the
engine to its estimate (p50, p99), and the CPU share of the estimator's core.

Latency here starts when the link hands the sample to the engine; the link's reorder
window (``--reorder-window``, default 0.05 s of vehicle time) holds samples on top of it.

    python benchmarks/live_latency.py [--duration 30] [--targets 10]
"""

from __future__ import annotations

import argparse
import copy
import os
import resource
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from uavest.apps.live import LiveConfig, run_live  # noqa: E402
from uavest.ingest.adsb_radar import RadarConfig  # noqa: E402


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _scenario(n: int, path: Path) -> None:
    """sim_default with ``n`` ADS-B aircraft (copies of its targets, shifted)."""
    src = ROOT / "uavest" / "scenarios" / "sim_default.toml"
    sc = tomllib.loads(src.read_text())
    base = [t for t in sc["targets"] if t.get("adsb", True)]
    out = []
    for i in range(n):
        t = copy.deepcopy(base[i % len(base)])
        p = t["position_ned"]
        t["position_ned"] = [p[0] + 150.0 * i, p[1] - 120.0 * i, p[2] - 20.0 * i]
        t["name"], t["id"], t["icao"] = f"T{i}", 100 + i, 0x4C0000 + i
        out.append(t)
    sc["targets"] = out
    lines = []

    def emit(prefix, d):
        for k, v in d.items():
            if not isinstance(v, dict | list) or (isinstance(v, list) and v and not
                                                  isinstance(v[0], dict)):
                lines.append(f"{k} = {_toml(v)}")
        for k, v in d.items():
            if isinstance(v, dict):
                lines.append(f"[{prefix}{k}]")
                emit(f"{prefix}{k}.", v)
            elif isinstance(v, list) and v and isinstance(v[0], dict):
                for item in v:
                    lines.append(f"[[{prefix}{k}]]")
                    emit(f"{prefix}{k}.", item)

    emit("", sc)
    path.write_text("\n".join(lines) + "\n")


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--targets", type=int, default=10)
    a = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    port = _port()
    with tempfile.TemporaryDirectory() as d:
        scen = Path(d) / "bench.toml"
        _scenario(a.targets, scen)
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        sim = subprocess.Popen(
            [sys.executable, "-m", "uavest", "sim", str(scen), "--out",
             f"udpout:127.0.0.1:{port}", "--imu-rate", "250", "--duration",
             str(a.duration + 30), "--quiet", "--wait"], env=env)
        try:
            cfg = LiveConfig(connect=f"udpin:127.0.0.1:{port}", duration=a.duration,
                             radar=RadarConfig(period=0.1, max_range=8000.0),
                             streams={"HIGHRES_IMU": 250.0, "ATTITUDE": 10.0,
                                      "GLOBAL_POSITION_INT": 10.0, "SIMSTATE": 10.0,
                                      "SYSTEM_TIME": 1.0})
            r0 = resource.getrusage(resource.RUSAGE_SELF)
            w0 = time.perf_counter()
            doc = run_live(cfg, status=False)
            wall = time.perf_counter() - w0
            r1 = resource.getrusage(resource.RUSAGE_SELF)
        finally:
            sim.terminate()
            sim.wait(timeout=10)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    rates = doc["link"]["rates_hz"]
    print(f"live path, {a.duration:g} s, IMU {rates.get('HIGHRES_IMU', 0):.0f} Hz arriving, "
          f"virtual radar 10 Hz, {doc['targets_seen']} aircraft seen")
    print(f"  attitude steps {doc['steps'] - doc['scans']}, scans {doc['scans']} "
          f"(due about {25 * a.duration:.0f} steps + {10 * a.duration:.0f} scans)")
    lat = doc["latency_ms"] or {}
    print(f"  latency sample -> estimate: p50 {lat.get('p50', float('nan')):.2f} ms, "
          f"p99 {lat.get('p99', float('nan')):.2f} ms (goal p99 < 20 ms)")
    print(f"  CPU share of one core: {100 * cpu / wall:.0f} %")
    print(f"  bad data {doc['link']['bad_data']['bad_total']}, queue overflow "
          f"{doc['link']['bad_data'].get('queue_overflow', 0)}")
    for k, v in doc["tracks"].items():
        print(f"  track {k}: us/scan {v['us_per_scan']:.0f}, GOSPA {v['gospa']:.1f}")
    for k, v in doc["attitude"].items():
        print(f"  attitude {k}: us/step {v.get('us_per_step', float('nan')):.0f}")


if __name__ == "__main__":
    main()
