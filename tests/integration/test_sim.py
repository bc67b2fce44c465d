"""`uavest sim` end to end: real MAVLink 2 over loopback UDP/TCP, tlogs, determinism,
and the truth consistency of what is sent (IMU vs SIMSTATE, radar and ADS-B vs targets)."""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"

import signal  # noqa: E402
import socket  # noqa: E402
import struct  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav2  # noqa: E402

from uavest.geometry.rotation import G0, euler_to_quat, quat_exp, quat_log, quat_mul  # noqa: E402
from uavest.scenarios import load_typed  # noqa: E402
from uavest.sim import CLUTTER_ID, Simulator  # noqa: E402
from uavest.sim.radar import Radar  # noqa: E402

mavutil.set_dialect("ardupilotmega")  # MAVLink 2 parser in this process
ROOT = Path(__file__).resolve().parents[2]


def free_port(kind=socket.SOCK_DGRAM) -> int:
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


class Live:
    """A Simulator running in a thread, sending to a pymavlink udpin client."""

    def __init__(self, sc_sets=(), duration=60.0, speed=20.0, imu_rate=500.0, seed=0,
                 proto="udp", **kw):
        self.sc = load_typed("sim_default", list(sc_sets))
        self.sim = Simulator(self.sc, seed=seed, imu_rate=imu_rate, **kw)
        self.stop = threading.Event()
        if proto == "udp":
            port = free_port()
            self.client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}",
                                                     source_system=255, source_component=190)
            target = f"udpout:127.0.0.1:{port}"
        else:
            port = free_port(socket.SOCK_STREAM)
            target = f"tcpin:127.0.0.1:{port}"
        self.result = None
        self.thread = threading.Thread(target=self._run, args=(target, duration, speed),
                                       daemon=True)
        self.thread.start()
        if proto == "tcp":
            assert self.sim.ready.wait(10)
            for _ in range(100):
                try:
                    self.client = mavutil.mavlink_connection(
                        f"tcp:127.0.0.1:{port}", source_system=255, source_component=190,
                        retries=0)
                    break
                except OSError:
                    time.sleep(0.05)

    def _run(self, target, duration, speed):
        self.result = self.sim.run(target, duration=duration, speed=speed,
                                   stop_event=self.stop, wait_gcs=True)

    def recv(self, timeout=5.0):
        return self.client.recv_match(blocking=True, timeout=timeout)

    def until(self, pred, timeout=10.0, keep=None):
        """Receive until ``pred(msg)``; ``keep`` collects every message seen."""
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            m = self.recv(0.5)
            if m is None:
                continue
            if keep is not None:
                keep.append(m)
            if pred(m):
                return m
        raise AssertionError("timed out")

    def ask(self, send, pred, what: str, timeout: float = 10.0):
        """``send(n)`` (n: the sends so far) until a message with ``pred`` comes, again
        every second, as a ground station does: on a loaded machine the client's UDP
        buffer overflows behind a fast stream and drops packets, the answer among them.
        Returns ``(the message, the number of sends)``."""
        t_end = time.monotonic() + timeout
        n = 0
        while time.monotonic() < t_end:
            send(n)
            n += 1
            try:
                return self.until(pred, timeout=1.0), n
            except AssertionError:
                pass
        raise AssertionError(f"no answer to {what} in {timeout:g} s ({n} sends)")

    def command(self, cmd: int, *params: float, result: int | None = None,
                timeout: float = 10.0):
        """COMMAND_LONG ``cmd`` until its COMMAND_ACK comes (with ``result``, if given:
        a late ACK of an earlier resent command is skipped), the confirmation count up at
        each resend (:meth:`ask`). Returns the ACK."""
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        return self.ask(
            lambda n: self.client.mav.command_long_send(1, 1, cmd, min(n, 255), *p),
            lambda m: (m.get_type() == "COMMAND_ACK" and m.command == cmd
                       and result in (None, m.result)),
            f"command {cmd} (result {result})", timeout)[0]

    def hello(self):
        """Wait for the sim's heartbeat and answer with a GCS heartbeat (starts its clock)."""
        self.until(lambda m: m.get_type() == "HEARTBEAT")
        self.client.mav.heartbeat_send(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def close(self):
        self.stop.set()
        self.thread.join(10)
        self.client.close()
        assert not self.thread.is_alive()


@pytest.fixture
def live(request):
    made = []

    def make(**kw):
        lv = Live(**kw)
        made.append(lv)
        return lv

    yield make
    for lv in made:
        lv.close()


def test_heartbeat_only_then_set_message_interval(live):
    # radar and ADS-B off: they are sent unrequested when on (see the next check)
    # 600 s of flight at 20x (30 s wall) that the test never reaches: with the default 60 s
    # (3 s wall) a loaded machine's client, reading the backlog, could find the simulator
    # finished before its last commands (a 2-s flight times out so on an idle machine)
    lv = live(sc_sets=["radar.enabled=false", "adsb.enabled=false"], speed=20.0,
              imu_rate=500.0, duration=600.0)
    lv.hello()
    seen = []
    hb = lv.until(lambda m: m.get_type() == "HEARTBEAT")  # 1 s of sim time passes
    lv.until(lambda m: m.get_type() == "HEARTBEAT", keep=seen)
    lv.until(lambda m: m.get_type() == "HEARTBEAT", keep=seen)
    assert {m.get_type() for m in seen} == {"HEARTBEAT"}
    assert hb.type == mav2.MAV_TYPE_QUADROTOR and hb.autopilot == mav2.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert lv.client.WIRE_PROTOCOL_VERSION == "2.0" or hb._header.mlen > 0
    assert lv.sim.sent["RAW_IMU"] == 0

    ack = lv.command(mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAVLINK_MSG_ID_RAW_IMU, 4000)
    assert ack.command == mav2.MAV_CMD_SET_MESSAGE_INTERVAL
    assert ack.result == mav2.MAV_RESULT_ACCEPTED
    imu = []
    lv.until(lambda m: m.get_type() == "RAW_IMU" and len(imu) > 500, keep=imu)
    raw = [m for m in imu if m.get_type() == "RAW_IMU"]
    t = np.array([m.time_usec for m in raw], float)
    assert np.all(np.diff(t) == 4000.0)  # IMU step 2000 us: exactly every other step
    rate = (t.size - 1) / ((t[-1] - t[0]) * 1e-6)
    assert rate == pytest.approx(250.0, rel=0.01)
    # time_usec is the boot clock: the vehicle booted with the sim, so it is < sim time now
    assert 0 < t[-1] * 1e-6 <= lv.sim.t + 1e-9
    # accelerations in milli-g, the truth's specific force plus the sensor's bias; the
    # last samples, whose times the simulator's history still holds (under load the
    # simulator may be in a manoeuvre by then, so no fixed "hover" window)
    last = raw[-50:]
    err = []
    for m in last:
        v = lv.sim.truth_at(m.time_usec * 1e-6).vehicle
        want = (v.f_body + v.accel_bias) / G0 * 1000.0
        err.append(np.array([m.xacc, m.yacc, m.zacc]) - want)
    err = np.array(err)
    # vibration and noise: ~50 mg per sample horizontally, ~120 vertically, so the
    # mean of 50 is within ~20 mg; a wrong unit or axis would be off by 100s of mg
    assert np.all(np.abs(err.mean(0)) < 60.0) and np.all(err.std(0) < 250.0)
    assert -1500 < last[-1].zacc < -500  # about -1 g: the unit is milli-g, not m/s^2

    # disable again (-1), and an unknown message id is denied
    ack = lv.command(mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAVLINK_MSG_ID_RAW_IMU, -1)
    assert ack.result == mav2.MAV_RESULT_ACCEPTED
    lv.command(mav2.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000, result=mav2.MAV_RESULT_DENIED)
    n0 = lv.sim.sent["RAW_IMU"]
    lv.until(lambda m: m.get_type() == "HEARTBEAT")
    lv.until(lambda m: m.get_type() == "HEARTBEAT")
    assert lv.sim.sent["RAW_IMU"] == n0


def test_request_data_stream_groups_and_cap(live):
    lv = live(speed=20.0, imu_rate=400.0)
    lv.hello()
    lv.client.mav.request_data_stream_send(1, 1, mav2.MAV_DATA_STREAM_EXTRA1, 200, 1)
    lv.client.mav.request_data_stream_send(1, 1, mav2.MAV_DATA_STREAM_POSITION, 5, 1)
    got = []
    lv.until(lambda m: m.get_type() == "HEARTBEAT", keep=got)  # settle
    got = []
    lv.until(lambda m: m.get_type() == "HEARTBEAT", keep=got)
    lv.until(lambda m: m.get_type() == "HEARTBEAT", keep=got)
    lv.until(lambda m: m.get_type() == "HEARTBEAT", keep=got)
    kinds = {m.get_type() for m in got}
    # unrequested: only the radar's messages (scenario radar/adsb enabled)
    assert kinds - {"ATTITUDE", "SIMSTATE", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"} == {
        "HEARTBEAT", "OBSTACLE_DISTANCE_3D", "ADSB_VEHICLE"}
    assert {"ATTITUDE", "SIMSTATE", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"} <= kinds
    assert "RAW_IMU" not in kinds and "GPS_RAW_INT" not in kinds
    ta = np.array([m.time_boot_ms for m in got if m.get_type() == "ATTITUDE"], float)
    tg = np.array([m.time_boot_ms for m in got if m.get_type() == "GLOBAL_POSITION_INT"], float)
    assert (ta.size - 1) / ((ta[-1] - ta[0]) * 1e-3) == pytest.approx(50.0, rel=0.02)  # capped
    assert (tg.size - 1) / ((tg[-1] - tg[0]) * 1e-3) == pytest.approx(5.0, rel=0.05)
    g = [m for m in got if m.get_type() == "GLOBAL_POSITION_INT"][-1]
    assert abs(g.relative_alt - 30000) < 15000  # ~30 m above home (climbs +-16 m)
    assert abs(g.lat * 1e-7 - 47.3977) < 1e-3
    # stop EXTRA1
    lv.client.mav.request_data_stream_send(1, 1, mav2.MAV_DATA_STREAM_EXTRA1, 0, 0)
    lv.until(lambda m: m.get_type() == "HEARTBEAT")
    n0 = lv.sim.sent["ATTITUDE"]
    lv.until(lambda m: m.get_type() == "HEARTBEAT")
    assert lv.sim.sent["ATTITUDE"] == n0 and lv.sim.sent["GLOBAL_POSITION_INT"] > 0


def test_params_compass_dec(live):
    lv = live(sc_sets=["mag.declination_deg=7.5"], speed=20.0, imu_rate=200.0)
    lv.hello()
    cl = lv.client.mav
    pv, _ = lv.ask(lambda n: cl.param_request_read_send(1, 1, b"COMPASS_DEC", -1),
                   lambda m: m.get_type() == "PARAM_VALUE", "PARAM_REQUEST_READ")
    assert pv.param_id == "COMPASS_DEC"
    assert pv.param_value == pytest.approx(np.deg2rad(7.5), abs=1e-6)
    names = {}
    # a resent list adds what the first lost: every index once
    lv.ask(lambda n: cl.param_request_list_send(1, 1),
           lambda m: m.get_type() == "PARAM_VALUE" and (
               names.setdefault(m.param_id, m) and len(names) == m.param_count),
           "PARAM_REQUEST_LIST", timeout=20.0)
    assert names["COMPASS_AUTODEC"].param_value == 0.0
    assert names["SYSID_THISMAV"].param_value == 1.0
    assert sorted(m.param_index for m in names.values()) == list(range(len(names)))
    # GET_MESSAGE_INTERVAL after SET, and REQUEST_MESSAGE (one instance per request)
    lv.command(mav2.MAV_CMD_SET_MESSAGE_INTERVAL, mav2.MAVLINK_MSG_ID_SIMSTATE, 20000)
    mi, _ = lv.ask(lambda n: cl.command_long_send(1, 1, mav2.MAV_CMD_GET_MESSAGE_INTERVAL,
                                                  n, mav2.MAVLINK_MSG_ID_SIMSTATE,
                                                  0, 0, 0, 0, 0, 0),
                   lambda m: m.get_type() == "MESSAGE_INTERVAL", "GET_MESSAGE_INTERVAL")
    assert (mi.message_id, mi.interval_us) == (mav2.MAVLINK_MSG_ID_SIMSTATE, 20000)
    st, asked = lv.ask(lambda n: cl.command_long_send(1, 1, mav2.MAV_CMD_REQUEST_MESSAGE, n,
                                                      mav2.MAVLINK_MSG_ID_SYSTEM_TIME,
                                                      0, 0, 0, 0, 0, 0),
                       lambda m: m.get_type() == "SYSTEM_TIME", "REQUEST_MESSAGE")
    assert st.time_unix_usec == int(lv.sim.epoch * 1e6) + st.time_boot_ms * 1000
    ack = lv.command(mav2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mav2.MAV_RESULT_UNSUPPORTED
    lv.until(lambda m: m.get_type() == "HEARTBEAT")
    lv.until(lambda m: m.get_type() == "HEARTBEAT")
    # one SYSTEM_TIME per request that arrived (a resend after a lost answer is one more)
    assert 1 <= lv.sim.sent["SYSTEM_TIME"] <= asked and lv.sim.sent["SIMSTATE"] > 40


def test_tcpin_like_sitl(live):
    lv = live(proto="tcp", speed=20.0, imu_rate=200.0)
    lv.hello()
    lv.client.mav.command_long_send(1, 1, mav2.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                    mav2.MAVLINK_MSG_ID_HIGHRES_IMU, 10000, 0, 0, 0, 0, 0)
    got = []
    lv.until(lambda m: m.get_type() == "HIGHRES_IMU" and len(got) > 150, keep=got)
    h = [m for m in got if m.get_type() == "HIGHRES_IMU"]
    assert len(h) > 100
    t = np.array([m.time_usec for m in h], float)
    assert np.all(np.diff(t) == 10000.0)
    assert np.mean([m.zacc for m in h]) == pytest.approx(-G0, abs=0.5)
    # HIGHRES mag in gauss: |B| = the scenario's 0.48 G
    assert np.linalg.norm([h[-1].xmag, h[-1].ymag, h[-1].zmag]) == pytest.approx(0.48, abs=0.02)


def test_udpin_server_answers_whoever_calls():
    """``--out udpin:...``: the sim is the UDP server; it replies to the client's address."""
    port = free_port()
    sim = Simulator(load_typed("sim_default"), imu_rate=200.0)
    stop = threading.Event()
    th = threading.Thread(target=sim.run, kwargs=dict(
        conn=f"udpin:127.0.0.1:{port}", duration=60.0, speed=20.0, stop_event=stop,
        wait_gcs=True), daemon=True)
    th.start()
    try:
        assert sim.ready.wait(10)
        c = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        c.mav.heartbeat_send(mav2.MAV_TYPE_GCS, mav2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        c.mav.command_long_send(1, 1, mav2.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                mav2.MAVLINK_MSG_ID_RAW_IMU, 5000, 0, 0, 0, 0, 0)
        m = c.recv_match(type="RAW_IMU", blocking=True, timeout=10)
        assert m is not None and m.get_srcSystem() == 1
    finally:
        stop.set()
        th.join(10)
    assert sim.received["HEARTBEAT"] >= 1 and sim.received["COMMAND_LONG"] == 1


@pytest.mark.slow
def test_radar_detections_over_udp_match_truth(live):
    lv = live(sc_sets=["radar.rate_hz=4"], speed=0.0, imu_rate=50.0, duration=150.0)
    lv.hello()
    dets, adsb = [], []
    while True:
        m = lv.recv(0.3)
        if m is None:
            if not lv.thread.is_alive():
                break
            continue
        if m.get_type() == "OBSTACLE_DISTANCE_3D":
            dets.append(m)
        elif m.get_type() == "ADSB_VEHICLE":
            adsb.append(m)
    lv.thread.join(10)
    sim = lv.sim
    assert lv.result.reason == "duration"
    assert len(dets) == sim.sent["OBSTACLE_DISTANCE_3D"]  # nothing lost on loopback
    radar = sim.radar
    sig = radar.sigma
    res, clutter_per_scan = [], {}
    for m in dets:
        assert m.sensor_type == mav2.MAV_DISTANCE_SENSOR_RADAR
        assert m.frame == mav2.MAV_FRAME_BODY_FRD
        assert (m.min_distance, m.max_distance) == (radar.r_min, radar.r_max)
        t = m.time_boot_ms * 1e-3
        d = np.array([m.x, m.y, m.z])
        if m.obstacle_id == CLUTTER_ID:
            clutter_per_scan[t] = clutter_per_scan.get(t, 0) + 1
            continue
        tr = sim.truth_at(t)
        j = tr.target_ids.index(m.obstacle_id)
        R = mav_R(tr.vehicle.q)
        # back to NED: what a tracker with a perfect attitude would compute
        p_ned = tr.vehicle.pos_ned + R @ d
        true_los = R.T @ (tr.target_pos[j] - tr.vehicle.pos_ned)
        meas, ref = Radar.to_spherical(d), Radar.to_spherical(true_los)
        e = meas - ref
        e[1] = (e[1] + np.pi) % (2 * np.pi) - np.pi
        res.append(e / sig)
        assert np.linalg.norm(p_ned - tr.target_pos[j]) < 6 * np.linalg.norm(
            [sig[0], ref[0] * sig[1], ref[0] * sig[2]])
    res = np.array(res)
    assert len(res) > 1000
    assert np.all(np.abs(res.mean(0)) < 0.15)
    assert np.all((res.std(0) > 0.9) & (res.std(0) < 1.1))
    scans = 150 * radar.rate + 1
    assert sum(clutter_per_scan.values()) / scans == pytest.approx(radar.clutter_rate, rel=0.15)
    # Pd: detections per in-view target and scan
    in_view = 0
    for t, _ in sim.detections:
        tr = sim.truth_at(t)
        los = (tr.target_pos - tr.vehicle.pos_ned) @ mav_R(tr.vehicle.q)
        in_view += int(radar.in_view(Radar.to_spherical(los)).sum())
    assert len(sim.detections) == scans
    assert in_view > 2 * scans
    assert len(res) / in_view == pytest.approx(radar.pd, abs=0.03)
    # ADS-B: ~1 Hz per transponder-equipped aircraft, simulated flag, callsigns
    by = {}
    for m in adsb:
        by.setdefault(m.ICAO_address, []).append(m)
    assert set(by) == {0x4B1801, 0x4B1802, 0x4B1803}  # UAV4 has adsb = false
    for ms in by.values():
        assert len(ms) == pytest.approx(150, abs=2)
        assert all(m.flags & mav2.ADSB_FLAGS_SIMULATED for m in ms)
    assert by[0x4B1802][0].callsign == "CROSS2"


def mav_R(q):
    from uavest.geometry.rotation import quat_to_dcm

    return quat_to_dcm(np.asarray(q, float))


# ----------------------------------------------------------------------- tlog-based checks


def read_tlog(path):
    """(timestamp s, message) of every record, checking that every record is whole."""
    data = Path(path).read_bytes()
    out, i = [], 0
    parser = mav2.MAVLink(None)
    while i < len(data):
        assert i + 8 + 12 <= len(data), "truncated record header"
        (ts,) = struct.unpack(">Q", data[i:i + 8])
        assert data[i + 8] == 0xFD, "not a MAVLink 2 frame"
        n = data[i + 9] + 12 + (13 if data[i + 10] & 1 else 0)
        frame = data[i + 8:i + 8 + n]
        assert len(frame) == n, "truncated frame"
        msgs = parser.parse_buffer(frame)
        assert msgs and len(msgs) == 1, "frame did not parse (CRC)"
        out.append((ts * 1e-6, msgs[0]))
        i += 8 + n
    return out


def make_log(tmp_path, name="a", seed=0, sets=(), rates=None, duration=20.0, imu_rate=200.0):
    sc = load_typed("sim_default", list(sets))
    sim = Simulator(sc, seed=seed, imu_rate=imu_rate,
                    rates=rates or {"RAW_IMU": imu_rate, "SIMSTATE": imu_rate, "ATTITUDE": 50,
                                    "GPS_RAW_INT": 5, "GLOBAL_POSITION_INT": 10})
    path = tmp_path / f"{name}.tlog"
    s = sim.run(None, duration=duration, speed=0, tlog=path)
    assert s.reason == "duration"
    return sim, path


@pytest.mark.slow
def test_simstate_consistent_with_imu(tmp_path):
    sim, path = make_log(tmp_path, duration=20.0, imu_rate=200.0)
    recs = read_tlog(path)
    epoch = sim.epoch
    imu = [(m.time_usec * 1e-6, m) for _, m in recs if m.get_type() == "RAW_IMU"]
    ss = [(ts - epoch, m) for ts, m in recs if m.get_type() == "SIMSTATE"]
    assert len(imu) == len(ss) == 20 * 200 + 1
    t_imu = np.array([t for t, _ in imu])
    t_ss = np.array([t for t, _ in ss])
    assert np.allclose(t_imu, t_ss, atol=1e-6)  # tlog clock = boot clock + epoch
    gyro = np.array([[m.xgyro, m.ygyro, m.zgyro] for _, m in imu]) * 1e-3  # mrad/s
    acc = np.array([[m.xacc, m.yacc, m.zacc] for _, m in imu]) * 1e-3 * G0
    mag = np.array([[m.xmag, m.ymag, m.zmag] for _, m in imu]) * 1e-3  # gauss
    eul = np.array([[m.roll, m.pitch, m.yaw] for _, m in ss])
    q_ss = euler_to_quat(eul[:, 0], eul[:, 1], eul[:, 2])
    dt = 1.0 / 200
    worst = 0.0
    for t0 in (5.0, 12.0, 15.0):  # roll / pitch oscillations (rates up to ~0.5 rad/s)
        k0, k1 = int(t0 * 200), int((t0 + 1.0) * 200)
        b = sim.truth_at(t0).vehicle.gyro_bias  # a random walk: ~constant over 1 s
        q = q_ss[k0]
        for k in range(k0, k1):  # trapezoid of the bias-corrected rates
            w = 0.5 * (gyro[k] + gyro[k + 1]) - b
            q = quat_mul(q, quat_exp(w * dt))
        err = np.linalg.norm(quat_log(quat_mul(np.array([q[0], *(-q[1:])]), q_ss[k1])))
        rot = np.linalg.norm(quat_log(quat_mul(np.array([q_ss[k0][0], *(-q_ss[k0][1:])]),
                                               q_ss[k1])))
        assert rot > np.deg2rad(10)  # a real rotation happened
        worst = max(worst, err)
    assert worst < np.deg2rad(0.3)
    # without the bias correction the error is larger: the bias is really in the gyro
    b = sim.truth_at(5.0).vehicle.gyro_bias
    assert np.linalg.norm(b) > 0.003
    # accelerometer: 1 s mean (vibration averages out) equals SIMSTATE specific force + bias
    f_ss = np.array([[m.xacc, m.yacc, m.zacc] for _, m in ss])
    ba = sim.truth_at(19.0).vehicle.accel_bias
    assert np.allclose(acc[-200:].mean(0) - ba, f_ss[-200:].mean(0), atol=0.03)
    # magnetometer: tilt-compensated heading - declination = SIMSTATE yaw
    decl = np.deg2rad(3.0)
    from uavest.geometry.rotation import quat_rotate

    m_ned = quat_rotate(q_ss, mag)  # body field rotated to NED with the true attitude
    heading = np.arctan2(m_ned[:, 1], m_ned[:, 0])
    assert np.allclose(np.angle(np.exp(1j * (heading - decl))).mean(), 0.0, atol=0.01)
    # ATTITUDE ("autopilot") differs from truth by a slowly varying ~1-2 deg error
    att = [(m.time_boot_ms, m) for _, m in recs if m.get_type() == "ATTITUDE"]
    idx = [int(round(tm * 1e-3 * 200)) for tm, _ in att]
    da = np.array([[m.roll, m.pitch] for _, m in att]) - eul[idx, :2]
    rms = np.sqrt(np.mean(da**2))
    assert np.deg2rad(0.2) < rms < np.deg2rad(4)


def test_hil_state_quaternion_is_the_true_state(tmp_path):
    """HIL_STATE_QUATERNION (asked for by interval, as of PX4 SITL) carries the vehicle's
    true attitude, position and velocity at its stamp, to its fields' resolution; read
    through uavest's converter it is a truth reference with a position."""
    from uavest.ingest.convert import convert_mavlink

    sim, path = make_log(tmp_path, duration=10.0, imu_rate=100.0,
                         rates={"RAW_IMU": 1, "HIL_STATE_QUATERNION": 20})
    recs = [m for _, m in read_tlog(path) if m.get_type() == "HIL_STATE_QUATERNION"]
    assert len(recs) == pytest.approx(200, abs=2)
    for m in recs[::7]:
        v = sim.truth_at(m.time_usec * 1e-6).vehicle
        ref, pos = convert_mavlink(m)
        assert ref.kind == "truth" and ref.source == pos.source == "HIL_STATE_QUATERNION"
        q = ref.values[0]
        assert min(np.abs(q - v.q).max(), np.abs(q + v.q).max()) < 1e-6
        _, vel, lla = pos.values
        np.testing.assert_allclose(vel, v.vel_ned, atol=0.006)  # cm/s
        np.testing.assert_allclose(lla[:2], v.lla[:2], atol=1.5e-7)  # degE7
        assert lla[2] == pytest.approx(v.lla[2], abs=0.0006)  # mm
        np.testing.assert_allclose([m.rollspeed, m.pitchspeed, m.yawspeed], v.omega,
                                   atol=1e-6)


@pytest.mark.parametrize("sets, acc", [
    ((), (800, 1500, 150)),  # the default receiver: sigma_h, sigma_v, 1.5 x sigma_vel
    (("gps.sigma_h=2.5", "gps.sigma_v=4", "gps.sigma_vel=0.2", "gps.speed_acc_scale=1"),
     (2500, 4000, 200)),
    (("gps.sigma_h=0",), (1, 1500, 150)),  # 0 would be "not reported"
])
def test_gps_raw_int_reports_the_scenarios_accuracies(tmp_path, sets, acc):
    """GPS_RAW_INT's h_acc / v_acc / vel_acc (mm, mm/s) are the scenario's receiver, not
    the default's: a filter takes them as the fix's accuracy."""
    _, path = make_log(tmp_path, sets=sets, duration=3.0, imu_rate=100.0,
                       rates={"RAW_IMU": 1, "GPS_RAW_INT": 5})
    fixes = [m for _, m in read_tlog(path) if m.get_type() == "GPS_RAW_INT" and m.fix_type == 3]
    assert len(fixes) >= 10
    assert {(m.h_acc, m.v_acc, m.vel_acc) for m in fixes} == {acc}


def test_adsb_matches_targets(tmp_path):
    pm = pytest.importorskip("pymap3d")
    sim, path = make_log(tmp_path, duration=30.0, imu_rate=100.0, rates={"RAW_IMU": 1})
    o = sim.sc.origin
    recs = [(ts - sim.epoch, m) for ts, m in read_tlog(path) if m.get_type() == "ADSB_VEHICLE"]
    assert len(recs) == pytest.approx(90, abs=3)
    errs = []
    for t, m in recs:
        tr = sim.truth_at(t)
        j = tr.target_icao.index(m.ICAO_address)
        n, e, d = pm.geodetic2ned(m.lat * 1e-7, m.lon * 1e-7, m.altitude * 1e-3,
                                  o.lat_deg, o.lon_deg, o.alt_m)
        errs.append(np.array([n, e, d]) - tr.target_pos[j])
        v = tr.target_vel[j]
        assert m.hor_velocity * 1e-2 == pytest.approx(np.hypot(v[0], v[1]), abs=1.5)
        hd = np.rad2deg(np.arctan2(v[1], v[0])) % 360
        assert abs((m.heading * 1e-2 - hd + 180) % 360 - 180) < 5
        assert m.ver_velocity * 1e-2 == pytest.approx(-v[2], abs=1.5)
    errs = np.array(errs)
    assert np.all(np.abs(errs.mean(0)) < 2.0)
    assert np.all(errs[:, :2].std(0) < 4.5) and errs[:, 2].std() < 7.0


@pytest.mark.slow
def test_determinism_and_stream_independence(tmp_path):
    _, a = make_log(tmp_path, "a", seed=3, duration=5.0)
    _, b = make_log(tmp_path, "b", seed=3, duration=5.0)
    _, c = make_log(tmp_path, "c", seed=4, duration=5.0)
    _, d = make_log(tmp_path, "d", seed=3, duration=5.0,
                    sets=["radar.pd=0.5", "radar.clutter_rate=10"])
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    imu = [[(m.xacc, m.ygyro, m.zmag) for _, m in read_tlog(p) if m.get_type() == "RAW_IMU"]
           for p in (a, c, d)]
    assert imu[0] == imu[2]  # radar config does not move the IMU noise
    assert imu[0] != imu[1]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_subprocess_signal_leaves_whole_tlog(tmp_path, sig):
    path = tmp_path / "int.tlog"
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen(
        [sys.executable, "-m", "uavest.cli.sim", "--out", f"udpout:127.0.0.1:{port}",
         "--speed", "1", "--imu-rate", "200", "--rate", "RAW_IMU=200", "--rate", "EXTRA1=50",
         "--tlog", str(path)],
        cwd=ROOT, env=env, stderr=subprocess.PIPE, text=True)
    try:
        t_end = time.monotonic() + 30
        while time.monotonic() < t_end and (not path.exists() or path.stat().st_size < 20000):
            time.sleep(0.1)
        assert p.poll() is None, p.stderr.read()
        p.send_signal(sig)
        # stderr read while waiting (a full pipe would hold the exit); what it said is in
        # the failure when the exit does not come (once in a loaded CI run, not reproduced)
        try:
            _, err = p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
            pytest.fail(f"no exit 30 s after signal {sig}; stderr: {err}")
        rc = p.returncode
    finally:
        if p.poll() is None:
            p.kill()
    assert rc == 0, err
    assert "stopped" in err
    recs = read_tlog(path)  # every record whole
    kinds = {m.get_type() for _, m in recs}
    assert {"HEARTBEAT", "RAW_IMU", "ATTITUDE", "SIMSTATE"} <= kinds
    ts = np.array([t for t, _ in recs])
    assert np.all(np.diff(ts) >= 0)


def test_targets_repeat_with_period():
    sim = Simulator(load_typed("sim_default"))
    P, _ = sim.targets.state_at(np.array([10.0, 130.0, 250.0]))
    assert np.allclose(P[1, 0], P[1, 1]) and np.allclose(P[1, 0], P[1, 2])  # CROSS2
    assert not np.allclose(P[0, 0], P[0, 1])  # ORBIT1 has no period


def test_cli_rejects_bad_arguments(capsys):
    from uavest.cli.sim import main

    assert main(["--out", "none", "--speed", "0"]) == 2  # no duration
    assert main(["ungm", "--out", "none", "--duration", "1"]) == 2  # not a sim scenario
    assert main(["--out", "none", "--duration", "1", "--speed", "-1"]) == 2
    assert main(["--out", "none", "--duration", "1", "--rate", "NOPE=3"]) == 2
    assert "unknown message" in capsys.readouterr().err


@pytest.mark.slow
def test_committed_log(tmp_path):
    """logs/sim_200hz.tlog is whole, as documented, and reproduced by its command
    (logs/README.md). If the simulator changes on purpose, regenerate it with that command."""
    log = ROOT / "logs" / "sim_200hz.tlog"
    assert log.stat().st_size < 3_000_000
    recs = read_tlog(log)
    kinds = {}
    for _, m in recs:
        kinds.setdefault(m.get_type(), []).append(m)
    t = np.array([m.time_usec for m in kinds["RAW_IMU"]]) * 1e-6
    assert 30 <= t[-1] - t[0] <= 60.5 and np.allclose(np.diff(t), 0.005)
    assert len(kinds["SIMSTATE"]) == len(kinds["RAW_IMU"])
    assert len(kinds["HIL_STATE_QUATERNION"]) == pytest.approx(len(kinds["RAW_IMU"]) / 4, abs=2)
    assert {"ATTITUDE", "GPS_RAW_INT", "GLOBAL_POSITION_INT", "OBSTACLE_DISTANCE_3D",
            "ADSB_VEHICLE", "HEARTBEAT"} <= set(kinds)
    dec = [m for m in kinds["PARAM_VALUE"] if m.param_id == "COMPASS_DEC"]
    assert dec and dec[0].param_value == pytest.approx(np.deg2rad(3.0), abs=1e-6)
    cmd = (ROOT / "logs" / "README.md").read_text().split("```")[1].split()
    from uavest.cli.sim import main

    i = cmd.index("--tlog")
    cmd[i + 1] = str(tmp_path / "again.tlog")
    assert main(cmd[3:]) == 0  # drop "python -m uavest.cli.sim"
    assert (tmp_path / "again.tlog").read_bytes() == log.read_bytes()


def test_truth_csv(tmp_path):
    import csv

    from uavest.cli.sim import main
    from uavest.sim.mavlink import TRUTH_COLUMNS

    out = tmp_path / "truth.csv"
    assert main(["--out", "none", "--duration", "10", "--speed", "0", "--imu-rate", "100",
                 "--truth", str(out), "--truth-rate", "5", "--quiet"]) == 0
    rows = list(csv.DictReader(out.open()))
    assert tuple(rows[0]) == TRUTH_COLUMNS
    veh = [r for r in rows if r["kind"] == "vehicle"]
    tgt = [r for r in rows if r["kind"] == "target"]
    det = [r for r in rows if r["kind"] == "det"]
    assert len(veh) == 51 and len(tgt) == 4 * 51
    sim = Simulator(load_typed("sim_default"))
    for r in tgt[::17]:
        P, _ = sim.targets.state_at(float(r["t"]))
        assert np.allclose([float(r[k]) for k in "ned"], P[int(r["origin"])], atol=1e-3)
    assert det and all((r["id"] == "65535") == (r["origin"] == "-1") for r in det)
    assert abs(float(veh[-1]["d"]) + 30.0) < 1.0  # hovering 30 m above the origin
