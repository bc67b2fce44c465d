"""Scenario files: TOML documents in ``scenarios/`` with a ``kind`` key.

``load_scenario("ungm")`` finds ``scenarios/ungm.toml`` (next to the package in a source
checkout, or in ./scenarios); a path to a .toml file works too. ``--set KEY=VALUE``
overrides (dotted keys for tables, values parsed as TOML literals, bare words as
strings) are applied with :func:`apply_sets`. Built-in defaults for ``ungm``,
``nonlinear2d`` and ``linear_cv`` exist so that the benchmark runs even without the files.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

BUILTIN: dict[str, dict] = {
    "ungm": {
        "name": "ungm",
        "kind": "ungm",
        "description": "Univariate nonstationary growth model (Gordon, Salmond and Smith "
        "1993), bimodal posterior",
        "runs": 200,
        "steps": 100,
        "divergence_rmse": 20.0,
        "model": {"a": 0.5, "b": 25.0, "c": 20.0, "alpha": 8.0, "beta": 1.2, "Q": 10.0,
                  "R": 1.0},
        "prior": {"truth_mean": [0.0], "truth_var": [1.0], "filter_mean": [0.0],
                  "filter_var": [1.0]},
        "filters": ["ekf", "ukf", "srukf", "enkf", "etkf", "hybrid", "hybrid_literal", "pf"],
    },
    "nonlinear2d": {
        "name": "nonlinear2d",
        "kind": "nonlinear2d",
        "description": "2-D strongly nonlinear system (ours, documented in docs/filters.md)",
        "runs": 200,
        "steps": 100,
        "divergence_rmse": 10.0,
        "model": {"nl": 1.0, "rho": 0.9, "th": 0.3, "g": 10.0, "alpha": 4.0, "beta": 1.2,
                  "c": 10.0, "Q": [1.0, 1.0], "R": [1.0, 1.0]},
        "prior": {"truth_mean": [0.0, 0.0], "truth_var": [1.0, 1.0],
                  "filter_mean": [0.0, 0.0], "filter_var": [1.0, 1.0]},
        "filters": ["ekf", "ukf", "srukf", "enkf", "etkf", "hybrid", "hybrid_literal", "pf"],
    },
    "linear_cv": {
        "name": "linear_cv",
        "kind": "linear_cv",
        "description": "1-D constant velocity, position measured (linear-Gaussian: KF optimal)",
        "runs": 200,
        "steps": 100,
        "divergence_rmse": 50.0,
        "model": {"dt": 1.0, "q": 0.1, "R": 4.0},
        "prior": {"truth_mean": [0.0, 1.0], "truth_var": [10.0, 1.0],
                  "filter_mean": [0.0, 1.0], "filter_var": [10.0, 1.0]},
        "filters": ["kf", "ekf", "ukf", "srukf", "enkf", "etkf", "hybrid", "pf"],
    },
}


class ScenarioError(ValueError):
    """A scenario name, file or override could not be used."""


def scenario_dirs() -> list[Path]:
    here = Path(__file__).resolve().parent
    return [Path.cwd() / "scenarios", here]


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
    names = set(BUILTIN)
    for d in scenario_dirs():
        if d.is_dir():
            names.update(f.stem for f in d.glob("*.toml"))
    return sorted(names)


def load_scenario(name_or_path: str, sets: list[str] | tuple[str, ...] = ()) -> dict:
    """Scenario dict (with ``name`` and ``kind``) from a name or a .toml path, with
    ``KEY=VALUE`` overrides applied."""
    f = find_scenario(name_or_path)
    if f is not None:
        try:
            with open(f, "rb") as fh:
                sc = tomllib.load(fh)
        except tomllib.TOMLDecodeError as e:
            raise ScenarioError(f"{f}: invalid TOML: {e}") from None
        sc.setdefault("name", f.stem)
        sc["source"] = str(f)
    elif name_or_path in BUILTIN:
        sc = copy.deepcopy(BUILTIN[name_or_path])
        sc["source"] = "built-in"
    else:
        raise ScenarioError(
            f"unknown scenario {name_or_path!r}; known: {', '.join(list_scenarios())}"
        )
    if "kind" not in sc:
        raise ScenarioError(f"scenario {sc.get('name')!r} has no 'kind' key")
    return apply_sets(sc, sets)


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
        node = sc
        for p in parts[:-1]:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise ScenarioError(f"--set {item!r}: {p!r} is not a table")
            node = nxt
        node[parts[-1]] = parse_value(val.strip())
    return sc
