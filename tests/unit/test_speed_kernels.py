"""The fused attitude-manifold kernels (issue 13) equal the composed implementation they
replaced to 1e-12; the composed form is kept here verbatim as the reference."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.geometry.rotation import (
    AttitudeSpace,
    gyro_propagate,
    local_rows,
    quat_conj,
    quat_exp,
    quat_log,
    quat_mul,
    retract_rows,
)
from uavest.geometry.spaces import manifold_mean
from uavest.models.attitude import GyroTransition


# ---------------------------------------------------------------- the pre-change code
def ref_retract(x, dx):
    q = quat_mul(x[..., :4], quat_exp(dx[..., :3]))
    q /= np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]
    b = x[..., 4:] + dx[..., 3:]
    lead = np.broadcast_shapes(q.shape[:-1], b.shape[:-1])
    return np.concatenate(
        [np.broadcast_to(q, lead + (4,)), np.broadcast_to(b, lead + (3,))], axis=-1)


def ref_local(x, y):
    d = quat_log(quat_mul(quat_conj(x[..., :4]), y[..., :4]))
    db = y[..., 4:] - x[..., 4:]
    d, db = np.broadcast_arrays(d, db)
    return np.concatenate([d, db], axis=-1)


class RefSpace:
    dim, size = 6, 7
    retract = staticmethod(ref_retract)
    local = staticmethod(ref_local)

    def mean(self, X, w, x0=None):
        ref = X[0] if x0 is None else x0
        q = X[:, :4]
        sgn = np.where(q @ ref[:4] < 0.0, -1.0, 1.0)
        qm = (w * sgn) @ q
        nq = np.linalg.norm(qm)
        start = np.concatenate([qm / nq if nq > 1e-9 else ref[:4], w @ X[:, 4:]])
        return manifold_mean(self, X, w, start, iters=1)


def ref_gyro_f(X, dt, u):
    phi = (u - X[..., 4:]) * dt
    q = quat_mul(X[..., :4], quat_exp(phi))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.concatenate([q, X[..., 4:]], axis=-1)


# ---------------------------------------------------------------- cases
def _points(rng, M, spread):
    """M states: random attitudes (some with w < 0, the double cover), biases."""
    q = rng.standard_normal((M, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.concatenate([q, spread * rng.standard_normal((M, 3))], axis=1)


def _offsets(rng, M, scale):
    D = scale * rng.standard_normal((M, 6))
    D[0] = 0.0  # a zero offset (the sigma-point centre): the small-angle branches
    if M > 2:
        D[1, :3] = 1e-7  # below the exp Taylor threshold
    return D


SCALES = [1e-9, 1e-3, 0.3, 2.5]  # rad: tiny, filter spread, large, beyond pi/2


@pytest.mark.parametrize("M", [1, 13, 221])
@pytest.mark.parametrize("scale", SCALES)
def test_retract_and_local_equal_the_composed_code(M, scale):
    rng = np.random.default_rng(M + int(1e3 * scale))
    sp = AttitudeSpace()
    x = _points(rng, 1, 0.01)[0]
    X = _points(rng, M, 0.01)
    D = _offsets(rng, M, scale)
    np.testing.assert_allclose(sp.retract(x, D), ref_retract(x, D), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sp.retract(X, D), ref_retract(X, D), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sp.retract(x, D[-1]), ref_retract(x, D[-1]), rtol=0,
                               atol=1e-12)
    Y = ref_retract(x, D)  # points near x (and X itself: far ones)
    for a, b in ((x, Y), (x, X), (X, Y), (Y, X)):
        np.testing.assert_allclose(sp.local(a, b), ref_local(a, b), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sp.local(x, Y[0]), ref_local(x, Y[0]), rtol=0, atol=1e-12)
    # the kernels themselves
    np.testing.assert_allclose(retract_rows(x, D), ref_retract(x, D), rtol=0, atol=1e-12)
    np.testing.assert_allclose(local_rows(X, Y), ref_local(X, Y), rtol=0, atol=1e-12)


def test_local_is_exact_at_identity_and_for_antipodal_quaternions():
    sp = AttitudeSpace()
    X = _points(np.random.default_rng(1), 5, 0.01)
    np.testing.assert_allclose(sp.local(X, X), ref_local(X, X), rtol=0, atol=1e-12)
    Xm = X.copy()
    Xm[:, :4] *= -1.0  # the same rotations
    np.testing.assert_allclose(sp.local(X, Xm), ref_local(X, Xm), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sp.local(X[0], Xm), ref_local(X[0], Xm), rtol=0, atol=1e-12)


@pytest.mark.parametrize("M", [13, 221])
@pytest.mark.parametrize("scale", [1e-4, 0.05, 0.5])
def test_manifold_mean_equals_the_composed_code(M, scale):
    rng = np.random.default_rng(7 * M)
    x = _points(rng, 1, 0.01)[0]
    X = ref_retract(x, scale * rng.standard_normal((M, 6)))
    X[::3, :4] *= -1.0  # double cover inside the ensemble
    w = rng.random(M)
    w /= w.sum()
    for x0 in (None, X[3]):
        np.testing.assert_allclose(AttitudeSpace().mean(X, w, x0), RefSpace().mean(X, w, x0),
                                   rtol=0, atol=1e-12)


@pytest.mark.parametrize("M", [1, 13, 221])
def test_gyro_propagation_equals_the_composed_code(M):
    rng = np.random.default_rng(M)
    X = _points(rng, M, 0.02)
    tr = GyroTransition()
    for u, dt in ((rng.standard_normal(3), 0.004), (np.zeros(3), 0.04), (5 * np.ones(3), 1.0)):
        np.testing.assert_allclose(tr.f(X, 0.0, dt, u), ref_gyro_f(X, dt, u), rtol=0,
                                   atol=1e-12)
        np.testing.assert_allclose(gyro_propagate(X, u, dt), ref_gyro_f(X, dt, u), rtol=0,
                                   atol=1e-12)
    X[:, 4:] = 0.0
    np.testing.assert_allclose(tr.f(X, 0.0, 0.01, np.zeros(3)), ref_gyro_f(X, 0.01, np.zeros(3)),
                               rtol=0, atol=1e-12)  # zero rotation: the Taylor branch


def test_radar_closed_form_jacobian_equals_the_batched_one():
    from uavest.models.radar import RadarMeasurement, SensorPose

    rng = np.random.default_rng(5)
    for pose in (None, SensorPose.fixed(2, [100.0, -50.0], 0.7)):
        m = RadarMeasurement(2, pose=pose)
        for x in [np.zeros(4), *rng.normal(0, 5000, (50, 4))]:
            np.testing.assert_allclose(m.H(x), m.H_rows(x[None, :])[0], rtol=0, atol=1e-15)


def test_radar_single_state_h_equals_the_batched_one():
    from uavest.models.radar import RadarMeasurement, SensorPose

    rng = np.random.default_rng(6)
    for pose in (None, SensorPose.fixed(2, [100.0, -50.0], 0.7)):
        m = RadarMeasurement(2, pose=pose)
        X = rng.normal(0, 5000, (50, 4))
        X[0] = 0.0
        batch = m.h(X)
        for i in range(len(X)):
            np.testing.assert_allclose(m.h(X[i:i + 1]), batch[i:i + 1], rtol=1e-14, atol=1e-12)


def test_accel_update_weight_scales_R_and_is_exact_at_the_reference_rate():
    from uavest.models.attitude import AttitudeNoise, GravityDirection

    a = np.array([0.3, -0.2, -9.7])
    z1, m1 = GravityDirection.from_accel(a, AttitudeNoise())
    z2, m2 = GravityDirection.from_accel(a, AttitudeNoise(), weight=1.0)
    z8, m8 = GravityDirection.from_accel(a, AttitudeNoise(), weight=1.0 / 8)
    assert np.array_equal(m1.R, m2.R) and np.array_equal(z1, z8)
    np.testing.assert_allclose(m8.R, 8.0 * m1.R, rtol=1e-15)
    with pytest.raises(ValueError):
        GravityDirection.from_accel(a, AttitudeNoise(), weight=0.0)


def _ref_quat_mul(p, q):
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    out[..., 0] = pw * qw - px * qx - py * qy - pz * qz
    out[..., 1] = pw * qx + px * qw + py * qz - pz * qy
    out[..., 2] = pw * qy - px * qz + py * qw + pz * qx
    out[..., 3] = pw * qz + px * qy - py * qx + pz * qw
    return out


def _ref_quat_exp(v):
    th = np.sqrt(np.einsum("...i,...i->...", v, v))
    out = np.empty(v.shape[:-1] + (4,))
    h = 0.5 * th
    out[..., 0] = np.cos(h)
    small = th < 1e-5
    s = np.where(small, 0.5 - th * th / 48.0, np.sin(h) / np.where(small, 1.0, th))
    out[..., 1:] = s[..., None] * v
    return out


def _ref_quat_log(q):
    w = q[..., 0]
    sgn = np.where(w < 0.0, -1.0, 1.0)
    w = np.abs(w)
    xyz = q[..., 1:] * sgn[..., None]
    n = np.sqrt(np.einsum("...i,...i->...", xyz, xyz))
    small = n < 1e-8
    k = np.where(small, 2.0 / np.maximum(w, 1e-300),
                 2.0 * np.arctan2(n, w) / np.where(small, 1.0, n))
    return k[..., None] * xyz


def test_quaternion_functions_fast_paths_are_bit_identical():
    rng = np.random.default_rng(9)
    Q = _points(rng, 40, 0.0)[:, :4]
    V = rng.standard_normal((40, 3)) * np.logspace(-9, 0.5, 40)[:, None]
    V[0] = 0.0
    for i in range(len(Q) - 1):
        assert np.array_equal(quat_mul(Q[i], Q[i + 1]), _ref_quat_mul(Q[i], Q[i + 1]))
    assert np.array_equal(quat_exp(V), _ref_quat_exp(V))
    assert np.array_equal(quat_log(Q), _ref_quat_log(Q))
    assert np.array_equal(quat_log(quat_exp(V)), _ref_quat_log(_ref_quat_exp(V)))
    for i in range(3):
        assert np.array_equal(quat_exp(V[i]), _ref_quat_exp(V[i]))
        assert np.array_equal(quat_log(Q[i]), _ref_quat_log(Q[i]))


def test_mag_update_weight_scales_R_and_is_exact_at_the_reference_rate():
    from uavest.models.attitude import AttitudeNoise, MagField, MagHeading

    f = np.array([0.2, 0.05, 0.4])
    ref = np.array([0.5, 0.0, 0.86])
    for make in (lambda w: MagField.from_field(f, AttitudeNoise(), ref, weight=w),
                 lambda w: MagHeading.from_field(f, AttitudeNoise(), 0.1, weight=w)):
        (z1, m1), (z8, m8) = make(1.0), make(0.125)
        assert np.array_equal(z1, z8)
        np.testing.assert_allclose(m8.R, 8.0 * m1.R, rtol=1e-15)


def test_gyro_transition_float_paths_equal_the_composed_forms():
    """GyroTransition.F and f of one state run on Python floats; they equal the composed
    numpy forms (quat_to_dcm(quat_exp(-phi)), right_jacobian, gyro_propagate) to 1e-15
    over angles from 1e-9 rad (the Taylor branches) to ~3 rad per step."""
    from uavest.geometry.rotation import gyro_propagate, quat_exp, quat_to_dcm, right_jacobian
    from uavest.models.attitude import AttitudeNoise, GyroTransition

    tr = GyroTransition(AttitudeNoise())
    rng = np.random.default_rng(4)
    for _ in range(500):
        q = rng.normal(size=4)
        x = np.concatenate([q / np.linalg.norm(q), rng.normal(0, 0.01, 3)])
        u = rng.normal(0, 1, 3) * 10 ** rng.uniform(-9, 1.5)
        dt = rng.uniform(1e-4, 0.1)
        phi = (u - x[4:]) * dt
        F = np.eye(6)
        F[:3, :3] = quat_to_dcm(quat_exp(-phi))
        F[:3, 3:] = -right_jacobian(phi) * dt
        np.testing.assert_allclose(tr.F(x, 0.0, dt, u), F, rtol=0, atol=1e-15)
        np.testing.assert_allclose(tr.f(x[None], 0.0, dt, u), gyro_propagate(x[None], u, dt),
                                   rtol=0, atol=1e-15)
    Q = tr.Q(0.0, 0.004)
    assert Q is tr.Q(0.0, 0.004) and not Q.flags.writeable  # one diag per dt
    assert tr.Q(0.0, 0.005)[0, 0] > Q[0, 0]


def test_slerp_one_equals_the_composed_slerp():
    from uavest.geometry.rotation import quat_conj, quat_exp, quat_log, quat_mul, slerp_one

    rng = np.random.default_rng(5)
    for i in range(300):
        q0 = rng.normal(size=4)
        q0 /= np.linalg.norm(q0)
        d = rng.normal(size=3) * 10 ** rng.uniform(-10, 0.4)
        q1 = quat_mul(q0, quat_exp(d)) * (-1 if i % 3 == 0 else 1)  # both signs
        for s in (0.0, 0.3, 1.0):
            ref = quat_mul(q0, quat_exp(s * quat_log(quat_mul(quat_conj(q0), q1))))
            np.testing.assert_allclose(slerp_one(q0, q1, s), ref, rtol=0, atol=1e-15)


def _numba_kernels():
    from conftest import compiled_kernels

    from uavest.geometry import rotation

    return rotation, compiled_kernels(rotation.MANIFOLD_KERNELS.get, "attitude kernels")


def test_compiled_kernels_equal_the_numpy_kernels():
    """The numba kernels (uavest[fast]) against the fused numpy ones, both called
    explicitly, on 13 and 221 rows, single and per-row states, angles from 1e-9 rad (the
    Taylor branches) to ~3 rad, both quaternion signs: equal to 1e-12."""
    rot, nb = _numba_kernels()
    rng = np.random.default_rng(11)
    for M in (1, 13, 221):
        X = _points(rng, M, 0.0)
        x = X[0].copy()
        dx = rng.standard_normal((M, 6)) * 10 ** rng.uniform(-9, 0.5, (M, 1))
        X[::3, :4] *= -1.0
        np.testing.assert_allclose(nb.retract_rows(x[None, :], dx),
                                   rot._np_retract_rows(x, dx), rtol=0, atol=1e-12)
        np.testing.assert_allclose(nb.retract_rows(X, dx), rot._np_retract_rows(X, dx),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(nb.local_rows(x[None, :], X), rot._np_local_rows(x, X),
                                   rtol=0, atol=1e-12)
        Y = rot._np_retract_rows(X, dx)
        np.testing.assert_allclose(nb.local_rows(X, Y), rot._np_local_rows(X, Y), rtol=0,
                                   atol=1e-12)
        u = rng.normal(0, 2, 3)
        np.testing.assert_allclose(nb.gyro_propagate(X, u, 0.004),
                                   rot._np_gyro_propagate(X, u, 0.004), rtol=0, atol=1e-12)
        w = rng.uniform(0.1, 1.0, M)
        w /= w.sum()
        Xs = rot._np_retract_rows(x, rng.normal(0, 0.05, (M, 6)))
        np.testing.assert_allclose(nb.mean(Xs, w, Xs[0]), rot._np_mean(Xs, w, Xs[0]),
                                   rtol=0, atol=1e-12)
        v = rng.normal(size=3)
        np.testing.assert_allclose(
            nb.rotate_inv_rows(X[:, :4], v),
            np.einsum("...ji,...j->...i", rot.quat_to_dcm(X[:, :4]), v), rtol=0, atol=1e-12)
    # the public functions dispatch to the compiled kernels
    assert rot.MANIFOLD_KERNELS.get() is nb


@pytest.mark.slow
def test_numba_can_be_switched_off_and_gives_the_same_replay(tmp_path):
    """UAVEST_NUMBA=0 uses the numpy kernels; a replay with either gives the same RMSE
    (over the log's first 20 s: the attitude filters run the manifold kernels from their
    first step)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    _numba_kernels()
    log = Path(__file__).resolve().parents[2] / "logs" / "sim_200hz.tlog"
    code = ("import json,sys; from uavest.apps.replay import replay, ReplayConfig;"
            "from uavest.geometry import rotation as r;"
            "d = replay(sys.argv[1], ReplayConfig(end=20.0));"
            "print(json.dumps({'nb': bool(r.MANIFOLD_KERNELS.loaded), 'rows': d['filters']}))")
    out = {}
    for flag in ("0", "1"):
        env = dict(os.environ, UAVEST_NUMBA=flag)
        p = subprocess.run([sys.executable, "-c", code, str(log)], env=env,
                           capture_output=True, text=True, timeout=600, check=True)
        out[flag] = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["0"]["nb"] is False and out["1"]["nb"] is True
    assert all(out[f]["rows"]["hybrid"]["n"] > 400 for f in out)  # (estimates to compare)
    a, b = out["0"]["rows"], out["1"]["rows"]
    assert a.keys() == b.keys()
    for lab in a:
        for k in ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "nees_mean"):
            va, vb = a[lab].get(k), b[lab].get(k)
            assert (va is None) == (vb is None)
            if va is not None:
                assert abs(va - vb) < 1e-6, (lab, k, va, vb)
