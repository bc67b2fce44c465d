"""Scenario files: TOML documents in ``scenarios/`` with a ``kind`` key.

``load_scenario("ungm")`` finds ``scenarios/ungm.toml`` (next to the package in a source
checkout, or in ./scenarios); a path to a .toml file works too. ``--set KEY=VALUE``
overrides (dotted keys for tables, values parsed as TOML literals, bare words as
strings) are applied with :func:`apply_sets`; a key the scenario lacks (and not in
:data:`OPTIONAL_KEYS`) is a ScenarioError naming the close matches. Built-in defaults for ``ungm``,
``nonlinear2d`` and ``linear_cv`` exist so that the benchmark runs even without the files.
"""

from __future__ import annotations

import copy
import difflib
import tomllib
from pathlib import Path

from ..errors import InputError

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


class ScenarioError(InputError):
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
    sc = apply_sets(sc, sets)
    try:
        validate_scenario(sc)
    except ScenarioError as e:
        if sets:
            raise ScenarioError(f"{e} (after --set {' '.join(sets)})") from None
        raise
    return sc


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
    standard deviations >= 0, and for radar scenarios the checks of
    :func:`uavest.tracking.scenario.check_radar`."""
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
    if sc.get("kind") == "radar":
        from ..tracking.scenario import check_radar

        check_radar(sc, where, fail)


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


#: Keys the code reads with a default, so a scenario file may leave them out and ``--set``
#: may still add them (dotted, from the top of the scenario). Everything else ``--set``
#: names must already be in the scenario (TOML merged with its built-in defaults):
#: a typo must not be silently ignored.
OPTIONAL_KEYS: frozenset[str] = frozenset({
    "ndim", "dt", "runs", "steps", "divergence_rmse", "filters", "mode", "metrics",
    "motion.truth_q", "motion.q", "motion.q_omega", "motion.model",
    # uavest.tracking.tracker.TrackerConfig fields (a [tracker] table overrides them)
    "tracker.gate_prob", "tracker.confirm_m", "tracker.confirm_n", "tracker.delete_misses",
    "tracker.init_vel_std", "tracker.init_omega_std", "tracker.max_pos_std",
    "tracker.association", "tracker.pd", "tracker.clutter_density", "tracker.jpda_max_cluster",
    "radar.pd", "radar.clutter_rate", "radar.enabled", "radar.rate_hz",
    "adsb.enabled", "mag.declination_deg",
    "targets", "source", "prior", "kind", "name", "uav", "model", "missed",
    "prior.mean", "prior.std", "prior.truth_mean", "prior.truth_var", "prior.filter_mean",
    "prior.filter_var", "prior.omega_std",
})

#: Sections the code reads with defaults (the simulator's and the radar's): when a scenario
#: has no such table, any key under it may be set (its reader checks the values); when it
#: has one, its keys are checked like the rest.
OPTIONAL_SECTIONS: frozenset[str] = frozenset({
    "tracker", "vehicle", "time", "origin", "mavlink", "mag", "imu", "gps", "baro", "ahrs",
    "adsb", "radar", "motion", "prior", "uav",
})


def _known_keys(sc: dict, prefix: str = "") -> set[str]:
    out: set[str] = set()
    for k, v in sc.items():
        key = f"{prefix}{k}"
        out.add(key)
        if isinstance(v, dict):
            out |= _known_keys(v, key + ".")
    return out


def _check_known(sc: dict, parts: list[str]) -> None:
    """Raise :class:`ScenarioError` if the dotted key is neither in ``sc`` nor optional,
    naming the close matches (or the top-level sections)."""
    key = ".".join(parts)
    known = _known_keys(sc) | OPTIONAL_KEYS
    if key in known:
        return
    if len(parts) > 1 and parts[0] in OPTIONAL_SECTIONS and not isinstance(sc.get(parts[0]),
                                                                           dict):
        return
    cands = sorted(known)
    close = difflib.get_close_matches(key, cands, n=3, cutoff=0.6)
    # a bare leaf name ("clutter_rate") matches its dotted form ("radar.clutter_rate")
    close += [c for c in cands if c.rsplit(".", 1)[-1] == parts[-1] and c not in close]
    if close:
        hint = f"did you mean {', '.join(close[:3])}?"
    else:
        secs = sorted(k for k, v in sc.items() if isinstance(v, dict))
        hint = f"known sections: {', '.join(secs) or '(none)'}"
    raise ScenarioError(f"unknown scenario key {key!r} ({hint})")
