"""What runs on a worker: one task (a log replay or a shard of Monte Carlo trials).

This module is imported by every worker (process pool, Dask worker, or the driver when
serial), so it pins BLAS to one thread before numpy loads and imports the estimators
lazily. A task is a plain picklable :class:`Task`; :func:`run_task` returns a JSON-ready
dict and raises on a bad input (the driver turns the exception into a failure with its
reason). Nothing here writes files other than a temporary copy of a shipped log.
"""

from __future__ import annotations

import os

# The filters do many tiny matrix operations: a multithreaded BLAS only adds
# synchronisation on a loaded machine (see uavest/cli/__init__.py). Set before numpy loads
# in this worker; the driver also sets them in the environment its workers inherit.
BLAS_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
for _k, _v in BLAS_ENV.items():
    os.environ.setdefault(_k, _v)

import fnmatch  # noqa: E402
import hashlib  # noqa: E402
import signal  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402

from ..errors import InputError  # noqa: E402

__all__ = ["CRASH_ENV", "Task", "init_worker", "run_task"]

#: Test-only hook: a worker whose task name matches this fnmatch pattern kills itself
#: with SIGKILL (stands in for a log that crashes its worker: segfault, OOM killer).
CRASH_ENV = "UAVEST_EVALUATE_CRASH_ON"


@dataclass(frozen=True)
class Task:
    """One unit of work. ``kind`` "log": replay ``path`` (or the shipped bytes ``data``,
    written to a temporary file with ``suffix``) with ReplayConfig fields ``replay``;
    ``kind`` "shard": Monte Carlo trials ``lo`` .. ``hi - 1`` of ``scenario`` (the loaded
    scenario dict) with filter ``specs`` and ``seed``."""

    key: str
    kind: str
    name: str
    path: str | None = None
    data: bytes | None = None
    sha256: str | None = None
    suffix: str = ""
    replay: dict = field(default_factory=dict)
    scenario: dict = field(default_factory=dict)
    specs: tuple = ()
    seed: int = 0
    lo: int = 0
    hi: int = 0

    def shipped(self, data: bytes) -> Task:
        """This task carrying the log's bytes (for workers that cannot see the file)."""
        from dataclasses import replace

        return replace(self, data=data)


def worker_env() -> dict:
    """The driver's settings a pool worker takes (a forkserver started earlier would
    otherwise keep the environment it started with)."""
    env = {k: os.environ.get(k, v) for k, v in BLAS_ENV.items()}
    env[CRASH_ENV] = os.environ.get(CRASH_ENV)
    return env


def init_worker(env: dict | None = None) -> None:
    """Process-pool initializer: the driver's BLAS settings (numpy in a worker started by
    spawn loads after this; with forkserver the server itself was started with them),
    and Ctrl-C goes to the driver only (it decides; workers print no tracebacks)."""
    for k, v in (env or {}).items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    for k, v in BLAS_ENV.items():
        os.environ.setdefault(k, v)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _crash_hook(name: str) -> None:
    pat = os.environ.get(CRASH_ENV)
    if pat and fnmatch.fnmatch(name, pat):
        os.kill(os.getpid(), signal.SIGKILL)


def _replay_log(task: Task) -> dict:
    from ..apps.replay import ReplayConfig, replay

    cfg = ReplayConfig(**{**task.replay, "filters": tuple(task.replay["filters"])})
    if task.data is None:
        return replay(task.path, cfg, command="uavest evaluate")
    if task.sha256 and hashlib.sha256(task.data).hexdigest() != task.sha256:
        raise InputError(f"{task.name}: shipped content does not match its hash")
    with tempfile.TemporaryDirectory(prefix="uavest-eval-") as d:
        p = os.path.join(d, "log" + task.suffix)
        with open(p, "wb") as f:
            f.write(task.data)
        doc = replay(p, cfg, command="uavest evaluate")
    doc["log"] = task.name
    doc["run"]["source"] = task.name
    return doc


def _run_shard(task: Task) -> dict:
    from ..experiments.montecarlo import trial_rows
    from ..experiments.systems import build_system
    from ..scenarios import typed

    sc = typed(task.scenario)
    sysm = build_system(sc)
    rows = trial_rows(sysm, list(task.specs), task.seed, range(task.lo, task.hi))
    return {"scenario": sc.name, "seed": task.seed,
            "trials": [task.lo, task.hi], "dim": sysm.transition.space.dim, "rows": rows}


def run_task(task: Task) -> dict:
    """Run one task; returns {"result": ..., "elapsed_s", "cpu_s", "pid", "host"}. Raises
    on a bad input (the driver records the reason)."""
    import socket

    _crash_hook(task.name)
    t0, c0 = time.perf_counter(), time.thread_time()
    res = _replay_log(task) if task.kind == "log" else _run_shard(task)
    return {"result": res, "elapsed_s": time.perf_counter() - t0,
            "cpu_s": time.thread_time() - c0, "pid": os.getpid(), "host": socket.gethostname()}
