"""The MAVLink publisher, heard by a pymavlink listener on loopback UDP."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
from fakevehicle import FakeVehicle, free_port
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from uavest.geometry.rotation import euler_to_quat
from uavest.ingest import open_live
from uavest.sinks.mavlink_pub import MavlinkPublisher, icao_address


def listen(sock: socket.socket, seconds: float) -> list:
    rx = mavlink.MAVLink(None)
    rx.robust_parsing = True
    out = []
    end = time.monotonic() + seconds
    sock.settimeout(0.05)
    while time.monotonic() < end:
        try:
            data = sock.recv(65536)
        except TimeoutError:
            continue
        out += [m for m in rx.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]
    return out


@pytest.mark.slow
def test_publisher_sends_own_identity_and_simulated_tracks():
    port = free_port()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    q = euler_to_quat(0.1, -0.2, 0.3)
    with MavlinkPublisher(f"udpout:127.0.0.1:{port}", rate_hz=5.0) as pub:
        assert pub.attitude("ukf", 12.5, q, rates=[0.01, 0.02, 0.03])
        assert not pub.attitude("ukf", 12.6, q)  # rate-limited
        pub.attitude("ekf", 12.5, q)
        pub.value("ukf_nis", 12.5, 3.25)
        pub.vector("ukf_bias", 12.5, [1e-3, 2e-3, 3e-3])
        pub.track("jpda", 7, 12.5, -35.36, 149.16, 700.0, [10.0, 10.0, -1.0])
        with pytest.raises(ValueError, match="1..10"):
            pub.value("much_too_long_name", 1.0, 0.0)
        msgs = listen(sock, 1.3)
    assert pub.dropped == 1
    assert {m.get_srcSystem() for m in msgs} == {250}
    hb = [m for m in msgs if m.get_type() == "HEARTBEAT"]
    assert {m.get_srcComponent() for m in hb} == {191, 192}
    assert all(m.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
               and m.autopilot == mavlink.MAV_AUTOPILOT_INVALID for m in hb)
    att = [m for m in msgs if m.get_type() == "ATTITUDE"]
    assert sorted(m.get_srcComponent() for m in att) == [191, 192]
    a = [m for m in att if m.get_srcComponent() == 191][0]
    assert (a.roll, a.pitch, a.yaw) == pytest.approx((0.1, -0.2, 0.3), abs=1e-6)
    assert a.time_boot_ms == 12500 and a.yawspeed == pytest.approx(0.03)
    nv = {m.name: m.value for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert nv["ukf_nis"] == pytest.approx(3.25) and nv["ukf_rol"] == pytest.approx(0.1)
    assert nv["ekf_yaw"] == pytest.approx(0.3)
    dv = [m for m in msgs if m.get_type() == "DEBUG_VECT"][0]
    assert dv.name == "ukf_bias" and dv.z == pytest.approx(3e-3)
    ad = [m for m in msgs if m.get_type() == "ADSB_VEHICLE"][0]
    assert ad.flags & mavlink.ADSB_FLAGS_SIMULATED
    assert ad.ICAO_address == icao_address(0, 7) == 0xF00007
    assert ad.callsign == "JPDA0007"
    assert ad.heading == 4500 and ad.hor_velocity == round(100 * math.hypot(10, 10))
    assert ad.ver_velocity == 100 and ad.lat == -353600000
    assert not pub._thread.is_alive()


def test_publisher_refuses_the_vehicle_link():
    port = free_port()
    with pytest.raises(ValueError, match="vehicle's link"):
        MavlinkPublisher(f"udpout:localhost:{port}", vehicle_conn=f"udpin:0.0.0.0:{port}")
    with FakeVehicle(port), open_live(f"udpin:127.0.0.1:{port}", streams={},
                                      read_declination=False):
        with pytest.raises(ValueError, match="vehicle's link"):
            MavlinkPublisher(f"udpout:127.0.0.1:{port}")
        MavlinkPublisher(f"udpout:127.0.0.1:{port}", allow_vehicle_link=True).close()
    other = free_port()
    MavlinkPublisher(f"udpout:127.0.0.1:{other}").close()
    assert np.isfinite(other)
