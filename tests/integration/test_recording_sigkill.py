"""A recorder killed with SIGKILL mid-run loses at most about one second (wall time) of
data: every message of the chunks closed before the kill is recovered from the torn
file (no summary, no footer), and the report still works on it."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_logs_dir

from uavest.report import read_recording, write_report

VTOL = shared_logs_dir() / "vtol.tlog"
# a recording subprocess killed mid-run, then read back
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not VTOL.exists(), reason=f"needs {VTOL} (or UAVEST_LOGS)")]

SCRIPT = r"""
import sys, time
from uavest.apps.replay import ReplayConfig, replay
from uavest.sinks.base import Sink
from uavest.sinks.mcap import McapSink

class Pace(Sink):
    # (chunk_size 1 GiB: only the 1 s wall-time flush closes chunks here)
    # slows the run down (so it is still running when killed) and logs the wall time at
    # which each ekf step was handed to the recorder (the recorder is the first sink)
    def __init__(self, path):
        self.f = open(path, "w", buffering=1)
    def record(self, rec):
        if rec.estimator == "ekf":
            self.f.write(f"{rec.k} {time.time():.6f}\n")
        time.sleep(0.02)

out, progress = sys.argv[1], sys.argv[2]
sink = McapSink(out, flush_s=1.0, chunk_size=1 << 30)
replay(sys.argv[3], ReplayConfig(), sinks=[sink, Pace(progress)])
print("finished")
"""


def _progress(path: Path) -> list[tuple[int, float]]:
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        p = line.split()
        if len(p) == 2:
            rows.append((int(p[0]), float(p[1])))
    return rows


def test_sigkill_mid_run_loses_at_most_about_a_second(tmp_path):
    out, prog = tmp_path / "killed.mcap", tmp_path / "progress.txt"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]),
               OPENBLAS_NUM_THREADS="1")
    p = subprocess.Popen([sys.executable, "-c", SCRIPT, str(out), str(prog), str(VTOL)],
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.time() + 120
        while time.time() < deadline:
            rows = _progress(prog)
            if len(rows) > 2 and rows[-1][1] - rows[0][1] > 6.0:
                break
            assert p.poll() is None, p.communicate()
            time.sleep(0.05)
        else:
            pytest.fail("the recorder made no progress")
        os.kill(p.pid, signal.SIGKILL)
        p.wait(timeout=10)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == -signal.SIGKILL
    kill_wall = time.time()
    rows = _progress(prog)
    assert rows[-1][0] < 793, "the run finished before the kill"
    rec = read_recording(out)
    assert rec.truncated and rec.chunks >= 2
    assert {"run", "filters", "versions", "recording"} <= set(rec.metadata)
    est = rec.json["/attitude/ekf/estimate"]
    ks = [m["k"] for m in est]
    assert ks == list(range(1, len(ks) + 1))  # a gap-free prefix
    wall = dict(rows)
    lost_s = rows[-1][1] - wall[ks[-1]]
    # flush every 1 s of wall time; a step is handed to the recorder before Pace logs it
    assert lost_s <= 1.6, (lost_s, ks[-1], rows[-1])
    print(f"lost {lost_s:.2f} s of wall time, {rows[-1][0] - ks[-1]} steps; chunks {rec.chunks}")
    assert kill_wall - wall[ks[-1]] < 5.0
    # the other filters' channels are recovered to the same point (within a step)
    for lab in ("ukf", "hybrid"):
        k2 = [m["k"] for m in rec.json[f"/attitude/{lab}/estimate"]]
        assert k2 == list(range(1, len(k2) + 1)) and abs(len(k2) - len(ks)) <= 1
    np.testing.assert_equal(len(rec.decode("/tf/ekf")), rec.counts["/tf/ekf"])
    paths = write_report(out, tmp_path / "rep")
    assert "truncated (writer killed)</td><td>True" in paths["html"].read_text()
