"""From command-line inputs to tasks: log discovery, content hashes, configuration hashes.

A result is keyed by ``<content hash>-<configuration hash>``:

- content: sha256 of a log's bytes; for a Monte Carlo shard, sha256 of the scenario's
  content (its parameters, not its file path), the trial range and the seed;
- configuration: sha256 of the resolved filter specs (``FilterSpec.as_dict()``: every
  parameter, preset values included), the replay options, and the package version.

So renaming or moving a log keeps its result, identical copies are evaluated once, and
changing a filter parameter, a replay option or the version recomputes.
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .. import __version__
from ..errors import InputError
from .worker import Task

__all__ = ["LOG_SUFFIXES", "Input", "Plan", "discover_logs", "file_sha256", "plan_logs",
           "plan_trials"]

LOG_SUFFIXES = (".tlog", ".bin", ".ulg")
_GLOB_CHARS = set("*?[")


def canonical(o) -> str:
    """Canonical JSON (sorted keys, no spaces) for hashing."""
    return json.dumps(o, sort_keys=True, separators=(",", ":"), default=str)


def sha256_text(s: str) -> str:
    return hashlib.sha256(s.encode()).hexdigest()


def file_sha256(path: str | Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while b := f.read(chunk):
            h.update(b)
    return h.hexdigest()


def _is_log(p: Path) -> bool:
    return p.is_file() and p.suffix.lower() in LOG_SUFFIXES


def discover_logs(inputs: list[str]) -> list[Path]:
    """Log files named by ``inputs``: files (any name; the format is read from the
    content), folders (searched recursively for .tlog/.bin/.ulg, any case) and globs
    (``**`` recursive). Sorted within each input, first occurrence kept. Raises
    ValueError for an input that names nothing."""
    out: list[Path] = []
    seen: set[str] = set()
    for text in inputs:
        p = Path(text)
        if p.is_file():
            found = [p]
        elif p.is_dir():
            found = sorted(q for q in p.rglob("*") if _is_log(q))
            if not found:
                raise InputError(f"{text}: no .tlog, .bin or .ulg files in this folder")
        elif _GLOB_CHARS & set(text):
            found = []
            for m in sorted(glob.glob(text, recursive=True)):
                q = Path(m)
                if q.is_dir():
                    found += sorted(r for r in q.rglob("*") if _is_log(r))
                elif q.is_file():
                    found.append(q)
            if not found:
                raise InputError(f"{text}: the pattern matches no log files")
        else:
            raise InputError(f"{text}: no such file, folder or scenario (Monte Carlo "
                             "inputs need --trials N)")
        for q in found:
            k = os.path.abspath(q)
            if k not in seen:
                seen.add(k)
                out.append(q)
    return out


@dataclass
class Input:
    """One input as the user named it: a log file or one shard of a study. ``task`` is
    None when the input failed before it could be run (``error`` says why)."""

    name: str
    kind: str  # "log" | "shard"
    group: str  # "logs" or "mc:<scenario>"
    key: str | None
    content_hash: str | None
    task: Task | None = None
    error: str | None = None
    duplicate_of: str | None = None  # an earlier input with the same content (run once)


@dataclass
class Plan:
    """Inputs, their tasks (one per distinct key) and each group's configuration."""

    inputs: list[Input] = field(default_factory=list)
    configs: dict[str, dict] = field(default_factory=dict)  # group -> resolved config
    config_hashes: dict[str, str] = field(default_factory=dict)

    def tasks(self) -> list[Task]:
        seen, out = set(), []
        for i in self.inputs:
            if i.task is not None and i.key not in seen:
                seen.add(i.key)
                out.append(i.task)
        return out

    def extend(self, other: Plan) -> None:
        self.inputs += other.inputs
        self.configs.update(other.configs)
        self.config_hashes.update(other.config_hashes)


def _key(content: str, config: str) -> str:
    return f"{content[:24]}-{config[:16]}"


def plan_logs(paths: list[Path], filters: tuple[str, ...] | list[str] | None = None,
              replay: dict | None = None) -> Plan:
    """Tasks replaying each log with ``filters`` (attitude preset; default the replay
    defaults) and ReplayConfig fields ``replay`` (start, end, rate_hz, seed, ...)."""
    from ..apps.replay import DEFAULT_FILTERS, ReplayConfig
    from ..presets import resolve_list

    filters = tuple(filters or DEFAULT_FILTERS)
    # the model as uavest replay chooses it (per log: navigation with a GNSS fix stream)
    rcfg = ReplayConfig(filters=filters, **{"model": "auto", **(replay or {})})
    specs = resolve_list(list(filters), "attitude", dim=6)
    # a log with a GNSS fix stream runs them in the navigation preset
    nav_specs = resolve_list(list(filters), "nav")
    opts = {k: v for k, v in asdict(rcfg).items() if k != "filters"}
    config = {"kind": "log", "filters": [s.as_dict() for s in specs],
              "filters_nav": [s.as_dict() for s in nav_specs], "replay": opts,
              "version": __version__}
    ch = sha256_text(canonical(config))
    plan = Plan(configs={"logs": config}, config_hashes={"logs": ch})
    task_replay = {**opts, "filters": list(filters)}
    first: dict[str, str] = {}
    for p in paths:
        name = str(p)
        try:
            h = file_sha256(p)
        except OSError as e:
            plan.inputs.append(Input(name, "log", "logs", None, None,
                                     error=f"unreadable: {e.strerror or e}"))
            continue
        key = _key(h, ch)
        plan.inputs.append(Input(name, "log", "logs", key, h, Task(
            key, "log", name, path=os.path.abspath(p), sha256=h, suffix=p.suffix.lower(),
            replay=task_replay), duplicate_of=first.get(key)))
        first.setdefault(key, name)
    return plan


def scenario_content(sc: dict) -> dict:
    """The scenario's parameters without where it was read from."""
    return {k: v for k, v in sc.items() if k != "source"}


def plan_trials(scenario: str, trials: int, seed: int = 0, shard_size: int = 25,
                filters: tuple[str, ...] | list[str] | None = None, sets: list[str] = (),
                steps: int | None = None) -> Plan:
    """Shards of ``shard_size`` trials of a scenario (bench preset; default its filter
    list). Trial r is seeded from (seed, r, stream), so the shards' rows together are the
    rows of one ``uavest bench`` run."""
    from ..experiments.systems import build_system
    from ..presets import resolve_list
    from ..scenarios import load_scenario, typed

    if trials < 1:
        raise InputError(f"--trials must be >= 1, got {trials}")
    if shard_size < 1:
        raise InputError(f"--shard-size must be >= 1, got {shard_size}")
    raw = load_scenario(scenario, list(sets))  # the dict: hashed and shipped to workers
    sc = typed(raw)
    if sc.kind == "radar":
        raise InputError(f"scenario {sc.name!r} is a radar scenario; evaluate runs the "
                         "Monte Carlo systems (ungm, nonlinear2d, linear_cv)")
    if steps is not None:
        if steps < 1:
            raise InputError(f"--steps must be >= 1, got {steps}")
        raw["steps"] = steps
        sc = typed(raw)
    sysm = build_system(sc)
    filters = list(filters or sc.filters or ["ekf", "ukf", "hybrid"])
    specs = resolve_list(filters, "bench", dim=sysm.transition.space.dim)
    group = f"mc:{sc.name}"
    config = {"kind": "shard", "filters": [s.as_dict() for s in specs], "version": __version__}
    ch = sha256_text(canonical(config))
    content = scenario_content(raw)
    plan = Plan(configs={group: {**config, "scenario": content, "trials": trials,
                                 "seed": seed, "shard_size": shard_size}},
                config_hashes={group: ch})
    for lo in range(0, trials, shard_size):
        hi = min(lo + shard_size, trials)
        h = sha256_text(canonical({"scenario": content, "trials": [lo, hi], "seed": seed}))
        key = _key(h, ch)
        name = f"{sc.name}[{lo}:{hi}]"
        plan.inputs.append(Input(name, "shard", group, key, h, Task(
            key, "shard", name, scenario=raw, specs=tuple(filters), seed=seed, lo=lo, hi=hi)))
    return plan
