"""ArduPilot's flat-Earth frame (:class:`SphereFrame`) against its definition and against
WGS84, and the navigation stream's choice of geodesy (option, ArduPilot SITL evidence)."""

from __future__ import annotations

import numpy as np
import pytest
from test_nav_stream import ORIGIN, flight, run_nav

from uavest.engine.navigation import NavOptions, sitl_evidence
from uavest.errors import InputError
from uavest.geometry.geodesy import (
    ARDUPILOT_LATLON_TO_M,
    LocalFrame,
    SphereFrame,
    make_frame,
)
from uavest.ingest.types import AttitudeRef


def test_the_sphere_frame_is_ardupilots_scaling():
    lat0, lon0, h0 = 47.3977, 8.5456, 408.0
    fr = SphereFrame(lat0, lon0, h0)
    # Location::get_distance_NE: 1e-7 deg north is LATLON_TO_M m; east, times the cosine
    # of the mean latitude
    n = fr.geodetic_to_ned(lat0 + 1e-3, lon0, h0)
    assert n[0] == pytest.approx(1e4 * ARDUPILOT_LATLON_TO_M, rel=1e-9)
    e = fr.geodetic_to_ned(lat0 + 2e-3, lon0 + 1e-3, h0 + 5.0)
    assert e[1] == pytest.approx(1e4 * ARDUPILOT_LATLON_TO_M * np.cos(np.deg2rad(lat0 + 1e-3)),
                                 rel=1e-9)
    assert e[2] == pytest.approx(-5.0)
    # round trip
    ned = np.array([[120.0, -340.0, -25.0], [-65.0, 226.0, 3.0]])
    back = fr.geodetic_to_ned(*fr.ned_to_geodetic(ned))
    np.testing.assert_allclose(back, ned, atol=1e-8)
    # not WGS84: 0.13 % short north and 0.18 % long east at this latitude
    w = LocalFrame(lat0, lon0, h0).geodetic_to_ned(*fr.ned_to_geodetic(ned[1]))
    assert w[0] / ned[1, 0] == pytest.approx(1 - 0.00126, abs=2e-4)
    assert w[1] / ned[1, 1] == pytest.approx(1 + 0.00182, abs=2e-4)
    assert isinstance(make_frame(lat0, lon0, h0, "sphere"), SphereFrame)
    assert isinstance(make_frame(lat0, lon0, h0), LocalFrame)
    with pytest.raises(ValueError):
        make_frame(lat0, lon0, h0, "mercator")


def test_sitl_evidence_ignores_the_parameter_uavest_sim_also_sends():
    assert sitl_evidence({"SIM_SPEEDUP": 1.0, "COMPASS_DEC": 0.05}) is None
    assert "SIM_WIND_SPD" in sitl_evidence({"SIM_SPEEDUP": 1.0, "SIM_WIND_SPD": 4.0})
    assert sitl_evidence({}) is None


def test_a_px4_sitls_own_sim_parameters_are_not_an_ardupilot_sitl():
    # sample_px4_events.ulg (PX4_SITL): SIM_BAT_DRAIN with PX4's own parameters
    px4 = {"SIM_BAT_DRAIN": 60.0, "SIM_BAT_ENABLE": 1, "SYS_AUTOSTART": 10015}
    assert sitl_evidence(px4) is None
    assert sitl_evidence({"SIM_BAT_DRAIN": 60.0, "EKF2_MAG_DECL": 3.3}) is None
    assert sitl_evidence({"SIM_BAT_DRAIN": 60.0, "MAV_SYS_ID": 1}) is None
    # ArduPilot's own, with the same SIM_ name, still is
    assert "SIM_BAT_DRAIN" in sitl_evidence({"SIM_BAT_DRAIN": 60.0, "EK3_ENABLE": 1,
                                              "SYSID_THISMAV": 1})


def _geo(stream):
    d = [d for d in stream.summary["decisions"] if d["what"] == "geodesy"]
    assert len(d) == 1
    return stream.summary["geodesy"], d[0]


@pytest.mark.parametrize("case", ["plain", "sim_state", "params", "option"])
def test_the_stream_takes_ardupilots_sphere_for_an_ardupilot_sitl(case):
    samples, ts, xs = flight(2, T=14.0)
    params = None
    opts = NavOptions(integration="hold")
    if case == "sim_state":  # SIM_STATE, which only an ArduPilot SITL sends
        samples = [AttitudeRef(samples[0].t, np.array([1.0, 0, 0, 0]), "truth", "SIM_STATE"),
                   *samples]
    elif case == "params":
        params = {"SIM_WIND_SPD": 0.0}
    elif case == "option":
        params = {"SIM_WIND_SPD": 0.0}
        opts = NavOptions(integration="hold", geodesy="wgs84")
    stream, runners, coll = run_nav(samples, opts=opts, params=params)
    geo, d = _geo(stream)
    want = "sphere" if case in ("sim_state", "params") else "wgs84"
    assert geo == want, d
    assert isinstance(stream.frame, SphereFrame if want == "sphere" else LocalFrame)
    assert (("SIM_STATE" in d["why"]) if case == "sim_state" else
            ("SIM_WIND_SPD" in d["why"]) if case == "params" else
            ("option" in d["why"]) if case == "option" else "no ArduPilot SITL" in d["why"])
    # the frame's origin is the first fix, whatever the geodesy
    o = stream.summary["origin"]
    np.testing.assert_allclose(stream.frame.geodetic_to_ned(o["lat"], o["lon"], o["alt"]),
                               0.0, atol=1e-9)
    assert abs(o["lat"] - ORIGIN[0]) < 1e-3


def test_a_bad_geodesy_is_one_line():
    with pytest.raises(InputError, match="--geodesy"):
        NavOptions(geodesy="mercator")
