"""Live view of the navigation model: a real WebSocket client (``foxglove.sdk.v1``)
subscribes to the navigation channels while a navigation replay of the project's SITL
flight (logs/sitl_copter.tlog) runs into FoxgloveLiveSink, as ``uavest run/demo --model
nav --foxglove`` and ``uavest replay --foxglove`` serve them: velocity and position with
their 3-sigma, and the 3-D view's body placed at the filter's own position."""

import asyncio
import base64
import json
import threading
from pathlib import Path

import pytest
from test_foxglove_live import Pace, _client

from uavest.apps.replay import ReplayConfig, replay
from uavest.report.protowire import ProtoDecoder
from uavest.sinks.foxglove_live import FoxgloveLiveSink

pytest.importorskip("websockets")
LOG = Path(__file__).resolve().parents[2] / "logs" / "sitl_copter.tlog"
NAV = ("/navigation/ekf/estimate", "/tf/ekf", "/attitude/ekf/estimate")


@pytest.mark.slow
def test_live_view_serves_the_navigation_model():
    sink = FoxgloveLiveSink("127.0.0.1", 0, wait_for_client=30.0, frame_rate_hz=None)
    result: dict = {}

    def run():
        result["doc"] = replay(LOG, ReplayConfig(filters=("ekf",), model="nav", start=60.0,
                                                 end=90.0, gnss_delay=0.08, mag_delay=0.05,
                                                 noise={"mag_noise": 0.05}),
                               sinks=[sink, Pace()])

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        got = asyncio.run(_client(sink.url, want=NAV, many=200))
    finally:
        th.join(timeout=300)
    assert not th.is_alive() and result["doc"]["model"]["value"] == "nav"
    adv = got["advertised"]
    assert adv["/navigation/ekf/estimate"]["schemaName"] == "uavest.NavigationEstimate"
    assert "/navigation/anchor" in adv and "/position/SIM_STATE" in adv
    assert set(got["data"]) == set(NAV) | {"/run/info"}
    ch = adv["/navigation/ekf/estimate"]
    dec = ProtoDecoder(base64.b64decode(ch["schema"]))
    log_time, payload = got["data"]["/navigation/ekf/estimate"]
    m = dec.decode(payload, "uavest.NavigationEstimate")
    assert abs(m["t"] * 1e9 - log_time) < 2
    for k in ("velocity_ned_m_s", "position_ned_m", "sigma3_velocity_m_s",
              "sigma3_position_m", "accel_bias_m_s2"):
        assert len(m[k]) == 3, k
    assert all(s > 0 for s in m["sigma3_position_m"] + m["sigma3_velocity_m_s"])
    # the 3-D view: the filter's body at its own position (ENU), 2 m east for display
    tdec = ProtoDecoder(base64.b64decode(adv["/tf/ekf"]["schema"]))
    tfs = {lt: tdec.decode(b, "foxglove.FrameTransform")["translation"]
           for lt, b in got["all"]["/tf/ekf"]}
    navs = {lt: dec.decode(b, "uavest.NavigationEstimate")["position_ned_m"]
            for lt, b in got["all"]["/navigation/ekf/estimate"]}
    both = sorted(set(tfs) & set(navs))
    assert len(both) > 20
    moved = 0.0
    for lt in both:
        (n, e, d), tr = navs[lt], tfs[lt]
        assert abs(tr["x"] - (e + 2.0)) < 1e-6 and abs(tr["y"] - n) < 1e-6
        assert abs(tr["z"] + d) < 1e-6
        moved = max(moved, abs(n) + abs(e) + abs(d))
    assert moved > 0.5  # the body follows the trajectory
    info = json.loads(got["data"]["/run/info"][1])
    assert list(info["filters"]) == ["ekf"]
