"""Scenario files: TOML documents in ``scenarios/`` with a ``kind`` key.

``load_scenario("ungm")`` finds ``scenarios/ungm.toml`` (next to the package in a source
checkout, or in ./scenarios); a path to a .toml file works too. The TOML files are the only
source of the built-in scenarios. ``--set KEY=VALUE`` overrides (dotted keys for tables,
values parsed as TOML literals, bare words as strings) are applied with :func:`apply_sets`;
a key the schema of the scenario's kind (:mod:`uavest.scenarios.schema`) does not declare
is a ScenarioError naming the close matches. Every value is checked once, here, against the
schema's declared types, ranges and units (:func:`load_typed` returns the typed scenario).
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import asdict
from pathlib import Path
from typing import Any

from .schema import ScenarioError, close_keys, declared, known_keys, parse, schema_for

__all__ = ["ScenarioError", "load_scenario", "load_typed", "list_scenarios",
           "find_scenario", "apply_sets", "parse_value", "validate_scenario", "typed",
           "resolved"]


def scenario_dirs() -> list[Path]:
    """Where scenarios are looked up by name: ``./scenarios`` (the user's own, first), then
    the package's; each once, resolved (the repository's top-level ``scenarios`` is a link
    to the package's)."""
    here = Path(__file__).resolve().parent
    return list(dict.fromkeys([(Path.cwd() / "scenarios").resolve(), here]))


def find_scenario(name_or_path: str) -> Path | None:
    p = Path(name_or_path)
    if p.suffix == ".toml":
        if not p.is_file():
            raise ScenarioError(f"scenario file {p} not found")
        return p
    for d in scenario_dirs():
        f = d / f"{name_or_path}.toml"
        if f.is_file():
            return f
    return None


def list_scenarios() -> list[str]:
    names: set[str] = set()
    for d in scenario_dirs():
        if d.is_dir():
            names.update(f.stem for f in d.glob("*.toml"))
    return sorted(names)


def load_scenario(name_or_path: str, sets: list[str] | tuple[str, ...] = ()) -> dict:
    """Scenario dict (with ``name`` and ``kind``) from a name or a .toml path, with
    ``KEY=VALUE`` overrides applied, every value checked (:func:`load_typed` for the typed
    scenario)."""
    return _load(name_or_path, sets)[0]


def _load(name_or_path: str, sets: list[str] | tuple[str, ...]) -> tuple[dict, Any]:
    """(scenario dict, typed scenario), parsed and checked once."""
    f = find_scenario(name_or_path)
    if f is not None:
        try:
            with open(f, "rb") as fh:
                sc = tomllib.load(fh)
        except tomllib.TOMLDecodeError as e:
            raise ScenarioError(f"{f}: invalid TOML: {e}") from None
        sc.setdefault("name", f.stem)
        sc["source"] = str(f)
    else:
        raise ScenarioError(
            f"unknown scenario {name_or_path!r}; known: {', '.join(list_scenarios())}"
        )
    if "kind" not in sc:
        raise ScenarioError(f"scenario {sc.get('name')!r} has no 'kind' key")
    schema_for(sc["kind"])  # unknown kind: a ScenarioError before any --set
    sc = apply_sets(sc, sets)
    try:
        validate_scenario(sc)
        scn = parse(sc)
        _check_kind(scn, sc)
    except ScenarioError as e:
        if sets:
            raise ScenarioError(f"{e} (after --set {' '.join(sets)})") from None
        raise
    return sc, scn


def load_typed(name_or_path: str, sets: list[str] | tuple[str, ...] = ()) -> Any:
    """The typed scenario (a frozen dataclass of :mod:`uavest.scenarios.schema`, every
    default filled in) of :func:`load_scenario`."""
    return _load(name_or_path, sets)[1]


def typed(sc: dict | Any) -> Any:
    """The typed scenario of a scenario dict (a typed scenario is returned as it is)."""
    return parse(sc) if isinstance(sc, dict) else sc


def resolved(sc: dict | Any) -> dict:
    """The resolved scenario (every declared field, defaults filled in) as a plain dict,
    for a result's :class:`~uavest.engine.records.RunInfo` ``scenario``."""
    if isinstance(sc, dict) and "kind" not in sc:  # a hand-made scenario (tests)
        return copy.deepcopy(sc)
    typed = parse(sc) if isinstance(sc, dict) else sc
    return _finite(asdict(typed))


def _finite(v: Any) -> Any:
    """JSON-safe: tuples as lists, non-finite numbers (no limit, 'until the end') as None."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite(x) for x in v]
    if isinstance(v, float) and not v == v or v in (float("inf"), -float("inf")):
        return None
    return v


#: Keys whose numbers must be >= 0 (noise levels, variances, standard deviations).
_NONNEG = ("Q", "R", "q", "q_omega", "truth_q", "sigma_range", "sigma_az_deg", "sigma_el_deg",
           "sigma_rr", "truth_var", "filter_var", "std", "omega_std", "init_vel_std",
           "max_pos_std", "r_max", "rr_max", "gospa_c")
MAX_RUNS = 1_000_000  # Monte Carlo runs a scenario may ask for
MAX_STEPS = 1_000_000


def validate_scenario(sc: dict) -> None:
    """Types and ranges of a scenario's values, with a one-line :class:`ScenarioError`
    naming the file, the key, the value and what is allowed: every number finite,
    ``runs``/``steps`` integers >= 1, ``filters`` a list of spec strings, noise levels and
    standard deviations >= 0 (the schema's :func:`~uavest.scenarios.schema.parse` then
    checks each declared field, and :func:`_check_kind` the typed scenario)."""
    where = f"{sc.get('source', sc.get('name'))}: " if sc.get("source") else ""

    def fail(msg: str):
        raise ScenarioError(msg)

    def walk(node, path):
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{path}.{k}" if path else str(k))
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{path}[{i}]")
        elif isinstance(node, float) and (node != node or (
                node in (float("inf"), -float("inf")) and "turns" not in path)):
            # (a turn's end step may be inf: "until the end")
            fail(f"{where}{path} = {node!r}: must be a finite number")
        elif isinstance(node, int | float) and not isinstance(node, bool):
            leaf = path.rsplit(".", 1)[-1].split("[")[0]
            if leaf in _NONNEG and node < 0:
                fail(f"{where}{path} = {node!r}: must be >= 0")

    walk(sc, "")
    for key, top in (("runs", MAX_RUNS), ("steps", MAX_STEPS)):
        if key in sc:
            v = sc[key]
            if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= top:
                fail(f"{where}{key} = {v!r}: must be an integer from 1 to {top:,}")
    if "filters" in sc:
        f = sc["filters"]
        if isinstance(f, str):
            fail(f"{where}filters = {f!r}: must be a list of filter specs, e.g. "
                 f"filters = [{f!r}]")
        if not isinstance(f, list) or not f or not all(isinstance(x, str) and x.strip()
                                                        for x in f):
            fail(f"{where}filters = {f!r}: must be a non-empty list of filter spec strings")
    if "divergence_rmse" in sc:
        d = sc["divergence_rmse"]
        if not isinstance(d, int | float) or isinstance(d, bool) or d <= 0:
            fail(f"{where}divergence_rmse = {d!r}: must be a number > 0")


def _check_kind(scn: Any, sc: dict) -> None:
    """The checks of a typed scenario across its fields (the schema checks each field
    alone): a radar scenario's clutter within what a run can hold
    (:data:`uavest.tracking.scenario.MAX_CLUTTER_PER_SCAN`) and prior lengths matching
    its dimension."""
    if scn.kind != "radar":
        return
    from ..tracking.scenario import MAX_CLUTTER_PER_SCAN

    where = f"{sc['source']}: " if sc.get("source") else ""
    lam = scn.radar.clutter_rate
    if lam > MAX_CLUTTER_PER_SCAN:
        gb = lam * 8 * 8 / 1e9
        raise ScenarioError(
            f"{where}radar.clutter_rate = {lam:g}: about {gb:.2g} GB of detections per scan "
            f"before association; at most {MAX_CLUTTER_PER_SCAN:g} per scan is supported")
    n = 2 * scn.ndim
    for key in ("mean", "std"):
        v = getattr(scn.prior, key)
        if v and len(v) not in (n, n + 1):
            raise ScenarioError(f"{where}prior.{key} = {list(v)!r}: must be a list of {n} "
                                f"numbers (the state [position, velocity] in {scn.ndim}-D)")


def parse_value(v: str):
    """A TOML literal (number, bool, array, quoted string) or else the bare string."""
    try:
        return tomllib.loads(f"v = {v}")["v"]
    except tomllib.TOMLDecodeError:
        return v


def apply_sets(sc: dict, sets) -> dict:
    """Apply ``KEY=VALUE`` overrides (dotted keys walk into tables; tables are created)."""
    sc = copy.deepcopy(sc)
    for item in sets or ():
        if "=" not in item:
            raise ScenarioError(f"--set {item!r}: expected KEY=VALUE")
        key, val = item.split("=", 1)
        parts = [p for p in key.strip().split(".") if p]
        if not parts:
            raise ScenarioError(f"--set {item!r}: empty key")
        _check_known(sc, parts)
        node = sc
        for p in parts[:-1]:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise ScenarioError(f"--set {item!r}: {p!r} is not a table")
            node = nxt
        node[parts[-1]] = parse_value(val.strip())
    return sc


def _known_keys(sc: dict, prefix: str = "") -> set[str]:
    out: set[str] = set()
    for k, v in sc.items():
        key = f"{prefix}{k}"
        out.add(key)
        if isinstance(v, dict):
            out |= _known_keys(v, key + ".")
    return out


def _check_known(sc: dict, parts: list[str]) -> None:
    """Raise :class:`ScenarioError` if the dotted key is not declared by the schema of the
    scenario's kind, naming the close matches (or the top-level sections)."""
    key = ".".join(parts)
    cls = schema_for(sc.get("kind", ""))
    known = known_keys(cls)
    if key in known:
        return
    # below a free-form value (e.g. mavlink.rates.NAME): its reader checks it
    for i in range(1, len(parts)):
        node: Any = cls
        for p in parts[:i - 1]:
            node = declared(node)[p]["table"]
        m = declared(node).get(parts[i - 1]) if isinstance(node, type) else None
        if m is None:
            break
        if m["kind"] == "any":
            return
        if m["kind"] != "table":
            break
    close = close_keys(key, sorted(known))
    if close:
        hint = f"did you mean {', '.join(close)}?"
    else:
        secs = sorted(k for k, m in declared(cls).items() if m["kind"] == "table")
        hint = f"known sections: {', '.join(secs) or '(none)'}"
    raise ScenarioError(f"unknown scenario key {key!r} ({hint})")
