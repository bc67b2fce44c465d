"""Shared inputs of the evaluate tests: short windows of the repository's simulated tlog
(content differs per window, so every window is its own input), and the shared logs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from conftest import shared_log as _shared_log
from conftest import shared_logs_dir

REPO = Path(__file__).resolve().parents[2]
SIM = REPO / "logs" / "sim_200hz.tlog"
SHARED = shared_logs_dir()  # tests/conftest.py: $UAVEST_LOGS or repo_root/../shared/logs

TIMING = {"wall_s", "kernel_load_s", "realtime_factor", "us_per_step", "seconds", "elapsed_s",
          "cpu_s", "pid", "host", "run_id", "finished_at", "backend", "attempts"}


def numbers(o):
    """A stored document without wall times and bookkeeping (all that may differ)."""
    if isinstance(o, dict):
        return {k: numbers(v) for k, v in o.items() if k not in TIMING}
    if isinstance(o, list):
        return [numbers(v) for v in o]
    return o


def make_windows(folder: Path, n: int, length: float = 2.5, step: float = 5.0) -> list[Path]:
    from uavest.fleet.tools import cut_tlog

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(n):
        p = folder / f"w{i:02d}.tlog"
        cut_tlog(SIM, p, 2.0 + i * step, 2.0 + i * step + length)
        out.append(p)
    return out


def shared_log(name: str) -> Path:
    """One shared log, or skip with the reason (tests/conftest.py's ``shared_log``)."""
    return _shared_log(name)


def cli_env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1",
               OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.update(extra)
    return env


def evaluate_cmd() -> list[str]:
    """``python -m uavest evaluate`` once the command is registered, else the module."""
    from uavest.cli import build_parser

    ap = build_parser()
    sub = next(a for a in ap._actions if a.__class__.__name__ == "_SubParsersAction")
    if "evaluate" in sub.choices:
        return [sys.executable, "-m", "uavest", "evaluate"]
    return [sys.executable, "-m", "uavest.cli.evaluate"]


def run_cli(args: list[str], timeout: float = 300, **env) -> subprocess.CompletedProcess:
    return subprocess.run(evaluate_cmd() + args, capture_output=True, text=True,
                          timeout=timeout, env=cli_env(**env), cwd=REPO)
