"""``--set KEY=VALUE`` must name a key the scenario has (or a known optional key): a typo
such as ``clutter_rate`` for ``radar.clutter_rate`` used to be silently ignored."""

from __future__ import annotations

import pytest

from uavest.cli import main
from uavest.scenarios import ScenarioError, load_scenario


def test_unknown_key_exits_2_naming_the_close_match(capsys):
    rc = main(["track", "radar_crossing", "--set", "clutter_rate=5", "--filters", "ekf",
               "--seed", "0"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "clutter_rate" in err and "radar.clutter_rate" in err


def test_unknown_key_with_no_close_match_lists_the_sections():
    with pytest.raises(ScenarioError, match="known sections: .*radar"):
        load_scenario("radar_crossing", ["zzzqqq.xx=1"])


def test_misspelt_nested_key_is_rejected():
    with pytest.raises(ScenarioError, match="radar.clutter_rate"):
        load_scenario("radar_crossing", ["radar.cluter_rate=5"])


def test_known_key_still_changes_the_value():
    base = load_scenario("radar_crossing")["radar"]["clutter_rate"]
    sc = load_scenario("radar_crossing", [f"radar.clutter_rate={base + 3}"])
    assert sc["radar"]["clutter_rate"] == base + 3


def test_new_optional_key_under_an_existing_section_still_works():
    sc0 = load_scenario("radar_crossing")
    assert "motion" in sc0 and "truth_q" not in sc0["motion"]
    sc = load_scenario("radar_crossing", ["motion.truth_q=0.2"])
    assert sc["motion"]["truth_q"] == 0.2
    sc = load_scenario("radar_crossing", ["tracker.confirm_m=3"])  # a new optional table
    assert sc["tracker"]["confirm_m"] == 3
