"""Fleet evaluation: replay many flight logs, or shards of a Monte Carlo study, on a
process pool or a Dask cluster, with stored per-input results (resumable) and one report.

API::

    from uavest.fleet import evaluate
    summary = evaluate(["logs/", "flights/*.ulg"], out="eval", workers=2)
    summary = evaluate(["ungm"], out="eval-mc", trials=400, shard_size=25, workers=2)
    summary = evaluate(inputs, out="eval", scheduler="tcp://host:8786")   # Dask

Pieces: :func:`~uavest.fleet.plan.plan_logs` / :func:`~uavest.fleet.plan.plan_trials`
(inputs -> keyed tasks), :func:`~uavest.fleet.backends.make_backend`,
:func:`~uavest.fleet.run.execute` (skip stored results, run the rest),
:func:`~uavest.fleet.run.summarize` and :func:`~uavest.fleet.run.write_outputs`.
See docs/evaluate.md.
"""

from __future__ import annotations

from pathlib import Path

from .backends import DaskBackend, PoolBackend, SerialBackend, make_backend
from .plan import Plan, discover_logs, plan_logs, plan_trials
from .run import RunStats, execute, summarize, terminal_report, write_outputs
from .worker import Task, run_task

__all__ = ["DaskBackend", "Plan", "PoolBackend", "RunStats", "SerialBackend", "Task",
           "build_plan", "discover_logs", "evaluate", "execute", "make_backend",
           "plan_logs", "plan_trials", "run_task", "summarize", "terminal_report",
           "write_outputs"]


def build_plan(inputs: list[str], *, filters=None, replay: dict | None = None,
               trials: int | None = None, seed: int = 0, shard_size: int = 25,
               sets: list[str] = (), steps: int | None = None) -> Plan:
    """Logs (files, folders, globs) or, with ``trials``, scenario names (one group each)."""
    if trials is None:
        return plan_logs(discover_logs(inputs), filters, {"seed": seed, **(replay or {})})
    plan = Plan()
    for name in dict.fromkeys(inputs):
        plan.extend(plan_trials(name, trials, seed, shard_size, filters, sets, steps))
    return plan


def evaluate(inputs: list[str], out: str | Path, *, workers: int | None = None,
             scheduler: str | None = None, backend=None, bar=None, recompute: bool = False,
             retry_failed: bool = False, **plan_options) -> dict:
    """Plan, run what is not stored yet, write the report under ``out``; returns the
    summary document (also ``out/summary.json``). ``backend`` overrides
    ``workers``/``scheduler`` (e.g. ``DaskBackend(Client(cluster))``)."""
    plan = build_plan(inputs, **plan_options)
    own = backend is None
    backend = backend or make_backend(workers, scheduler)
    detail = backend.describe()
    try:
        docs, stats = execute(plan, out, backend, recompute=recompute,
                              retry_failed=retry_failed, bar=bar)
    finally:
        if own:
            backend.close()
    summary = summarize(plan, docs, stats, {"backend_detail": detail})
    write_outputs(summary, out)
    return summary
