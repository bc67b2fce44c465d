"""Frames and conversions of the recording channels (NED/FRD -> ENU/FLU), the Euler
3-sigma linearisation, the protobuf decoder, layouts."""

import json

import numpy as np
import pytest

from uavest.geometry.rotation import euler_to_quat, quat_exp, quat_mul, quat_to_dcm, quat_to_euler
from uavest.layouts import build_layout, colour, layout_text, shipped
from uavest.report.protowire import ProtoDecoder
from uavest.sinks.foxglove_channels import (
    _enu_flu,
    _sigma3_scalar,
    euler_sigma_deg,
    ned_frd_to_enu_flu,
    quat_to_rpy_deg,
)

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
    np.testing.assert_allclose(np.array([_enu_flu(x) for x in q]), qe, atol=1e-12)


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
    np.testing.assert_allclose(np.array(_sigma3_scalar(quat_to_rpy_deg(q), P.tolist())),
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
    from uavest.sinks.foxglove_channels import _ellipsoid

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
    from uavest.sinks.foxglove_channels import Publisher, b64_floats

    ctx = foxglove.Context()
    w = foxglove.open_mcap(str(tmp_path / "nan.mcap"), context=ctx)
    pub = Publisher(ctx)
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
    assert est[0]["sigma3_deg"]["yaw"] is None and np.isnan(b64_floats(est[1]["P_triu_b64"])).all()


def test_hot_path_json_text_is_valid_and_nan_becomes_null():
    from uavest.sinks.foxglove_channels import _EST_TPL, _fill, _g, _nees3, _neg, _rpy

    vals = (1.25, 3, 1.0, 0.0, 0.0, 0.0, 1e-3, -2e-3, 3e-4, 0.1, -0.2, 179.9)
    txt = _fill(_EST_TPL, vals) + '{"roll":1,"pitch":2,"yaw":3}}'
    m = json.loads(txt)
    assert m["t"] == 1.25 and m["k"] == 3 and m["bias_rad_s"] == [1e-3, -2e-3, 3e-4]
    m = json.loads(_fill(_EST_TPL, (1.25, 3, float("nan"), *vals[3:]))
                   + '{"roll":1,"pitch":2,"yaw":3}}')
    assert m["q"][0] is None and m["q"][1] == 0.0
    assert _g(float("inf")) == "null" and _neg("null") == "null"
    assert _neg("-1.5") == "1.5" and _neg("2") == "-2"
    rng = np.random.default_rng(3)
    for q in _random_q(rng, 20):
        np.testing.assert_allclose(_rpy(*q), quat_to_rpy_deg(q), atol=1e-12)
    # NEES against the vectorised scorer
    from uavest.eval.attitude import nees_attitude

    q, qr = _random_q(rng, 2)
    A = rng.standard_normal((6, 6))
    P = A @ A.T + np.eye(6)
    assert _nees3(tuple(q), tuple(qr), P.tolist()) == pytest.approx(
        float(nees_attitude(q[None], P[None], qr[None])[0]), rel=1e-9)


def test_3d_channels_are_rate_limited_by_default(tmp_path):
    """At 250 Hz, the JSON channels carry every step and the 3-D channels about 30 Hz of
    data time (the default); frame_rate_hz=None gives every step."""
    from uavest.engine.records import RunInfo, StepRecord
    from uavest.report import read_recording
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
            assert dt.min() >= 1 / 30 - 1e-9
    assert counts["every"] == (500, 500)
    assert 55 <= counts["default"][0] <= 61 and counts["default"][0] == counts["default"][1]
