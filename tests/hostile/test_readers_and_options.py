"""Issue 11, items 4 and 5: bad data counted from every reader and kept off the
terminal; partial logs recovered; every input validated with a one-line error, exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from uavest.cli import main
from uavest.ingest import open_source

from . import cases as H
from . import corpus as C

ROOT = Path(__file__).resolve().parents[2]


def _stats(path):
    s = open_source(path)
    n = sum(1 for _ in s)
    return n, s.stats


def test_dataflash_damage_is_counted_and_pymavlink_kept_quiet(tmp_path, logs, capfd):
    """Issue: pymavlink printed 'Skipped N bad bytes'/'bad header' (up to 107 lines) and a
    byte-flipped .bin reported the same counts as the clean file."""
    d = (logs / "test.BIN").read_bytes()
    _, st0 = _stats(logs / "test.BIN")
    for i, data in enumerate((C.flip_bits(d, 1e-3, 3, skip=3000),
                              C.random_after_header(d, 20000, 500_000, 1))):
        p = tmp_path / f"b{i}.bin"
        p.write_bytes(data)
        _, st = _stats(p)
        assert st.corrupt > st0.corrupt
    out, err = capfd.readouterr()
    assert "bad header" not in out + err and "Skipped" not in out + err


def test_pymavlink_lines_shown_with_verbose(tmp_path, logs, caplog):
    import logging

    d = (logs / "test.BIN").read_bytes()
    p = tmp_path / "r.bin"
    p.write_bytes(C.random_after_header(d, 20000, 100_000, 1))
    with caplog.at_level(logging.INFO, logger="uavest"):
        _stats(p)
    assert any("pymavlink" in r.getMessage() for r in caplog.records)


def test_tlog_random_after_header_counted(tmp_path, logs):
    """Issue: 50 MB of random bytes after a valid header counted as 'corrupt 2'."""
    d = (logs / "vtol.tlog").read_bytes()
    p = tmp_path / "r.tlog"
    p.write_bytes(C.random_after_header(d, 40_000, 1_000_000, 2))
    _, st = _stats(p)
    assert st.corrupt > 1000


def test_one_corrupt_ulog_parameter_keeps_the_log(tmp_path, logs):
    """Issue: one corrupt parameter made a whole ULog fail ('could not convert string to
    float: b'\\x00...'')."""
    d = (logs / "sample_px4_events.ulg").read_bytes()
    p = tmp_path / "p.ulg"
    p.write_bytes(C.ulog_corrupt_param(d, 3))
    s = open_source(p)
    imu = sum(1 for m in s if type(m).__name__ == "ImuSample")
    assert imu > 7000 and s.stats.rejected["corrupt:parameter"] == 1


def test_truncated_ulog_header_names_the_file_not_a_window(tmp_path, logs, capsys):
    d = (logs / "sample_px4_events.ulg").read_bytes()
    p = tmp_path / "h.ulg"
    p.write_bytes(d[: C.ulog_data_start(d) + 10])
    assert main(["replay", str(p), "--filters", "ekf", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert str(p) in err and "window" not in err and "no IMU samples" in err


_BAD = [c for c in H.all_cases(full=False) if c["expect"] == "error" and c.get("data") is None
        and not c.get("special")]


@pytest.mark.parametrize("case", _BAD, ids=[c["name"] for c in _BAD])
def test_bad_option_one_line_exit_2(case, tmp_path, capsys):
    """Issue: --declination nan, --noise gyro_noise=nan, --mag-delay -100, --runs 0,
    --steps 0/2.5, kf, ekf,ekf, --filters '', Q = nan, R = inf, pd = 7.5, clutter_rate =
    -3 / 1e7, prior mean length, unknown motion model, confirm_m = 'four', filters =
    'ukf', steps = -1, bench --runs 1000000000 ... each a one-line error and exit 2."""
    argv = [a.replace("{d}", str(tmp_path)) for a in case["argv"]]
    try:
        rc = main(argv)
    except SystemExit as e:  # argparse usage errors
        rc = e.code
    err = [ln for ln in capsys.readouterr().err.splitlines()
           if ln.strip() and not ln.startswith("usage:") and not ln.startswith(" ")]
    assert rc == 2
    assert len(err) == 1 and "error" in err[0] and len(err[0]) < 400, err


_TOML = [c for c in H.all_cases(full=False) if c["cls"] == "bad scenario TOML"]


@pytest.mark.parametrize("case", _TOML, ids=[c["name"] for c in _TOML])
def test_bad_scenario_file(case, tmp_path, capsys):
    f = tmp_path / f"s{case['ext']}"
    f.write_bytes(case["data"])
    rc = main([a.replace("{f}", str(f)) for a in case["argv"]])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and str(f) in err[0], err


def test_directory_and_missing_file(tmp_path):
    from uavest.ingest import IngestError, detect_format

    with pytest.raises(IngestError, match="is a directory"):
        detect_format(tmp_path)
    with pytest.raises(IngestError, match="no such file"):
        detect_format(tmp_path / "missing.tlog")


@pytest.mark.slow
@pytest.mark.parametrize("special", ["FIFO", "/dev/zero"])
def test_special_files_child_process(special, tmp_path):
    """Issue: FIFO and /dev/zero reported as 'no such log file' (and /dev/zero a
    traceback); a FIFO must not hang the reader."""
    case = next(c for c in H.all_cases(full=False) if c.get("special") == special)
    res = H.run(case, tmp_path, timeout=60)
    assert H.classify(case, res) == "clear_error", res["stderr"]
    want = {"FIFO": "FIFO", "/dev/zero": "character device", "directory": "directory",
            "missing": "no such log file"}[special]
    assert want in res["stderr"]


def test_track_exits_2_like_every_command(tmp_path):
    """Issue: track exited 1 where every other command exits 2."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, "-m", "uavest", "track", "radar_multitarget", "--set",
                        "radar.pd=7.5"], capture_output=True, text=True, env=env, timeout=60)
    assert p.returncode == 2 and "Traceback" not in p.stderr


def test_progress_follows_the_bytes_read(logs):
    """Issue: no progress while a log is read (a 50 MB tlog read for 83 s in silence)."""
    from uavest.apps.replay import ReplayConfig, replay
    from uavest.cli.replay import _Progress

    bar = _Progress(False, str(logs / "test.BIN"))
    replay(logs / "test.BIN", ReplayConfig(filters=("ekf",)), sinks=[bar], on_source=bar.source)
    assert bar.src is not None and bar.bar.total == (logs / "test.BIN").stat().st_size
    assert bar.src.bytes_read > 0.9 * bar.bar.total
