"""Frames and conversions of the recording channels (NED/FRD -> ENU/FLU), the Euler
3-sigma linearisation, the protobuf decoder, layouts."""

import json

import numpy as np
import pytest

from uavest.geometry.rotation import euler_to_quat, quat_exp, quat_mul, quat_to_dcm, quat_to_euler
from uavest.layouts import build_layout, colour, layout_text, shipped
from uavest.report.protowire import ProtoDecoder
from uavest.sinks.foxglove import euler_sigma_deg, ned_frd_to_enu_flu, quat_to_rpy_deg
from uavest.sinks.foxglove.attitude import _nees_rows, _rpy_rows, _sigma3_rows
from uavest.sinks.foxglove.frames import _enu_flu_rows

A_NED2ENU = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])
B_FLU2FRD = np.diag([1.0, -1, -1])


def _random_q(rng, n):
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_enu_flu_conversion_matches_the_matrices():
    q = _random_q(np.random.default_rng(1), 50)
    qe = ned_frd_to_enu_flu(q)
    # v_enu = A v_ned = A R(q) v_frd = A R(q) B v_flu
    np.testing.assert_allclose(quat_to_dcm(qe), A_NED2ENU @ quat_to_dcm(q) @ B_FLU2FRD,
                               atol=1e-12)
    # the recorder's written-out form
    np.testing.assert_allclose(_enu_flu_rows(q), qe, atol=1e-12)


def test_enu_flu_known_attitudes():
    # level, nose north: the FLU nose points ENU north, left points west, up is up
    R = quat_to_dcm(ned_frd_to_enu_flu(np.array([1.0, 0, 0, 0])))
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 1, 0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 0, 1], atol=1e-12)
    # yaw 90 deg (nose east), roll 30 deg right wing down: nose east, FLU up tilts south
    q = euler_to_quat(np.deg2rad(30.0), 0.0, np.deg2rad(90.0))
    R = quat_to_dcm(ned_frd_to_enu_flu(q))
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 0, 1], [0, -np.sin(np.pi / 6), np.cos(np.pi / 6)],
                               atol=1e-12)


def test_euler_sigma_matches_a_numerical_jacobian():
    rng = np.random.default_rng(2)
    q = euler_to_quat(0.4, -0.3, 2.0)
    L = rng.standard_normal((3, 3)) * 0.01
    P = np.zeros((6, 6))
    P[:3, :3] = L @ L.T + 1e-6 * np.eye(3)
    h = 1e-6
    J = np.empty((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        J[:, i] = (quat_to_euler(quat_mul(q, quat_exp(d)))
                   - quat_to_euler(quat_mul(q, quat_exp(-d)))) / (2 * h)
    want = np.degrees(np.sqrt(np.diag(J @ P[:3, :3] @ J.T)))
    np.testing.assert_allclose(euler_sigma_deg(q, P), want, rtol=1e-5)
    np.testing.assert_allclose(_sigma3_rows(np.array([quat_to_rpy_deg(q)]), P[None, :3, :3])[0],
                               3 * want, rtol=1e-5)
    np.testing.assert_allclose(quat_to_rpy_deg(q), np.degrees(quat_to_euler(q)), atol=1e-12)


def test_protobuf_decoder_round_trips_a_foxglove_message():
    from foxglove.messages import FrameTransform, Quaternion, Timestamp, Vector3

    m = FrameTransform(timestamp=Timestamp(12, 345), parent_frame_id="world",
                       child_frame_id="body_ekf", translation=Vector3(x=1.5, y=-2.0, z=3.25),
                       rotation=Quaternion(x=0.1, y=0.2, z=0.3, w=0.9))
    dec = ProtoDecoder(FrameTransform.get_schema().data)
    d = dec.decode(m.encode(), "foxglove.FrameTransform")
    assert d == {"timestamp": {"seconds": 12, "nanos": 345}, "parent_frame_id": "world",
                 "child_frame_id": "body_ekf",
                 "translation": {"x": 1.5, "y": -2.0, "z": 3.25},
                 "rotation": {"x": 0.1, "y": 0.2, "z": 0.3, "w": 0.9}}


def test_shipped_layouts_are_the_generated_ones():
    for kind in ("attitude", "radar"):
        assert shipped(kind) == layout_text(["ekf", "ukf", "hybrid"], kind)
        lay = json.loads(shipped(kind))
        ids = set(lay["configById"])

        def leaves(node):
            if isinstance(node, str):
                return {node}
            return leaves(node["first"]) | leaves(node["second"])

        assert leaves(lay["layout"]) == ids
    lay = build_layout(["ekf", "a_new_one"])
    paths = [p["value"] for p in lay["configById"]["Plot!uavest_err_roll"]["paths"]]
    assert "/attitude/a_new_one/error.err_deg.roll" in paths
    assert "/attitude/a_new_one/error.neg_sigma3_deg.roll" in paths
    with pytest.raises(ValueError):
        build_layout(["ekf"], "sonar")


def test_colours_are_fixed_per_label():
    assert colour("ekf") == "#1f77b4" and colour("ukf") != colour("ekf")
    assert colour("ukf(alpha=0.1)") == colour("ukf(alpha=0.1)")
    assert len({colour(x) for x in ("ekf", "ukf", "hybrid", "enkf", "pf")}) == 5


def test_track_ellipsoid_is_three_sigma_along_the_principal_axes():
    from uavest.geometry.rotation import quat_to_dcm
    from uavest.sinks.foxglove.radar import _ellipsoid

    c, s = np.cos(0.5), np.sin(0.5)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    P = R @ np.diag([100.0**2, 50.0**2, 10.0**2]) @ R.T
    size, q = _ellipsoid(P)
    Rq = quat_to_dcm(np.array(q))
    # the ellipsoid x Rq diag(size/2)^2 Rq^T is 3-sigma: (3 sigma)^2 along each axis
    D = np.diag((np.array(size) / 2) ** 2)
    np.testing.assert_allclose(Rq @ D @ Rq.T, 9 * P, rtol=1e-9)
    assert sorted(size) == pytest.approx([60.0, 300.0, 600.0])


def test_publisher_survives_a_diverged_filter(tmp_path):
    """NaN covariance and pitch 90 deg are written as null, not an exception."""
    import foxglove

    from uavest.engine.records import StepRecord
    from uavest.report import read_recording
    from uavest.sinks.foxglove import FoxglovePublisher

    ctx = foxglove.Context()
    w = foxglove.open_mcap(str(tmp_path / "nan.mcap"), context=ctx)
    pub = FoxglovePublisher(ctx)
    q90 = euler_to_quat(0.0, np.pi / 2, 0.0)
    pub.record(StepRecord("ekf", 1, 1.0, np.r_[q90, 0, 0, 0], np.eye(6) * 1e-4))
    pub.record(StepRecord("ekf", 2, 2.0, np.r_[1.0, 0, 0, 0, 0, 0, 0], np.full((6, 6), np.nan)))
    pub.record(StepRecord("ekf", 3, 3.0, np.r_[1.0, 0, 0, 0, 0, 0, 0], np.eye(6), reset=True,
                          reason="NIS above the gate 5 times", resets=1))
    pub.close()
    w.close()
    rec = read_recording(tmp_path / "nan.mcap")
    logs = rec.decode("/log")
    assert [m["level"] for m in logs] == [3]  # WARNING
    assert "NIS above the gate 5 times" in logs[0]["message"]
    hl = rec.json["/attitude/ekf/health"]
    assert [m["reset"] for m in hl] == [False, False, True] and hl[-1]["resets"] == 1
    est = rec.json["/attitude/ekf/estimate"]
    assert [m["k"] for m in est] == [1, 2, 3]
    assert est[0]["sigma3_deg"]["yaw"] is None and all(v is None for v in est[1]["P_triu"])


def test_row_functions_equal_the_one_attitude_forms():
    """The recorder's vectorised Euler angles, Euler 3-sigma and NEES equal the one-attitude
    functions (and the scorer's NEES); gimbal lock gives inf, a NaN covariance NaN."""
    from uavest.eval.attitude import nees_attitude

    rng = np.random.default_rng(3)
    q, qr = _random_q(rng, 40), _random_q(rng, 40)
    A = rng.standard_normal((40, 6, 6)) * 0.1
    P = A @ A.transpose(0, 2, 1) + 1e-3 * np.eye(6)
    rpy = _rpy_rows(q)
    np.testing.assert_allclose(rpy, [quat_to_rpy_deg(x) for x in q], atol=1e-12)
    np.testing.assert_allclose(_sigma3_rows(rpy, P[:, :3, :3]),
                               3 * euler_sigma_deg(q, P), rtol=1e-9)
    np.testing.assert_allclose(_nees_rows(q, qr, P[:, :3, :3]),
                               nees_attitude(q, P, qr), rtol=1e-9)
    q90 = euler_to_quat(0.0, np.pi / 2, 0.0)[None]
    s = _sigma3_rows(_rpy_rows(q90), np.eye(3)[None])
    assert np.isinf(s[0, 0]) and np.isinf(s[0, 2])
    bad = np.full((1, 3, 3), np.nan)
    assert np.isnan(_sigma3_rows(rpy[:1], bad)).all() and np.isnan(_nees_rows(q[:1], qr[:1], bad))
    assert np.isnan(_nees_rows(q[:1], qr[:1], np.zeros((1, 3, 3))))


def test_own_frame_encoding_equals_the_sdks():
    """/tf and /attitude/*/pose are encoded by the publisher: the same message as the
    SDK's FrameTransform / PoseInFrame encode, decoded with the SDK's schema (zeros too,
    which the SDK leaves out)."""
    import foxglove.messages as fm

    from uavest.sinks import protobuf as pb
    from uavest.sinks.foxglove import frames as fc

    dt = ProtoDecoder(fm.FrameTransform.get_schema().data)
    dp = ProtoDecoder(fm.PoseInFrame.get_schema().data)

    def full(d):  # proto3 defaults filled in
        out = {"timestamp": {"seconds": 0, "nanos": 0}, **d}
        out["timestamp"] = {"seconds": 0, "nanos": 0, **d.get("timestamp", {})}
        for k in ("translation", "rotation", "pose"):
            if k in out and k != "pose":
                out[k] = {**dict.fromkeys("xyz" + ("w" if k == "rotation" else ""), 0.0),
                          **out[k]}
        if "pose" in out:
            p = out["pose"]
            out["pose"] = {"position": {**dict.fromkeys("xyz", 0.0), **p.get("position", {})},
                           "orientation": {**dict.fromkeys("xyzw", 0.0),
                                           **p.get("orientation", {})}}
        return out

    rng = np.random.default_rng(4)
    for ns in (0, 7, 1_000_000_000, 123_456_789_012, 2**40 + 5):
        v = rng.standard_normal(7)
        v[rng.integers(0, 7)] = 0.0
        mine = (pb.timestamp_field(1, ns) + pb.len_field(2, b"world")
                + pb.len_field(3, b"body_ekf") + fc._TF_POSE.pack(*v))
        ts = fm.Timestamp(ns // 10**9, ns % 10**9)
        rot = fm.Quaternion(x=v[3], y=v[4], z=v[5], w=v[6])
        sdk = fm.FrameTransform(timestamp=ts, parent_frame_id="world",
                                child_frame_id="body_ekf",
                                translation=fm.Vector3(x=v[0], y=v[1], z=v[2]),
                                rotation=rot).encode()
        assert full(dt.decode(mine, "foxglove.FrameTransform")) == full(
            dt.decode(sdk, "foxglove.FrameTransform"))
        mine = pb.timestamp_field(1, ns) + fc._POSE_HEAD + fc._POSE.pack(*v)
        sdk = fm.PoseInFrame(timestamp=ts, frame_id="world", pose=fm.Pose(
            position=fm.Vector3(x=v[0], y=v[1], z=v[2]), orientation=rot)).encode()
        assert full(dp.decode(mine, "foxglove.PoseInFrame")) == full(
            dp.decode(sdk, "foxglove.PoseInFrame"))


def test_fixed_encoder_batches_decode_to_the_columns():
    """A batch of N messages from one FixedEncoder call decodes (our decoder) to the
    columns given, constant strings included; appended repeated fields decode too."""
    from uavest.sinks import protobuf as pb

    rng = np.random.default_rng(5)
    dec = ProtoDecoder(pb.DESCRIPTOR_SET)
    n = 17
    cols = {"t": rng.random(n), "k": np.arange(n), "err_deg": rng.standard_normal((n, 3)),
            "sigma3_deg": rng.random((n, 3)), "neg_sigma3_deg": -rng.random((n, 3)),
            "nees": np.r_[np.nan, rng.random(n - 1)]}
    enc = pb.FixedEncoder("AttitudeError", {"reference": "SIMSTATE", "kind": "truth"})
    msgs = enc.encode(n, cols)
    assert len(msgs) == n and {len(m) for m in msgs} == {enc.size}
    for i, m in enumerate(msgs):
        d = dec.decode(m, "uavest.AttitudeError")
        assert (d["reference"], d["kind"], d["k"]) == ("SIMSTATE", "truth", i)
        assert d["t"] == cols["t"][i]
        assert [d["err_deg"][a] for a in ("roll", "pitch", "yaw")] == cols["err_deg"][i].tolist()
        assert (np.isnan(d["nees"]) if i == 0 else d["nees"] == cols["nees"][i])
    h = pb.FixedEncoder("FilterHealth").encode(1, {"t": [2.0], "reset": [True]})[0]
    h += pb.update_bytes(5, "accel", 1.5, 3) + pb.field_bytes(7, "NIS gate")
    d = dec.decode(h, "uavest.FilterHealth")
    assert d["updates"] == [{"kind": "accel", "nis": 1.5, "dof": 3}]
    assert d["reset"] is True and d["reason"] == "NIS gate" and d["t"] == 2.0


def test_3d_channels_are_rate_limited_by_default(tmp_path):
    """At 250 Hz, the per-step channels carry every step and the 3-D channels the default
    rate of data time (DEFAULT_FRAME_RATE_HZ); frame_rate_hz=None gives every step."""
    from uavest.engine.records import RunInfo, StepRecord
    from uavest.report import read_recording
    from uavest.sinks.foxglove import DEFAULT_FRAME_RATE_HZ as R
    from uavest.sinks.mcap import McapSink

    recs = [StepRecord("ekf", k, k / 250.0, np.array([1.0, 0, 0, 0, 0, 0, 0]),
                       np.eye(6) * 1e-4) for k in range(1, 501)]
    counts = {}
    for name, kw in (("default", {}), ("every", {"frame_rate_hz": None})):
        sink = McapSink(tmp_path / f"{name}.mcap", **kw)
        sink.open(RunInfo("test", "synthetic", 0))
        for r in recs:
            sink.record(r)
        sink.close()
        rec = read_recording(tmp_path / f"{name}.mcap")
        assert rec.counts["/attitude/ekf/estimate"] == 500
        counts[name] = rec.counts["/tf/ekf"], rec.counts["/attitude/ekf/pose"]
        if name == "default":
            dt = np.diff(np.array(rec.log_times["/tf/ekf"])) * 1e-9
            assert dt.min() >= 1 / R - 1e-9
    assert counts["every"] == (500, 500)
    # 2 s of data: about 2 R frames (the first at once, then one per 1/R s, on the steps)
    assert 2 * R * 0.9 <= counts["default"][0] <= 2 * R + 1
    assert counts["default"][0] == counts["default"][1]
