"""``uavest run`` attached to the real ArduCopter SITL (../shared/sitl) while its scripted
flight flies it on another port (mark ``live``; skipped with the reason when absent).

One SITL session is shared by the module (~70 s of wall time): the SITL is started in
its own process group (setsid) and the whole group is killed with SIGKILL at teardown.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO_ROOT, shared_sitl_dir

pytestmark = pytest.mark.live

DURATION_S = 70.0
INSTANCE = 3  # -I offsets every port by 10*I: SERIAL0 5790, SERIAL2 5793


def _sitl_or_skip() -> Path:
    d = shared_sitl_dir()
    if not (d / "arducopter").is_file() or not (d / "fly.py").is_file():
        pytest.skip(f"ArduCopter SITL not found in {d} (repo_root/../shared/sitl, or set "
                    "UAVEST_SITL)")
    return d


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _kill_group(p: subprocess.Popen) -> None:
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    p.wait(timeout=10)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Run the SITL, fly.py on SERIAL0 and ``uavest run`` on SERIAL2; yield the outputs."""
    from pymavlink import mavutil

    d = _sitl_or_skip()
    work = tmp_path_factory.mktemp("sitl")
    base = 5760 + 10 * INSTANCE
    sitl = subprocess.Popen(
        [str(d / "arducopter"), "--model", "+", "--speedup", "1", f"-I{INSTANCE}",
         "--home", "47.3977,8.5456,408,270", "--defaults",
         ",".join(str(d / f) for f in ("copter.parm", "common.parm", "adsb.parm")), "-w"],
        cwd=work, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    procs = [sitl]
    try:
        time.sleep(3.0)
        fly = subprocess.Popen(
            [sys.executable, str(d / "fly.py"), "--url", f"tcp:127.0.0.1:{base}",
             "--out", str(work / "fly.tlog"), "--profile", "flight5"],
            cwd=work, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True)
        procs.append(fly)
        pub_port = _free_udp_port()
        gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{pub_port}")
        env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
        run = subprocess.Popen(
            [sys.executable, "-m", "uavest", "run", "--connect", f"tcp:127.0.0.1:{base + 3}",
             "--duration", str(DURATION_S), "--mcap", str(work / "live.mcap"),
             "--tlog", str(work / "live.tlog"), "--json", str(work / "live.json"),
             "--publish", f"udpout:127.0.0.1:{pub_port}", "--no-status"],
            cwd=work, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True)
        procs.append(run)
        seen: dict[int, int] = {}
        deadline = time.monotonic() + DURATION_S + 60.0
        while run.poll() is None and time.monotonic() < deadline:
            m = gcs.recv_match(blocking=True, timeout=0.5)
            if m is not None and m.get_type() != "BAD_DATA":
                seen[m.get_srcSystem()] = seen.get(m.get_srcSystem(), 0) + 1
        out = run.communicate(timeout=30)[0]
        yield {"work": work, "rc": run.returncode, "out": out, "published": seen}
    finally:
        for p in reversed(procs):
            _kill_group(p)


def test_run_exits_cleanly(session):
    assert session["rc"] == 0, session["out"][-2000:]


def test_mcap_read_back(session):
    from mcap.reader import make_reader

    counts: dict[str, int] = {}
    with open(session["work"] / "live.mcap", "rb") as f:
        for _schema, channel, _msg in make_reader(f).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts and all(n > 0 for n in counts.values()), counts


def test_publish_under_own_sysid(session):
    seen = session["published"]
    assert seen.get(250, 0) > 0, seen
    assert 1 not in seen, "the vehicle's system id leaked onto --publish"


def test_replay_of_session_tlog(session):
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    tlog = str(session["work"] / "live.tlog")
    r = subprocess.run([sys.executable, "-m", "uavest", "replay", tlog],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
