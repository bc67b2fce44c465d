"""The vehicle's sensor spec (``SPEC_*`` parameters): what a vehicle states, what a run
takes (options first), what the simulator answers, and bad values skipped with a
reason."""

from __future__ import annotations

import math

import pytest

from uavest.apps.live import LiveConfig, nav_options, with_vehicle_spec
from uavest.apps.sensor_spec import with_sensor_spec
from uavest.link.spec import SPEC_PARAMS, sensor_spec, spec_params
from uavest.scenarios import load_typed
from uavest.sim import Simulator
from uavest.sim.sensors import GNSS_DELAY_S, spec_noise

PARAMS = {"SPEC_GYR_NSD": 1.5e-4, "SPEC_MAG_NSR": 0.00625, "SPEC_GPS_SDH": 0.8,
          "SPEC_GPS_SDV": 1.5, "SPEC_GPS_TAU": 60.0, "SPEC_GPS_DLY": 0.0,
          "COMPASS_DEC": 0.05}


def test_the_spec_reads_every_parameter_it_names_and_nothing_else():
    spec, skipped = sensor_spec(PARAMS)
    assert skipped == []
    assert spec == {"gyro_noise": 1.5e-4, "mag_noise": 0.00625, "gnss_bias_h": 0.8,
                    "gnss_bias_v": 1.5, "gnss_bias_tau": 60.0, "gnss_delay": 0.0}
    assert sensor_spec({"COMPASS_DEC": 0.05}) == ({}, [])
    # the simulator's side writes what the estimator's side reads
    assert sensor_spec(spec_params(spec))[0] == spec
    assert all(len(name) <= 16 for name in SPEC_PARAMS)  # MAVLink param_id


@pytest.mark.parametrize("name, value", [
    ("SPEC_GYR_NSD", math.nan), ("SPEC_GYR_NSD", -1e-4), ("SPEC_GPS_TAU", 0.0),
    ("SPEC_GPS_DLY", 2.5), ("SPEC_MAG_NSR", math.inf), ("SPEC_GPS_SDH", "abc"),
])
def test_a_bad_value_is_skipped_and_said_never_taken(name, value):
    spec, skipped = sensor_spec({**PARAMS, name: value})
    key = SPEC_PARAMS[name][0]
    assert key not in spec and len(spec) == 5
    assert len(skipped) == 1 and skipped[0].startswith(f"{name}="), skipped
    sp = with_sensor_spec({**PARAMS, name: value}, {}, None)
    assert sp.why is not None and f"skipped: {name}=" in sp.why


def test_options_win_over_the_spec():
    sp = with_sensor_spec(PARAMS, {"mag_noise": 0.05}, 0.1)
    assert "mag_noise" not in sp.taken and "gnss_delay" not in sp.taken
    noise, delay = sp.merged({"mag_noise": 0.05}, 0.1)
    assert noise["mag_noise"] == 0.05 and noise["gyro_noise"] == 1.5e-4 and delay == 0.1
    assert sp.stated["mag_noise"] == 0.00625  # said in the result as stated
    assert sp.why_of("mag_noise") is None
    assert sp.why_of("gnss_bias_h", "gnss_bias_tau") == (
        "the vehicle's sensor spec (SPEC_GPS_SDH, SPEC_GPS_TAU)")
    noise, delay = with_sensor_spec(PARAMS, {}, None).merged({}, None)
    assert delay == 0.0 and "gnss_delay" not in noise


def test_a_live_navigation_run_takes_the_spec_and_says_where_from():
    cfg = with_vehicle_spec(LiveConfig(model="nav", noise={"gyro_noise": 0.002}), PARAMS)
    assert cfg.noise["gyro_noise"] == 0.002 and cfg.noise["mag_noise"] == 0.00625
    assert cfg.gnss_delay == 0.0
    assert cfg.gnss_delay_why == "the vehicle's sensor spec (SPEC_GPS_DLY)"
    assert cfg.noise_why is not None and cfg.noise_why.endswith("option --noise: gyro_noise")
    o = nav_options(cfg, None)
    assert o.mag_noise_why == "the vehicle's sensor spec (SPEC_MAG_NSR)"
    assert o.gnss_bias_why == "the vehicle's sensor spec (SPEC_GPS_SDH, SPEC_GPS_SDV, " \
                              "SPEC_GPS_TAU)"
    assert cfg.sensor_spec is not None and "gyro_noise" not in cfg.sensor_spec["taken"]
    # a delay from --aiding-from is given: the file's, not the spec's
    aided = with_vehicle_spec(LiveConfig(model="nav", aiding={"gnss_delay": 0.08},
                                         aiding_why="f.json"), PARAMS)
    assert aided.gnss_delay is None and nav_options(aided, None).gnss_delay == 0.08
    # the attitude model and a vehicle that states nothing: the configuration as it was
    att = LiveConfig(model="attitude")
    assert with_vehicle_spec(att, PARAMS) is att
    nav = LiveConfig(model="nav")
    assert with_vehicle_spec(nav, {"COMPASS_DEC": 0.05}) is nav


def test_the_simulator_answers_its_scenarios_datasheet():
    sc = load_typed("sim_default")
    params = {k: v for k, (v, _) in Simulator(sc).params.items()}
    spec, skipped = sensor_spec(params)
    assert skipped == []
    assert spec == pytest.approx({**spec_noise(sc), "gnss_delay": GNSS_DELAY_S}, rel=1e-6)
    # a quieter gyro in the scenario is a different statement
    quiet = load_typed("sim_default", ["imu.gyro_noise_density=5e-5"])
    got = {k: v for k, (v, _) in Simulator(quiet).params.items()}
    assert got["SPEC_GYR_NSD"] == pytest.approx(5e-5, rel=1e-6)
    # no SIM_ prefix: the parameters are not taken for an ArduPilot SITL's
    assert not any(k.startswith("SIM_") for k in SPEC_PARAMS)
