"""benchmarks/live_seeds.py: the live job over the simulator's own flights. Its figures
are those `uavest run --connect TLOG --json` gives for the same tlog (a real subprocess),
and its tlog carries what a live session's does: the streams the live job asks for and
the simulator's sensor spec."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import load_benchmark
from pymavlink import mavutil


@pytest.mark.slow
def test_benchmark_figures_are_the_cli_runs(tmp_path):
    bench = load_benchmark("live_seeds")
    got = bench.trial(3, 200.0, ("ekf",), 14.0, 4.0, {}, [], str(tmp_path))
    tlog = tmp_path / "seed3_200hz.tlog"
    names, params, fixes, truth = set(), set(), [], []
    m = mavutil.mavlink_connection(str(tlog))
    while (msg := m.recv_match()) is not None:
        names.add(msg.get_type())
        if msg.get_type() == "PARAM_VALUE":
            params.add(msg.param_id)
        elif msg.get_type() == "GPS_RAW_INT" and msg.fix_type >= 3:
            fixes.append((msg._timestamp, msg.lat * 1e-7, msg.lon * 1e-7))
        elif msg.get_type() == "HIL_STATE_QUATERNION":
            truth.append((msg._timestamp, msg.lat * 1e-7, msg.lon * 1e-7))
    m.close()
    assert {"HIGHRES_IMU", "GPS_RAW_INT", "SCALED_PRESSURE", "SIMSTATE",
            "HIL_STATE_QUATERNION"} <= names
    assert {"SPEC_GYR_NSD", "SPEC_MAG_NSR", "COMPASS_DEC"} <= params

    out = tmp_path / "run.json"
    subprocess.run([sys.executable, "-m", "uavest", "run", "--connect", str(tlog),
                    "--model", "nav", "--filters", "ekf", "--trackers", "none",
                    "--settle", "4", "--json", str(out)],
                   check=True, capture_output=True, timeout=300)
    want = bench.scores(json.loads(out.read_text())["attitude"]["ekf"])
    assert got["ekf"] == want
    s = bench.summary({3: got}, "ekf")
    assert s["n"] == 1 and s["settled"]["meets"] == int(bench.meets(want["settled"]))
    assert list(s["whole"]["rpy_max"]) == want["whole"]["rpy"]
    assert s["settled"]["meets_att_vel"] >= s["settled"]["meets"]
    # the receiver's own error, here from pymavlink's decoding, on the tlog's receive
    # times, on a sphere: the benchmark's within 3 %
    f, r = np.array(fixes), np.array(truth)
    lat, lon = (np.interp(f[:, 0], r[:, 0], r[:, k]) for k in (1, 2))
    dn, de = (np.radians(f[:, 1] - lat) * 6371e3,
              np.radians(f[:, 2] - lon) * 6371e3 * np.cos(np.radians(lat)))
    late = f[:, 0] >= f[0, 0] + 4.0
    rms = float(np.sqrt(np.mean((dn**2 + de**2)[late])))
    assert 0.1 < rms < 5.0 and got["receiver"]["settled"] == pytest.approx(rms, rel=0.03)


def test_seed_list():
    bench = load_benchmark("live_seeds")
    assert bench.seed_list("0-3,7") == [0, 1, 2, 3, 7]
    assert bench.seed_list("5") == [5]


@pytest.mark.parametrize("args, says", [
    (["--noise", "mag_noise"], "--noise expects KEY=VALUE"),
    (["--noise", "nope=1"], "--noise: unknown parameter 'nope'"),
    (["--noise", "mag_noise=-1"], "must be a finite number >= 0"),
    (["--set", "gps.nope=1"], "unknown scenario key"),
    (["--seeds", "a-b"], "expected seeds as 0-7"),
    (["--rates", "200,0"], "expected rates in Hz"),
])
def test_bad_arguments_are_one_line_errors(args, says):
    from conftest import REPO_ROOT

    p = subprocess.run([sys.executable, str(REPO_ROOT / "benchmarks" / "live_seeds.py"),
                        *args], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and says in p.stderr and "Traceback" not in p.stderr
