"""The typed scenario schema (uavest/scenarios/schema.py): every built-in TOML loads and
is covered by the declared fields; a wrong type, an out-of-range value and an unknown key
each give a one-line ScenarioError naming the key (and its range and unit, or the close
matches); ``--set`` round-trips through the schema."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest

from uavest.errors import InputError
from uavest.scenarios import ScenarioError, list_scenarios, load_scenario, load_typed, resolved
from uavest.scenarios.schema import KINDS, declared, known_keys

TOMLS = sorted((Path(__file__).resolve().parents[2] / "uavest" / "scenarios").glob("*.toml"))


def _keys(d: dict, prefix: str = "") -> set[str]:
    out = set()
    for k, v in d.items():
        out.add(prefix + k)
        if isinstance(v, dict):
            out |= _keys(v, f"{prefix}{k}.")
    return out


def test_there_are_builtin_scenarios_of_every_kind():
    kinds = {tomllib.loads(f.read_text())["kind"] for f in TOMLS}
    assert kinds == set(KINDS)
    assert set(list_scenarios()) >= {f.stem for f in TOMLS}


@pytest.mark.parametrize("f", TOMLS, ids=lambda f: f.stem)
def test_every_builtin_toml_loads_typed(f):
    typed = load_typed(f.stem)
    assert dataclasses.is_dataclass(typed) and type(typed) is KINDS[typed.kind]
    with pytest.raises(dataclasses.FrozenInstanceError):
        typed.kind = "x"  # type: ignore[misc]
    # the declared fields cover every key of the file (arrays of tables: their members)
    raw = tomllib.loads(f.read_text())
    known = set(known_keys(type(typed)))
    assert _keys(raw) <= known | {"source"}, _keys(raw) - known
    for name, m in declared(type(typed)).items():
        if m["kind"] == "tables":
            members = set(declared(m["table"]))
            for tab in raw.get(name, []):
                assert set(tab) <= members, set(tab) - members
    # values survive typing (lists become tuples)
    if "steps" in raw:
        assert typed.steps == raw["steps"]


def test_defaults_are_declared_once_and_filled_in():
    typed = load_typed("radar_crossing")
    assert typed.tracker.gate_prob == 0.999 and typed.motion.truth_q is None
    assert typed.ndim == 2 and typed.radar.sigma_az_deg == 5.0
    d = resolved(load_scenario("radar_crossing"))
    assert d["tracker"]["confirm_m"] == 4 and d["radar"]["pd"] == 1.0


@pytest.mark.parametrize("sets, key, words", [
    (["radar.pd=\"high\""], "radar.pd", ["(0, 1]"]),          # wrong type
    (["radar.pd=1.5"], "radar.pd", ["(0, 1]"]),                # out of range
    (["radar.sigma_range=-3"], "radar.sigma_range", ["m"]),    # out of range, unit
    (["ndim=4"], "ndim", ["must be"]),                          # not a choice
    (["steps=2.5"], "steps", ["integer"]),                     # wrong type
    (["tracker.confirm_m=0"], "tracker.confirm_m", [">= 1"]),
])
def test_bad_value_is_a_one_line_error_naming_the_key_and_range(sets, key, words):
    with pytest.raises(ScenarioError) as e:
        load_scenario("radar_crossing", sets)
    msg = str(e.value)
    assert isinstance(e.value, InputError)
    assert "\n" not in msg and key in msg, msg
    for w in words:
        assert w in msg, msg


def test_sim_value_checked_with_unit():
    with pytest.raises(ScenarioError, match=r"gps\.rate_hz = -1.*> 0 \(Hz\)"):
        load_scenario("sim_default", ["gps.rate_hz=-1"])
    with pytest.raises(ScenarioError, match="imu.gyro_bias_std"):
        load_scenario("sim_default", ["imu.gyro_bias_std=true"])


def test_unknown_key_in_a_file_names_close_matches(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('kind = "linear_cv"\n[model]\ndt = 1.0\nqq = 0.1\nR = 4.0\n')
    with pytest.raises(ScenarioError) as e:
        load_scenario(str(f))
    msg = str(e.value)
    assert "\n" not in msg and "model.qq" in msg and "model.q" in msg


def test_unknown_set_key_names_close_matches():
    with pytest.raises(ScenarioError, match="did you mean .*gps.sigma_h"):
        load_scenario("sim_default", ["gps.sigma_hh=1"])
    with pytest.raises(ScenarioError, match="unknown scenario key 'targets.start'"):
        load_scenario("radar_multitarget", ["targets.start=[1]"])
    # the same key in another case comes first (UNGM's noise is model.Q)
    with pytest.raises(ScenarioError, match=r"'model.q' \(did you mean model.Q, "):
        load_scenario("ungm", ["model.q=1"])


def test_unknown_kind_is_a_scenario_error(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('kind = "nope"\n')
    with pytest.raises(ScenarioError, match="unknown scenario kind 'nope'"):
        load_scenario(str(f))


@pytest.mark.parametrize("name, key, value, get", [
    ("radar_crossing", "radar.clutter_rate", "3.0", lambda t: t.radar.clutter_rate),
    ("radar_crossing", "motion.truth_q", "0.2", lambda t: t.motion.truth_q),
    ("radar_crossing", "tracker.association", "jpda", lambda t: t.tracker.association),
    ("ungm", "model.Q", "5.0", lambda t: t.model.Q),
    ("linear_cv", "runs", "7", lambda t: t.runs),
    ("sim_default", "adsb.enabled", "false", lambda t: t.adsb.enabled),
    ("sim_default", "mavlink.rates.HEARTBEAT", "2.0", lambda t: t.mavlink.rates["HEARTBEAT"]),
])
def test_set_round_trips(name, key, value, get):
    from uavest.scenarios import parse_value

    typed = load_typed(name, [f"{key}={value}"])
    assert get(typed) == parse_value(value)
    # the resolved scenario loads back to the same typed scenario
    again = load_typed(name, [f"{key}={value}"])
    assert again == typed


def test_results_record_the_resolved_scenario(tmp_path, capsys):
    import json

    from uavest.cli import main

    out = tmp_path / "t.json"
    assert main(["track", "radar_crossing", "--filters", "ekf", "--seed", "0",
                 "--set", "radar.sigma_az_deg=4.0", "--json", str(out)]) == 0
    sc = json.loads(out.read_text())["run"]["scenario"]
    assert sc["radar"]["sigma_az_deg"] == 4.0 and sc["tracker"]["gate_prob"] == 0.999
    out = tmp_path / "b.json"
    assert main(["bench", "linear_cv", "--runs", "2", "--filters", "kf", "--seed", "0",
                 "--no-progress", "--json", str(out)]) == 0
    sc = json.loads(out.read_text())["run"]["scenario"]
    assert sc["model"] == {"dt": 1.0, "q": 0.1, "R": 4.0} and sc["kind"] == "linear_cv"


def test_radar_defaults_live_in_the_schema():
    """The detection range and the clutter box come from the schema's defaults (the code
    that reads them has none), and the resolved record states the values used."""
    from uavest.tracking.scenario import build_models, clutter_box

    sc = load_typed("radar_crossing")  # sets neither r_max nor rr_max
    assert (sc.radar.r_max, sc.radar.rr_max) == (20000.0, 100.0)
    _, radar = build_models(sc)
    lo, hi = clutter_box(sc.radar, radar)
    assert hi[0] == 20000.0 and lo[0] == 0.0
    assert resolved(sc)["radar"]["r_max"] == 20000.0
    narrow = load_typed("radar_crossing", ["radar.r_max=5000"])
    assert clutter_box(narrow.radar, radar)[1][0] == 5000.0


def test_filter_mode_without_a_prior_is_a_one_line_error(capsys):
    """Was an internal error (KeyError: 'mean'): radar_uav has no [prior] table."""
    from uavest.cli import main

    rc = main(["bench", "radar_uav", "--runs", "1", "--steps", "3", "--filters", "ukf",
               "--set", "mode=filter", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "prior.mean" in err[0], err
