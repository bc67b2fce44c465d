"""``uavest run --aiding-from FILE``: what a previous navigation result learned, read
from its JSON (uavest/apps/aiding.py); bad files get one line."""

from __future__ import annotations

import json

import pytest

from uavest.apps.aiding import read_aiding
from uavest.errors import InputError

LIVE = {"model": "nav", "gnss_delay_live": {
    "delay": 0.083, "window": 0.347, "baro_delay": 0.044, "baro_spread": 0.004,
    "baro_noise": 0.02, "mag_scatter": 0.034, "mag_noise": 0.05, "given": None}}
REPLAY = {"model": {"what": "model", "value": "nav"}, "gnss_delay_estimate": {
    "delay_used": 0.084, "window_used": 0.345,
    "baro": {"delay_used": 0.043, "noise_used": 0.02},
    "mag": {"delay_used": 0.06, "noise_used": 0.06}}}


def _file(tmp_path, doc, name="r.json"):
    p = tmp_path / name
    p.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return p


@pytest.mark.parametrize("doc, what", [(LIVE, "a live run's"), (REPLAY, "a replay's")])
def test_the_gnss_timing_and_the_noises_are_read_and_the_sensors_delays_are_not(
        tmp_path, doc, what):
    """The GNSS delay and window, the baro's and the magnetometer's noise (a live run's
    learner, a replay's probe); not the baro's and the magnetometer's ages."""
    got, why = read_aiding(_file(tmp_path, doc))
    want = ({"gnss_delay": 0.083, "gnss_vel_window": 0.347, "baro_noise": 0.02,
             "mag_noise": 0.05}
            if doc is LIVE else {"gnss_delay": 0.084, "gnss_vel_window": 0.345,
                                 "baro_noise": 0.02, "mag_noise": 0.06})
    assert got == pytest.approx(want)
    assert why == f"{what} estimates in r.json"


def test_what_was_not_learned_is_not_taken(tmp_path):
    doc = {"model": "nav", "gnss_delay_live": {"delay": None, "window": None,
                                               "baro_noise": 0.05, "given": 0.1}}
    got, _ = read_aiding(_file(tmp_path, doc))
    assert got == {"baro_noise": 0.05}  # a given delay is the option's, not learnt


@pytest.mark.parametrize("content, says", [
    (None, "cannot read it"),
    ("{not json", "not a JSON result"),
    (json.dumps({"model": "attitude", "attitude": {}}), "not a navigation result"),
    (json.dumps([1, 2]), "not a navigation result"),
    (json.dumps({"model": "nav", "gnss_delay_live": {"delay": None, "window": "x"}}),
     "learned none"),
    (json.dumps({"model": "nav", "gnss_delay_live": {"delay": float("nan")}}),
     "learned none"),
])
def test_a_file_that_is_not_a_navigation_result_gets_one_line(tmp_path, content, says):
    p = tmp_path / "x.json" if content is None else _file(tmp_path, content, "x.json")
    with pytest.raises(InputError) as e:
        read_aiding(p)
    msg = str(e.value)
    assert says in msg and "--aiding-from" in msg and "\n" not in msg


def test_the_command_line_refuses_it_for_the_attitude_model(tmp_path, capsys):
    from uavest.cli import main

    p = _file(tmp_path, LIVE)
    rc = main(["run", "--connect", str(p), "--aiding-from", str(p), "--trackers", "none"])
    err = capsys.readouterr().err
    assert rc == 2 and "--aiding-from needs --model nav" in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("spread, want", [(0.1, 0.1), (0.5, 0.2), (0.004, "floor")])
def test_the_baro_noise_a_live_run_records_is_capped_by_its_sources_profile(spread, want):
    """The baro noise a live run records for a next one, and takes itself from then on
    with the offset learnt with it, is its baro's spread within [BARO_NOISE_MIN, the IMU
    source's profile], not within the noise the run itself had: a run started with a
    previous run's 0.02 m would otherwise never record more."""
    from types import SimpleNamespace

    from uavest.engine.gnss_delay import BARO_NOISE_MIN, LiveDelayLearner
    from uavest.models.navigation import NavNoise

    want = BARO_NOISE_MIN if want == "floor" else want
    learner = LiveDelayLearner()
    learner.t_decided, learner.baro_spread, learner.baro_offset = 64.5, spread, -0.03
    fits = []
    stream = SimpleNamespace(_builder=object(), frame=None, noise=NavNoise(baro_noise=0.02),
                             source_noise=NavNoise(baro_noise=0.2), baro_fit=None,
                             opts=SimpleNamespace(noise={"baro_noise": 0.02}),
                             set_baro_fit=lambda *a: fits.append(a))
    learner.apply(stream)
    assert learner.baro_noise == pytest.approx(want)
    assert learner.as_dict()["baro_noise"] == pytest.approx(want)
    assert learner.as_dict()["baro_offset"] == -0.03
    (noise, offset, t, why), = fits
    assert noise == pytest.approx(want) and offset == -0.03 and t == 64.5
    assert why.startswith("estimated live: the spread of the baro height"), why


def test_a_run_that_learned_its_timing_says_how_to_start_the_next_with_it(tmp_path):
    """``uavest run --json PATH`` and ``uavest replay --json PATH`` end with the line naming
    ``--aiding-from PATH`` and what it would take, when the result learned any of it
    (none, or an attitude result: no line)."""
    from uavest.apps.aiding import aiding_hint

    p = _file(tmp_path, LIVE)
    line = aiding_hint(str(p), "run")
    assert line == ("a live run against this vehicle can start with what this run "
                    "learned (GNSS delay 0.083 s, velocity window 0.347 s, baro noise "
                    "0.020 m, magnetometer noise 0.050 rad): uavest run --model nav "
                    f"--aiding-from {p}")
    nothing = _file(tmp_path, {"model": "nav", "gnss_delay_live": {"delay": None}}, "n.json")
    assert aiding_hint(str(nothing), "run") is None
    assert aiding_hint(str(_file(tmp_path, {"model": "attitude"}, "a.json")), "replay") is None


def test_the_fields_inclination_is_read_with_where_it_was_learned(tmp_path):
    """A replay's probe inclination, a live run's learner's, else its first filter's
    magnetic reference states': taken with the result's origin (the field is the
    site's); without an origin, or not finite, or not an inclination: not taken."""
    import math

    origin = {"lat": 47.39, "lon": 8.54, "alt": 500.0}
    replay = dict(REPLAY, origin=origin)
    replay["gnss_delay_estimate"] = dict(REPLAY["gnss_delay_estimate"],
                                         mag={"inclination": 1.1188})
    got, _ = read_aiding(_file(tmp_path, replay))
    assert got["mag_inclination"] == 1.1188
    assert (got["mag_site_lat"], got["mag_site_lon"]) == (47.39, 8.54)
    learner = dict(LIVE, origin=origin)
    learner["gnss_delay_live"] = dict(LIVE["gnss_delay_live"], inclination={"value": 1.12})
    assert read_aiding(_file(tmp_path, learner))[0]["mag_inclination"] == 1.12
    states = dict(LIVE, origin=origin, attitude={
        "ekf": {"mag_ref": {"inclination_deg": 64.2}}, "autopilot": {}})
    assert read_aiding(_file(tmp_path, states))[0]["mag_inclination"] == pytest.approx(
        math.radians(64.2))
    for doc in (dict(replay, origin=None), dict(states, origin={"lat": "x"}),
                dict(states, attitude={"ekf": {"mag_ref": {"inclination_deg": 95.0}}}),
                dict(states, attitude={"ekf": {"mag_ref": {"inclination_deg": None}}})):
        got, _ = read_aiding(_file(tmp_path, doc))
        assert "mag_inclination" not in got and "mag_site_lat" not in got, doc
    only = {"model": "nav", "origin": origin, "gnss_delay_live": {
        "delay": None, "inclination": {"value": -0.5}}}
    got, _ = read_aiding(_file(tmp_path, only))
    assert got == {"mag_inclination": -0.5, "mag_site_lat": 47.39, "mag_site_lon": 8.54}


def test_the_hint_says_the_inclination_in_degrees(tmp_path):
    from uavest.apps.aiding import aiding_hint

    doc = dict(LIVE, origin={"lat": 47.39, "lon": 8.54})
    doc["gnss_delay_live"] = dict(LIVE["gnss_delay_live"], inclination={"value": 1.12})
    line = aiding_hint(str(_file(tmp_path, doc)), "run")
    assert "magnetometer noise 0.050 rad, field inclination 64.17 deg)" in line, line


def test_a_live_runs_magnetometer_age_is_the_option_or_0():
    """``uavest run --model nav --mag-delay S`` gives the navigation stream the
    magnetometer's age (said "option --mag-delay"); without it 0, whatever an
    ``--aiding-from`` result learned (the age a replay finds costs yaw RMSE live,
    docs/live.md)."""
    from uavest.apps.live import LiveConfig, nav_options
    from uavest.engine.navigation import NavStream

    given = nav_options(LiveConfig(model="nav", mag_delay=0.052), None)
    assert given.mag_delay == 0.052
    aided = nav_options(LiveConfig(model="nav", aiding={"gnss_delay": 0.08},
                                   aiding_why="x"), None)
    assert aided.mag_delay is None and aided.gnss_delay == 0.08
    assert NavStream(opts=given).opts.mag_delay == 0.052

