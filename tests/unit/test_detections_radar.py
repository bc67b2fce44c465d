"""Detection geometry, scans, the ADS-B virtual radar, geodesy and declination (no network)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from uavest.geometry.magnetic import decimal_year, declination
from uavest.geometry.rotation import euler_to_quat, quat_rotate
from uavest.ingest import (
    AdsbSample,
    AttitudeRef,
    DetectionSample,
    DetectionScan,
    PositionSample,
    attach_pose,
    group_scans,
    open_source,
    rae_from_frd,
    to_sensor_frame,
)
from uavest.ingest.adsb_radar import AdsbRadar, RadarConfig, geodetic_to_ned, virtual_radar
from uavest.ingest.detections import frd_from_rae
from uavest.link import endpoint_key, signing_key_bytes


def test_rae_matches_the_radar_model_conventions():
    from uavest.models.radar import RadarMeasurement, SensorPose

    rng = np.random.default_rng(1)
    for _ in range(20):
        q = euler_to_quat(*rng.uniform(-0.5, 0.5, 3))
        own = rng.normal(size=3) * 100
        tgt = rng.normal(size=3) * 500
        rae = rae_from_frd(to_sensor_frame(tgt, "LOCAL_NED", q, own))
        pose = SensorPose.from_ned_frd(q, own)
        T = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])  # NED -> ENU
        model = RadarMeasurement(ndim=3, state_dim=6, sigma_range=1, sigma_az=0.01,
                                 sigma_el=0.01, pose=pose)
        z = model.h(np.concatenate([T @ tgt, np.zeros(3)])[None, :])[0]
        assert rae == pytest.approx(z, abs=1e-9)
        assert frd_from_rae(rae) == pytest.approx(quat_rotate(q.conj() * [1, -1, -1, -1],
                                                              tgt - own), abs=1e-6)


def test_to_sensor_frame_body_ned_and_errors():
    q = euler_to_quat(0.0, 0.0, math.pi / 2)  # facing east
    d = to_sensor_frame(np.array([0.0, 10.0, 0.0]), "BODY_NED", q)  # 10 m east
    assert d == pytest.approx([10.0, 0.0, 0.0], abs=1e-9)  # straight ahead
    with pytest.raises(ValueError, match="attitude"):
        to_sensor_frame(np.ones(3), "BODY_NED", None)
    with pytest.raises(ValueError, match="position"):
        to_sensor_frame(np.ones(3), "LOCAL_NED", q, None)


def _det(t, x, frame="BODY_FRD", src="OBSTACLE_DISTANCE_3D"):
    xyz = np.array(x, float)
    return DetectionSample(t, 65535, xyz, frame, rae_from_frd(xyz) if frame == "BODY_FRD"
                           else None, 0.1, 500.0, src)


def test_group_scans_by_shared_time_and_window():
    pos = PositionSample(1.05, np.zeros(3), None, None, "LOCAL_POSITION_NED")
    stream = [_det(1.0, [10, 0, 0]), _det(1.0, [20, 0, 0]), pos, _det(1.1, [30, 0, 0]),
              _det(1.12, [40, 0, 0])]
    out = list(group_scans(stream))
    scans = [s for s in out if isinstance(s, DetectionScan)]
    assert [len(s) for s in scans] == [2, 1, 1]
    assert out.index(scans[0]) < out.index(pos)  # emitted before the later sample
    out = list(group_scans(stream, window=0.05))
    assert [len(s) for s in out if isinstance(s, DetectionScan)] == [2, 2]


def test_attach_pose_fills_world_frame_detections():
    q = euler_to_quat(0.0, 0.0, math.pi)  # facing south
    stream = [AttitudeRef(0.9, q, "autopilot", "ATTITUDE"),
              PositionSample(0.95, np.array([100.0, 0, 0]), None, None, "LOCAL_POSITION_NED"),
              _det(1.0, [50.0, 0, 0], frame="LOCAL_NED"), _det(3.0, [50.0, 0, 0], "LOCAL_NED")]
    d1, d2 = [s for s in attach_pose(stream) if isinstance(s, DetectionSample)]
    assert d1.rae == pytest.approx([50.0, 0.0, 0.0], abs=1e-9)  # 50 m south = ahead
    assert d1.sensor_ned == pytest.approx([100, 0, 0]) and d1.q is not None
    assert d2.rae is None  # pose too old


def _stream(n_scans=200, icaos=(0x10, 0x11), period=1.0):
    """Ownship fixed at the origin, aircraft at fixed positions, reports every 0.5 s."""
    own = np.array([-35.0, 149.0, 500.0])
    out = []
    for k in range(int(n_scans / period * 2)):
        t = 0.5 * k
        out.append(PositionSample(t, None, np.zeros(3), own, "GLOBAL_POSITION_INT"))
        for i, icao in enumerate(icaos):
            lla = own + [0.01 * (i + 1), 0.005, 100.0 * (i + 1)]
            out.append(AdsbSample(t + 0.01, icao, lla, np.zeros(3), "geometric", "X", 0x1F, 0))
    return own, out


def test_virtual_radar_geometry_pd_clutter_and_seed():
    own, stream = _stream()
    cfg = RadarConfig(sigma_r=5.0, sigma_az=0.01, sigma_el=0.01, pd=0.8, clutter_rate=2.0,
                      max_range=20_000.0)
    radar = AdsbRadar(np.random.default_rng(42), cfg)
    scans = [s for s in virtual_radar(stream, None, radar=radar) if isinstance(s, DetectionScan)]
    n = len(scans)
    assert n >= 190
    hits = {0x10: [], 0x11: []}
    clutter = 0
    for sc in scans:
        for d, o in zip(sc.detections, sc.origin, strict=True):
            if o is None:
                clutter += 1
            else:
                hits[o].append(d.rae)
    for i, icao in enumerate((0x10, 0x11)):
        k = len(hits[icao])
        p = 0.8
        assert abs(k - p * n) < 4 * math.sqrt(n * p * (1 - p))  # binomial, 4 sigma
        ned = geodetic_to_ned(own + [0.01 * (i + 1), 0.005, 100.0 * (i + 1)], own)
        true = rae_from_frd(ned)  # level north-aligned sensor at the origin
        z = np.array(hits[icao])
        tol = 4 * np.array([5, 0.01, 0.01]) / math.sqrt(k)
        assert np.all(np.abs(z.mean(axis=0) - true) < tol)
        assert z[:, 0].std() == pytest.approx(5.0, rel=0.2)
        t, states = radar.truth_arrays()[icao]
        assert states[0, :3] == pytest.approx(ned, abs=1e-6)
    assert abs(clutter - 2.0 * n) < 4 * math.sqrt(2.0 * n)  # Poisson, 4 sigma
    # same seed, same scans; another seed, other scans
    again = [s for s in virtual_radar(stream, np.random.default_rng(42), cfg)
             if isinstance(s, DetectionScan)]
    assert all(np.array_equal(a.detections[j].rae, b.detections[j].rae)
               for a, b in zip(scans, again, strict=True) for j in range(len(a)))
    other = [s for s in virtual_radar(stream, np.random.default_rng(43), cfg)
             if isinstance(s, DetectionScan)]
    assert [len(s) for s in other] != [len(s) for s in scans]


def test_virtual_radar_max_range_and_new_address_is_new_truth():
    own, stream = _stream(n_scans=20, icaos=(0x20,))
    cfg = RadarConfig(pd=1.0, clutter_rate=0.0, max_range=500.0)  # the aircraft is ~1.1 km
    radar = AdsbRadar(np.random.default_rng(0), cfg)
    scans = [s for s in virtual_radar(stream, None, radar=radar) if isinstance(s, DetectionScan)]
    assert sum(len(s) for s in scans) == 0 and 0x20 in radar.truth
    assert all(s.truth == {} for s in scans)
    with pytest.raises(TypeError, match="Generator"):
        AdsbRadar(42)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="pd"):
        RadarConfig(pd=1.5)


def test_geodetic_to_ned_matches_pymap3d():
    pm = pytest.importorskip("pymap3d")
    o = np.array([-35.3632, 149.1652, 584.0])
    p = np.array([-35.30, 149.25, 1500.0])
    ours = geodetic_to_ned(p, o)
    ref = pm.geodetic2ned(*p, *o)
    assert ours == pytest.approx(ref, abs=1e-3)


def test_declination_wmm():
    # Canberra (SITL home) ~ +12 deg east; London ~ +1 deg; Boulder ~ +7.5 deg (2025-2026)
    assert math.degrees(declination(-35.3632, 149.1652, 584, 2026.0)) == pytest.approx(12.3,
                                                                                      abs=1.0)
    assert math.degrees(declination(51.5, -0.12, 0, 2026.0)) == pytest.approx(1.0, abs=1.5)
    assert math.degrees(declination(40.0, -105.3, 1600, 2026.0)) == pytest.approx(7.6, abs=1.0)
    from datetime import datetime

    assert decimal_year(datetime(2026, 7, 2, 12)) == pytest.approx(2026.5, abs=0.01)
    with pytest.raises(ValueError, match="WMM2025"):
        declination(0, 0, 0, 2040.0)
    with pytest.raises(ValueError, match="non-finite"):
        declination(math.nan, 0, 0, 2026.0)


def test_signing_key_and_endpoints(tmp_path):
    import hashlib

    assert signing_key_bytes("abc") == hashlib.sha256(b"abc").digest()
    f = tmp_path / "k.bin"
    f.write_bytes(bytes(range(32)))
    assert signing_key_bytes(str(f)) == bytes(range(32))
    g = tmp_path / "k.txt"
    g.write_text("pass phrase\n")
    assert signing_key_bytes(g) == hashlib.sha256(b"pass phrase").digest()
    with pytest.raises(ValueError):
        signing_key_bytes(b"short")
    assert endpoint_key("udpin:0.0.0.0:14550") == endpoint_key("udpout:localhost:14550")
    assert endpoint_key("tcp:127.0.0.1:5760") != endpoint_key("udp:127.0.0.1:5760")
    assert endpoint_key("/dev/ttyACM0,57600") == endpoint_key("/dev/ttyACM0")


class _Buf:
    def __init__(self) -> None:
        self.b = b""

    def write(self, x) -> None:
        self.b += bytes(x)


def test_tlog_adsb_timed_from_receive_time_minus_tslc(tmp_path):
    buf = _Buf()
    mav = mavlink.MAVLink(buf, srcSystem=1, srcComponent=1)
    rec = bytearray()

    def put(t_rx: float) -> None:
        rec.extend(struct.pack(">Q", int(t_rx * 1e6)) + buf.b)
        buf.b = b""

    t0 = 1.7e9
    for k in range(30):
        mav.attitude_send(1000 + 100 * k, 0, 0, 0, 0, 0, 0)
        put(t0 + 0.1 * k)
        if k in (4, 14):  # the same report, re-sent 1 s later with tslc + 1
            mav.adsb_vehicle_send(0x42, -353600000, 1491700000, 1, 700000, 9000, 5000, 100,
                                  b"A", 1, 2 if k == 4 else 3, 0x1F, 0)
            put(t0 + 0.1 * k + 0.05)
    mav.obstacle_distance_3d_send(3900, 3, 12, 1, 1.0, 1.0, 1.0, 5.0, 10.0)  # too close
    put(t0 + 2.95)
    mav.obstacle_distance_3d_send(3900, 3, 0, 1, 1.0, 1.0, 1.0, 0.5, 10.0)  # GLOBAL frame
    put(t0 + 2.96)
    p = tmp_path / "a.tlog"
    p.write_bytes(bytes(rec))
    src = open_source(p)
    out = list(src)
    ad = [s for s in out if isinstance(s, AdsbSample)]
    assert len(ad) == 1 and ad[0].tslc == 2.0
    assert ad[0].t == pytest.approx(1.4 + 0.05, abs=1e-6)  # last ATTITUDE 1.4 s + 0.05 s rx
    assert src.stats.duplicate == 1  # the re-sent report: same position time, same content
    assert src.stats.out_of_range == 1 and src.stats.unknown_frame == 1


def test_virtual_radar_sensor_axes():
    own = np.array([-35.0, 149.0, 500.0])
    east = own + [0.0, 1000.0 / (111_320 * math.cos(math.radians(35.0))), 0.0]
    cfg = dict(pd=1.0, clutter_rate=0.0, sigma_r=0.0, sigma_az=0.0, sigma_el=0.0)
    stream = [AttitudeRef(0.0, euler_to_quat(0.0, 0.0, math.pi / 2), "autopilot", "ATTITUDE"),
              PositionSample(0.0, None, np.zeros(3), own, "GLOBAL_POSITION_INT"),
              AdsbSample(0.1, 0x30, east, np.zeros(3), "geometric", "E", 0x1F, 0),
              PositionSample(1.5, None, np.zeros(3), own, "GLOBAL_POSITION_INT")]
    level = [s for s in virtual_radar(stream, np.random.default_rng(0), RadarConfig(**cfg))
             if isinstance(s, DetectionScan)][0].detections[0]
    body = [s for s in virtual_radar(stream, np.random.default_rng(0),
                                     RadarConfig(attitude="autopilot", **cfg))
            if isinstance(s, DetectionScan)][0].detections[0]
    assert level.frame == "BODY_NED" and body.frame == "BODY_FRD"
    assert level.rae[0] == pytest.approx(1000.0, rel=2e-3)
    assert level.rae[1] == pytest.approx(-math.pi / 2, abs=3e-3)  # east = right of north
    assert body.rae[1] == pytest.approx(0.0, abs=3e-3)  # facing east: dead ahead
    assert abs(body.rae[2]) < 1e-3  # same altitude: level (earth curvature ~8e-5 rad)
