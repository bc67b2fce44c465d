"""The command line's contract: bare ``uavest`` prints help and the quick-start line;
``--version``; every bad usage or input is one line on stderr and exit code 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from uavest import __version__
from uavest.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _run(*argv: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "uavest", *argv], env=env,
                          capture_output=True, text=True, timeout=120)


def test_bare_uavest_prints_help_and_the_quick_start_without_running_anything(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "usage: uavest" in out and "quick start: uavest demo" in out


def test_version():
    r = _run("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"uavest {__version__}"


@pytest.mark.parametrize("argv,says", [
    (["bench", "ungm", "--filters", "ukf(alpha=abc)"], "alpha"),
    (["bench", "ungm", "--filters", "hybrid(n_cloud=2.5)"], "n_cloud"),
    (["bench", "ungm", "--filters", "hybrid(n_cloud=-1)"], "n_cloud"),
    (["bench", "ungm", "--filters", "enkf(members=1)"], "members"),
    (["bench", "ungm", "--filters", "hybrid(update_mode=local, tau=0.2)"], "no effect"),
    (["bench", "ungm", "--filters", "nosuch"], "unknown filter"),
    (["bench", "ungm", "--filters", "ekf,ekf"], "ekf"),
    (["bench", "ungm", "--filters", ""], "empty"),
    (["bench", "ungm", "--runs", "0"], "--runs"),
    (["bench", "nosuchscenario"], "nosuchscenario"),
    (["track", "ungm"], "not a radar scenario"),
    (["replay", "/nonexistent.tlog"], "no such log file"),
    (["nosuchcommand"], "invalid choice"),
])
def test_bad_input_is_one_line_and_exit_2(argv, says, capsys):
    # in-process (the process boundary is covered by test_version and the live tests):
    # an exception escaping main() would fail the test, as a traceback would
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert says in last, (argv, err)
    if argv[0] != "nosuchcommand":  # argparse prints its usage line before the message
        assert len(err.strip().splitlines()) == 1, err
