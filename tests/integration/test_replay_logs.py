"""Replay on the shared logs and on damaged copies of vtol.tlog (random bytes spliced in,
truncated): bad data is counted, no exception, filters still score against SIMSTATE.
Logs are read from repo_root/../shared/logs; tests skip if they are absent."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_log, shared_logs_dir

from uavest.apps.replay import ReplayConfig, replay
from uavest.engine.attitude import AttitudeOptions, AttitudeStream
from uavest.engine.records import Start, Step
from uavest.eval.attitude import rmse_deg
from uavest.geometry.rotation import quat_slerp_interp
from uavest.ingest import open_source, read_log

LOGS = shared_logs_dir()
VTOL = LOGS / "vtol.tlog"
BIN = LOGS / "test.BIN"


def need(p: Path) -> Path:
    """``p`` (a shared log under LOGS), or skip with the reason (tests/conftest.py)."""
    return shared_log(p.name)


def _prefix(tmp_path: Path, nbytes: int = 250_000) -> bytes:
    return need(VTOL).read_bytes()[:nbytes]


@pytest.mark.slow
def test_spliced_random_bytes_are_counted_and_replay_survives(tmp_path):
    data = bytearray(_prefix(tmp_path))
    rng = np.random.default_rng(7)
    for pos in sorted(rng.integers(10_000, len(data) - 10_000, 6), reverse=True):
        data[pos:pos] = rng.integers(0, 256, 300, dtype=np.uint8).tobytes()
    p = tmp_path / "spliced.tlog"
    p.write_bytes(bytes(data))
    doc = replay(p, ReplayConfig(filters=("ekf", "ukf")))
    assert doc["bad_data"]["corrupt"] > 0
    assert doc["reference"] == "SIMSTATE"
    for name in ("ekf", "ukf"):
        row = doc["filters"][name]
        assert np.isfinite(row["roll_rmse_deg"]) and row["roll_rmse_deg"] < 30.0


def test_truncated_tlog_is_counted_and_replays(tmp_path):
    data = _prefix(tmp_path, 200_003)  # ends inside a record
    p = tmp_path / "cut.tlog"
    p.write_bytes(data)
    doc = replay(p, ReplayConfig(filters=("ekf",)))
    assert doc["bad_data"]["truncated"] + doc["bad_data"]["corrupt"] >= 1
    assert doc["steps"] > 50
    assert np.isfinite(doc["filters"]["ekf"]["yaw_rmse_deg"])


def _gyro_only_rmse(path: Path, end: float) -> dict:
    """The model's f with zero bias over the replay's steps, from the same initial attitude
    as the filters, no measurement updates; RMSE against SIMSTATE."""
    data = read_log(path, end=end)
    src = open_source(path)
    items = list(AttitudeStream(src, AttitudeOptions(end=end), params=src.params))
    start, steps = items[0], [s for s in items if isinstance(s, Step)]
    assert isinstance(start, Start)
    x = start.prior.x.copy()  # the filters' initial attitude, zero bias
    model = steps[0].transition
    q = np.empty((len(steps), 4))
    for k, st in enumerate(steps):
        x = model.f(x, st.t, st.dt, st.u)
        q[k] = x[:4]
    ref = data.references["SIMSTATE"]
    ref_q, mask = quat_slerp_interp(ref.t, ref.q, np.array([st.t for st in steps]))
    return rmse_deg(q, ref_q, mask)


@pytest.mark.slow
def test_vtol_window_beats_gyro_only_and_reports_truth(tmp_path):
    need(VTOL)
    doc = replay(VTOL, ReplayConfig(filters=("ekf",), end=700.0, smooth=True))
    assert doc["reference"] == "SIMSTATE" and doc["reference_kind"] == "truth"
    row = doc["filters"]["ekf"]
    assert "nees_mean" in row and "smoothed" in row
    gyro = _gyro_only_rmse(VTOL, 700.0)
    for axis in ("roll", "pitch", "yaw"):
        assert row[f"{axis}_rmse_deg"] < 0.5 * gyro[f"{axis}_rmse_deg"], axis
    assert max(row["roll_rmse_deg"], row["pitch_rmse_deg"], row["yaw_rmse_deg"]) < 8.0
    assert doc["filters"]["autopilot"]["source"] == "ATTITUDE"


def _total_rmse(row: dict) -> float:
    return float(np.sqrt(sum(row[f"{a}_rmse_deg"] ** 2 for a in ("roll", "pitch", "yaw"))))


@pytest.mark.slow
@pytest.mark.parametrize("spec", ["hybrid(sampling=random)", "hybrid_sh"])
def test_smoothing_works_when_members_are_not_kept_or_filter_is_wrapped(spec):
    # members redrawn every step (sampling=random) or the hybrid wrapped in SageHusa:
    # the smoother must not pair unrelated members (C ~ 0, smoothing a no-op) but fall
    # back to the sigma-point cross-covariance, and beat the filter
    # (the ratio of one seeded run varies, 0.83-0.96 over seeds 0-2 for sampling=random:
    # the mean over two seeds is the claim)
    need(VTOL)
    ratios = []
    for seed in (0, 1):
        cfg = ReplayConfig(filters=(spec,), end=700.0, smooth=True, seed=seed)
        row = replay(VTOL, cfg)["filters"][spec]
        ratios.append(_total_rmse(row["smoothed"]) / _total_rmse(row))
    assert np.mean(ratios) < 0.95, ratios  # no-op: ~1.0


def test_short_dataflash_log_reads_replays_and_reports():
    need(BIN)
    doc = replay(BIN, ReplayConfig())
    assert doc["format"] == "dataflash"
    assert doc["reference"] == "ATT" and doc["reference_kind"] == "autopilot"
    assert set(doc["filters"]) >= {"ekf", "ukf", "hybrid"}
    for name in ("ekf", "ukf", "hybrid"):
        assert np.isfinite(doc["filters"][name]["roll_rmse_deg"])
        assert "nees_mean" not in doc["filters"][name]  # no truth, no NEES


def _cli(*argv: str):
    from uavest.cli import main

    return main(["replay", *argv])


def test_cli_json_shape(tmp_path, capsys):
    need(BIN)
    out = tmp_path / "r.json"
    assert _cli(str(BIN), "--filters", "ekf,ukf", "--json", str(out), "--no-progress",
                "--smooth") == 0
    doc = json.loads(out.read_text())
    for k in ("log", "reference", "imu_rate_hz", "filters", "bad_data", "realtime_factor"):
        assert k in doc
    assert "smoothed" in doc["filters"]["ekf"]
    assert "us_per_step" in doc["filters"]["ukf"]
    assert "reference: ATT" in capsys.readouterr().out


@pytest.mark.slow
def test_cli_errors_exit_2_without_traceback(tmp_path):
    code = (
        "import sys;from uavest.cli import main;sys.exit(main(sys.argv[1:]))"
    )
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(b"\x00" * 10)
    for argv, says in (
        (["replay", str(tmp_path / "nope.tlog")], "no such log file"),
        (["replay", str(tmp_path)], "is a directory, not a log file"),
        (["replay", str(junk), "--filters", "nosuch"], "nosuch"),
        (["replay", str(junk), "--filters", "ekf,ukf,ekf"], "ekf more than once"),
    ):
        r = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
        assert r.returncode == 2
        assert "Traceback" not in r.stderr and r.stderr.count("\n") == 1
        assert says in r.stderr, (argv, r.stderr)
    r = subprocess.run([sys.executable, "-c", code, "replay", str(junk)], capture_output=True,
                       text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr


@pytest.mark.slow
def test_filter_numbers_do_not_depend_on_the_other_filters():
    """Each filter draws from (seed, its own label), so running it alone or beside others
    gives identical numbers (the bench harness has the same property)."""
    if not VTOL.exists():
        pytest.skip(f"shared log {VTOL} not present")
    keys = ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg")
    alone = replay(VTOL, ReplayConfig(filters=("hybrid",), end=650.0))["filters"]["hybrid"]
    both = replay(VTOL, ReplayConfig(filters=("ekf", "ukf", "hybrid"), end=650.0))
    assert [alone[k] for k in keys] == [both["filters"]["hybrid"][k] for k in keys]
    other = replay(VTOL, ReplayConfig(filters=("hybrid",), end=650.0, seed=5))
    assert [other["filters"]["hybrid"][k] for k in keys] != [alone[k] for k in keys]
