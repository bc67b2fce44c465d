"""Live latency: from a message's receipt to the estimate it completes, per filter set.

The built-in simulator (a subprocess, ``uavest sim``, real time) sends the IMU at the
scenario's rate (400 Hz) and ADS-B for ``--targets`` aircraft over loopback UDP; the live
estimator (this process, pinned to one core; the simulator on the others) runs with the
virtual radar scanning at 10 Hz. Or ``--connect`` attaches to a running vehicle/SITL
instead (e.g. the ArduCopter SITL of ../shared/sitl on tcp:127.0.0.1:5763 while fly.py
flies it).

Two latencies per estimate (attitude step or radar scan) emitted at wall time ``w``:

* **receipt -> estimate**: ``w`` minus the receive time (reader thread, ``time.time()``) of
  the first IMU message at or after the estimate's vehicle time (plus the IMU low-pass
  delay a navigation step is stamped earlier by), i.e. of the message whose arrival made
  the estimate possible. It includes the link's reorder window
  (``--reorder-window``; by default 0, ``uavest run``'s: samples on arrival, a late one
  applied at its time within ``--history``), the queue and the engine (with the history's
  re-steps).
* **engine**: from the sample entering the engine to the estimate (what the status line
  shows).

Filter sets (``--sets``): ``default`` = what ``uavest run`` runs (attitude ekf,ukf,hybrid;
trackers ekf,ukf,hybrid of the radar preset); ``no-radar-hybrid`` = the same without the
hybrid tracker; ``radar-hybrid`` = attitude ekf and the radar-preset hybrid tracker alone.
``--profile`` runs cProfile (thread CPU time) over the first set's tlog run and prints
the top functions by own time.

    python benchmarks/live_latency.py [--duration 20] [--targets 10] [--sets default,...]
    python benchmarks/live_latency.py --connect tcp:127.0.0.1:5763 --duration 40
"""

from __future__ import annotations

import argparse
import copy
import cProfile
import io
import os
import pstats
import resource
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # as the command line does

import uavest.ingest.live as ingest_live  # noqa: E402
from uavest.apps.live import LIVE_STREAMS, LiveConfig, run_live  # noqa: E402
from uavest.engine.records import ScanRecord  # noqa: E402
from uavest.ingest.adsb_radar import RadarConfig  # noqa: E402
from uavest.sinks.base import Sink  # noqa: E402

SETS = {
    "default": (("ekf", "ukf", "hybrid"), ("ekf", "ukf", "hybrid")),
    "no-radar-hybrid": (("ekf", "ukf", "hybrid"), ("ekf", "ukf")),
    "radar-hybrid": (("ekf",), ("hybrid",)),
}
IMU_NAMES = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU")


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
    lines: list[str] = []

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


class _TappedLink(ingest_live.LiveLink):
    """The live link, also keeping (vehicle time s, receive time s) of every IMU message
    (a benchmark's tap on the link's message stream; not part of the package)."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        self.imu_t: list[float] = []
        self.imu_rx: list[float] = []

    def _messages(self):
        for m, rx in super()._messages():
            if m is not None and m.get_type() in IMU_NAMES:
                self.imu_t.append(m.time_usec * 1e-6)
                self.imu_rx.append(rx)
            yield m, rx


class _CpuLatency(Sink):
    """Engine CPU time (this thread's, ``time.thread_time()``) from a sample entering the
    engine to each estimate it completes: the latency on a free core, without the other
    processes of a shared machine (run over the session's tlog, as fast as it goes)."""

    def __init__(self) -> None:
        self.t_sample = time.thread_time()
        self.att: list[float] = []
        self.scan: list[float] = []
        self.need = float("nan")  # CPU s per s of session: the share of a core needed

    def sample(self, s) -> None:
        self.t_sample = time.thread_time()

    def record(self, rec) -> None:
        d = 1e3 * (time.thread_time() - self.t_sample)
        (self.scan if isinstance(rec, ScanRecord) else self.att).append(d)


class _Emitted(Sink):
    """Wall time (``time.time()``) of every estimate, with its vehicle time and kind."""

    def __init__(self) -> None:
        self.rows: list[tuple[float, float, bool]] = []

    def record(self, rec) -> None:
        self.rows.append((rec.t, time.time(), isinstance(rec, ScanRecord)))


def _percentiles(x: np.ndarray) -> tuple[float, float, float]:
    if x.size == 0:
        return (float("nan"),) * 3
    p = np.percentile(x, [50, 95, 99])
    return float(p[0]), float(p[1]), float(p[2])


def _measure(cfg: LiveConfig, settle_s: float, profile: bool):
    links: list[_TappedLink] = []

    def open_tapped(conn, **kw):
        link = _TappedLink(conn, **kw)
        links.append(link)
        return link.start()

    em = _Emitted()
    real_open = ingest_live.open_live
    ingest_live.open_live = open_tapped
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    w0 = time.perf_counter()
    try:
        doc = run_live(cfg, sinks=[em], status=False, on_note=lambda s: None)
    finally:
        ingest_live.open_live = real_open
    wall = time.perf_counter() - w0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    link = links[0]
    it = np.asarray(link.imu_t)
    irx = np.asarray(link.imu_rx)
    rows = np.asarray(em.rows, float).reshape(-1, 3)
    order = np.argsort(it, kind="stable")
    it, irx = it[order], irx[order]
    lat = {"attitude": np.empty(0), "scan": np.empty(0)}
    if len(it) and len(rows):
        t0 = rows[0, 1]
        keep = rows[:, 1] >= t0 + settle_s  # the alignment's start-up burst is not latency
        # a navigation step is stamped the IMU's low-pass delay before the IMU sample that
        # ends it (imu_delay_s): that sample's message is the one it waited for
        att = ~rows[:, 2].astype(bool)
        t_need = rows[:, 0] + np.where(att, doc.get("imu_delay_s") or 0.0, 0.0)
        j = np.searchsorted(it, t_need - 1e-7)
        ok = keep & (j < len(it))
        d = rows[ok, 1] - irx[j[ok]]
        scan = rows[ok, 2].astype(bool)
        lat = {"attitude": 1e3 * d[~scan], "scan": 1e3 * d[scan]}
    # the same session again over its tlog, as fast as it goes: engine CPU per estimate
    from uavest.apps.live import run_samples
    from uavest.ingest import open_source

    cl = _CpuLatency()
    src = open_source(cfg.tlog, reorder_window=cfg.reorder_window)
    prof = cProfile.Profile(time.thread_time) if profile else None
    if prof is not None:
        prof.enable()
    c0 = time.thread_time()
    run_samples(src, cfg, params=src.params, sinks=[cl], status=False)
    cl.need = (time.thread_time() - c0) / max(cfg.duration or 1.0, 1e-9)
    stats = None
    if prof is not None:  # the engine over the session's tlog, in this thread's CPU time
        prof.disable()
        out = io.StringIO()
        pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(20)
        stats = out.getvalue()
    n_skip = int(len(cl.att) * settle_s / max(cfg.duration or 1.0, 1.0))
    cpu_lat = {"attitude": np.asarray(cl.att[n_skip:]), "scan": np.asarray(cl.scan),
               "need": cl.need}
    return doc, lat, cpu / max(wall, 1e-9), stats, cpu_lat


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="s per filter set")
    ap.add_argument("--targets", type=int, default=10)
    ap.add_argument("--imu-rate", type=float, default=400.0, help="simulated IMU, Hz")
    ap.add_argument("--sets", default="default,no-radar-hybrid,radar-hybrid")
    ap.add_argument("--connect", help="attach to this vehicle/SITL instead of uavest sim")
    ap.add_argument("--reorder-window", type=float, default=LiveConfig.reorder_window,
                    help="s of vehicle time the link holds to order messages (default "
                    f"{LiveConfig.reorder_window:g}, uavest run's: on arrival)")
    ap.add_argument("--history", type=float, default=LiveConfig.history_s,
                    help="on arrival: s kept to apply late samples at their time (default "
                    f"{LiveConfig.history_s:g}, uavest run's)")
    ap.add_argument("--pin", action=argparse.BooleanOptionalAction, default=True,
                    help="pin this process to one core (default on)")
    ap.add_argument("--scan-hz", type=float, default=10.0, help="virtual radar scan rate")
    ap.add_argument("--settle", type=float, default=5.0, help="s left out at the start")
    ap.add_argument("--profile", action="store_true", help="cProfile the first set")
    ap.add_argument("--model", default="attitude", choices=("attitude", "nav"),
                    help="the attitude lane's model (nav: GNSS-aided navigation)")
    a = ap.parse_args()
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    sim_cores = set(cores)
    if a.pin and cores:
        os.sched_setaffinity(0, {cores[0]})
        # the simulator is the vehicle: on the other cores (when there are any), not
        # sharing the estimator's (a child inherits its parent's affinity)
        sim_cores = set(cores[1:]) or set(cores)
    table = []
    for k, name in enumerate(a.sets.split(",")):
        filters, trackers = SETS[name]
        streams = dict(LIVE_STREAMS)
        if a.connect is None:
            streams["HIGHRES_IMU"] = a.imu_rate
        with tempfile.TemporaryDirectory() as d:
            sim = None
            conn = a.connect
            if conn is None:
                port = _port()
                conn = f"udpin:127.0.0.1:{port}"
                scen = Path(d) / "bench.toml"
                _scenario(a.targets, scen)
                env = dict(os.environ, PYTHONPATH=str(ROOT))
                sim = subprocess.Popen(
                    [sys.executable, "-m", "uavest", "sim", str(scen), "--out",
                     f"udpout:127.0.0.1:{port}", "--imu-rate", str(a.imu_rate),
                     "--duration", str(a.duration + 60), "--quiet", "--wait"], env=env)
                if sim_cores:
                    os.sched_setaffinity(sim.pid, sim_cores)
            cfg = LiveConfig(connect=conn, duration=a.duration, filters=filters,
                             tlog=str(Path(d) / "session.tlog"),
                             trackers=trackers, reorder_window=a.reorder_window,
                             history_s=a.history, model=a.model,
                             radar=RadarConfig(period=1.0 / a.scan_hz, max_range=8000.0),
                             streams=streams, heartbeat_timeout=30.0)
            try:
                doc, lat, cpu, prof, cpu_lat = _measure(cfg, a.settle, a.profile and k == 0)
            finally:
                if sim is not None:
                    sim.terminate()
                    sim.wait(timeout=10)
        imu_hz = max((doc["link"]["rates_hz"].get(n, 0.0) for n in IMU_NAMES), default=0.0)
        eng = doc["latency_ms"] or {}
        table.append((name, lat, eng, cpu, doc, imu_hz, cpu_lat))
        if prof:
            print(f"cProfile of set {name}, the engine over the session's tlog (thread CPU "
                  f"time; top 20 by own time):\n{prof}")
    src = a.connect or f"uavest sim, {a.targets} aircraft, IMU {a.imu_rate:g} Hz"
    order = (f"on arrival, history {a.history:g} s" if not a.reorder_window > 0 else
             f"reorder window {a.reorder_window:g} s")
    print(f"live latency ({src}; {a.model} model; virtual radar {a.scan_hz:g} Hz; {order}; "
          f"{a.duration:g} s per set, first {a.settle:g} s left out; "
          f"{f'estimator on core {cores[0]}' if a.pin and cores else 'not pinned'}; "
          f"{'' if a.connect else f'simulator on cores {sorted(sim_cores)}; '}load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores); ms")
    print("receipt = receive time of the message completing the estimate -> estimate "
          "emitted (wall); engine cpu = this thread's CPU time from the sample entering the "
          "engine to the estimate, the session's tlog run again (a free core's latency, "
          "without the reorder window); got = CPU share of a core the live run had, need = "
          "engine CPU s per s of session (the tlog run)")
    hdr = (f"{'set':16s} {'kind':9s} {'n':>5s} {'receipt p50':>11s} {'p95':>8s} {'p99':>8s}"
           f"  {'engine cpu p50':>14s} {'p95':>7s} {'p99':>7s}  {'got':>4s} {'need':>4s}  extra")
    print(hdr)
    print("-" * len(hdr))
    for name, lat, _eng, cpu, doc, imu_hz, cl in table:
        for kind in ("attitude", "scan"):
            x = lat[kind]
            p50, p95, p99 = _percentiles(x)
            c50, c95, c99 = _percentiles(cl[kind])
            if kind == "attitude":
                late = doc["link"]["bad_data"].get("late", 0)
                h = list(doc["history"]["lanes"].values())
                rw = sum(v["rewinds"] for v in h)
                deep = max((v["deepest_s"] for v in h), default=0.0)
                extra = (f"IMU {imu_hz:.0f} Hz in; {doc['steps'] - doc['scans']} steps; "
                         f"late {late}; applied at their time {rw} (deepest "
                         f"{1e3 * deep:.0f} ms)")
            else:
                extra = (f"{doc['scans']} scans, {doc['targets_seen']} aircraft; ms/scan " +
                         ", ".join(f"{k} {v['us_per_scan'] / 1e3:.1f}"
                                   for k, v in doc["tracks"].items()))
            print(f"{name:16s} {kind:9s} {x.size:5d} {p50:11.1f} {p95:8.1f} {p99:8.1f}"
                  f"  {c50:14.2f} {c95:7.2f} {c99:7.2f}  {100 * cpu:3.0f}% "
                  f"{100 * cl['need']:3.0f}%  {extra}")
    print("goal (issue 18): p99 < 20 ms on one core")


if __name__ == "__main__":
    main()
