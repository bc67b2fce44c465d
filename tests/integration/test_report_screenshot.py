"""The report page renders in headless Chromium with no network (benchmarks/
report_screenshot.py), and ``uavest report`` works as a command."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import shared_logs_dir

# a replay to MCAP, then the report rendered (headless chromium, a subprocess)
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
VTOL = shared_logs_dir() / "vtol.tlog"


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    if not VTOL.exists():
        pytest.skip(f"needs {VTOL} (repo_root/../shared/logs, or set UAVEST_LOGS)")
    from uavest.apps.replay import ReplayConfig, replay
    from uavest.sinks.mcap import McapSink

    path = tmp_path_factory.mktemp("shot") / "short.mcap"
    replay(VTOL, ReplayConfig(end=640.0), sinks=[McapSink(path)])
    return path


@pytest.mark.skipif(shutil.which("chromium") is None,
                    reason="chromium not installed (apt-get install -y chromium)")
def test_headless_chromium_renders_the_report(recording, tmp_path):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import report_screenshot as rs
    finally:
        sys.path.pop(0)
    assert rs.main([str(recording), "--out", str(tmp_path)]) == 0
    st = rs.blank_check(tmp_path / "short.screenshot.png")
    assert st["width"] == 1400 and st["height"] == 3000
    assert st["nonwhite"] > 0.02 and st["coloured"] > 0.001
    # a blank page fails the same check
    blank = tmp_path / "blank.html"
    blank.write_text("<html><body></body></html>")
    rs.screenshot(blank, tmp_path / "blank.png")
    b = rs.blank_check(tmp_path / "blank.png")
    assert b["nonwhite"] < 0.02


def test_report_command(recording, tmp_path):
    r = subprocess.run([sys.executable, "-m", "uavest.cli.report_cmd", str(recording),
                        "--out", str(tmp_path)], capture_output=True, text=True,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "short.html").exists() and (tmp_path / "short.md").exists()
    r = subprocess.run([sys.executable, "-m", "uavest.cli.report_cmd", str(tmp_path / "no.mcap")],
                       capture_output=True, text=True, env={"PYTHONPATH": str(ROOT)})
    assert r.returncode == 2 and "no such file" in r.stderr
