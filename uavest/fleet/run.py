"""The driver: skip what is stored, run the rest on a backend, write the report.

``OUT/results/<key>.json`` one per task (written as each finishes, atomically);
``OUT/summary.json``, ``OUT/rows.csv``, ``OUT/aggregate.csv``, ``OUT/report.html``
rewritten at the end from every stored result of this run's inputs.
"""

from __future__ import annotations

import datetime as _dt
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from .. import __version__
from .plan import Plan
from .store import ResultStore, write_atomic
from .summary import aggregate_csv, group_summary, rows_csv
from .worker import Task

__all__ = ["RunStats", "execute", "summarize", "write_outputs", "terminal_report"]


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


@dataclass
class RunStats:
    run_id: str
    backend: str
    tasks: int = 0
    skipped: int = 0
    computed: int = 0
    failed: int = 0
    wall_s: float = 0.0
    computed_keys: list[str] = field(default_factory=list)


def _reusable(doc: dict | None, retry_failed: bool) -> bool:
    """A stored result is reused when ok, or failed on its input (a deterministic error)
    unless ``retry_failed``; a task whose worker died is run again."""
    if not doc:
        return False
    if doc.get("status") == "ok":
        return True
    return doc.get("failure") == "error" and not retry_failed


def execute(plan: Plan, out: str | Path, backend, *, recompute: bool = False,
            retry_failed: bool = False, bar=None,
            on_done: Callable[[Task, dict], None] | None = None) -> tuple[dict, RunStats]:
    """Run the plan's tasks that have no reusable stored result; returns
    ({key: stored document}, stats). ``bar`` a tqdm-like bar (update, set_postfix_str)."""
    store = ResultStore(out)
    stats = RunStats(uuid.uuid4().hex[:12], backend.name)
    docs: dict[str, dict] = {}
    todo: list[Task] = []
    tasks = plan.tasks()
    stats.tasks = len(tasks)
    for t in tasks:
        d = None if recompute else store.load(t.key)
        if _reusable(d, retry_failed):
            docs[t.key] = d
            stats.skipped += 1
        else:
            todo.append(t)
    inputs_by_key = {i.key: i for i in plan.inputs if i.key}
    t0 = time.perf_counter()

    def postfix() -> None:
        if bar is not None:
            ok = stats.computed - stats.failed
            left = len(todo) - stats.computed
            bar.set_postfix_str(f"done {ok}, failed {stats.failed}, remaining {left}"
                                + (f", reused {stats.skipped}" if stats.skipped else ""))

    postfix()

    def done(t: Task, outcome: dict) -> None:
        inp = inputs_by_key[t.key]
        doc = {"key": t.key, "name": t.name, "kind": t.kind, "group": inp.group,
               "content_hash": inp.content_hash, "config_hash": plan.config_hashes[inp.group],
               "status": outcome["status"], "failure": outcome.get("failure"),
               "reason": outcome.get("reason"), "attempts": outcome.get("attempts"),
               "backend": backend.name, "run_id": stats.run_id, "finished_at": _now(),
               "version": __version__}
        if outcome["status"] == "ok":
            v = outcome["value"]
            doc.update(elapsed_s=v["elapsed_s"], cpu_s=v.get("cpu_s"), pid=v["pid"],
                       host=v["host"], result=v["result"])
        else:
            stats.failed += 1
        store.save(t.key, doc)
        docs[t.key] = doc
        stats.computed += 1
        stats.computed_keys.append(t.key)
        if bar is not None:
            postfix()  # before the update: a line printer prints the line on update
            bar.update(1)
        if on_done:
            on_done(t, doc)

    if bar is not None and hasattr(bar, "reset"):
        bar.reset(total=len(todo))
    if todo:
        backend.run(todo, done)
    stats.wall_s = time.perf_counter() - t0
    return docs, stats


def summarize(plan: Plan, docs: dict[str, dict], stats: RunStats | None = None,
              run: dict | None = None) -> dict:
    """The whole report as one strict-JSON-ready document."""
    groups: dict[str, list] = {}
    for i in plan.inputs:
        groups.setdefault(i.group, []).append(i)
    gs = {g: group_summary(g, inps, docs, plan.configs[g], plan.config_hashes[g])
          for g, inps in groups.items()}
    failures = [{"group": g, "input": r["input"], "reason": r["reason"],
                 "attempts": r.get("attempts")}
                for g, s in gs.items() for r in s["rows"] if r["status"] != "ok"]
    doc = {"run": {"version": __version__, "finished_at": _now(), **(run or {})},
           "counts": {"inputs": len(plan.inputs), "tasks": len(plan.tasks()),
                      "ok": sum(s["ok"] for s in gs.values()),
                      "failed": len(failures)},
           "groups": gs, "failures": failures}
    if stats is not None:
        doc["counts"].update(computed=stats.computed, reused=stats.skipped)
        doc["run"].update(run_id=stats.run_id, backend=stats.backend,
                          wall_s=stats.wall_s)
    return doc


def write_outputs(summary: dict, out: str | Path) -> dict[str, Path]:
    """summary.json, rows.csv, aggregate.csv and report.html under ``out``."""
    from ..sinks.jsonout import dumps
    from .html import render_html

    out = Path(out)
    paths = {"json": out / "summary.json", "rows_csv": out / "rows.csv",
             "aggregate_csv": out / "aggregate.csv", "html": out / "report.html"}
    write_atomic(paths["json"], dumps(summary) + "\n")
    write_atomic(paths["rows_csv"], rows_csv(summary["groups"]))
    write_atomic(paths["aggregate_csv"], aggregate_csv(summary["groups"]))
    write_atomic(paths["html"], render_html(summary, out))
    return paths


LOG_COLUMNS = ["logs", "att_rmse_mean", "att_rmse_median", "att_rmse_worst",
               "roll_rmse_mean", "pitch_rmse_mean", "yaw_rmse_mean", "nees_mean_mean",
               "vel_rmse_ms_mean", "hpos_rmse_m_mean", "resets", "wins"]
MC_COLUMNS = ["trials", "rmse_mean", "rmse_median", "rmse_worst", "nees_mean",
              "diverged_fraction", "resets", "wins"]


def terminal_report(summary: dict) -> str:
    """The tables printed at the end of ``uavest evaluate``."""
    from ..sinks.table import table

    lines = []
    for g, s in summary["groups"].items():
        if g == "logs":
            head = f"{s['ok']} log(s) evaluated, {s['failed']} failed"
            if s["duplicates"]:
                head += f" ({s['duplicates']} identical copies counted once)"
            cols = LOG_COLUMNS
        else:
            head = (f"{g[3:]}: {s['trials_evaluated']} of {s['trials_requested']} trials "
                    f"({s['ok']} shard(s) ok, {s['failed']} failed)")
            cols = MC_COLUMNS
        lines += [head, f"wins: {s['wins_metric']}"]
        lines.append(table(s["aggregate"], cols) if s["aggregate"] else "(no results)")
        lines.append("")
    if summary["failures"]:
        lines.append("failed:")
        lines += [f"  {f['input']}: {f['reason']}" for f in summary["failures"]]
    c = summary["counts"]
    if "computed" in c:
        lines.append(f"{c['tasks']} task(s): {c['computed']} computed, {c['reused']} reused "
                     "from earlier runs")
    return "\n".join(lines).rstrip()
