"""Vectorised unit-quaternion algebra and the attitude + gyro-bias state space.

Conventions (same as :mod:`uavest.ingest.types`):

* quaternions are scalar-first ``[w, x, y, z]``, Hamilton product, unit norm;
* ``q`` rotates vectors from body FRD into NED: ``v_ned = q * v_body * q^-1``,
  i.e. ``R(q) @ v_body`` with :func:`quat_to_dcm`;
* Euler angles are the aerospace ZYX sequence (yaw, then pitch, then roll), radians:
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``;
* rotation vectors (``Exp``/``Log``) are axis * angle in radians.

Every function takes ``(..., 4)`` / ``(..., 3)`` arrays and broadcasts over the leading
axes; nothing loops in Python. Hand-written numpy is used instead of
``scipy.spatial.transform.Rotation`` on the filters' hot paths because the per-call
overhead of the latter dominates for the small row counts (13 sigma points) used there;
the test-suite checks both agree.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from types import ModuleType

import numpy as np

from ..compiled import read_only, register

Array = np.ndarray
#: one quaternion (w, x, y, z) or rotation vector as floats: a tuple, list or 1-D array
Quat = Sequence[float] | Array

#: Standard gravity (m/s^2 per g), also MAVLink's "milli-g" unit.
G0 = 9.80665

__all__ = [
    "G0",
    "AttitudeSpace",
    "QuatRowsSpace",
    "dcm_to_quat",
    "euler_to_quat",
    "quat_canonical",
    "quat_conj",
    "quat_exp",
    "quat_log",
    "quat_mul",
    "quat_rotate",
    "quat_rotate_inv",
    "qexp_f",
    "qlog_f",
    "qmul_f",
    "quat_slerp_interp",
    "quat_to_dcm",
    "quat_to_euler",
    "gyro_propagate",
    "local_rows",
    "retract_rows",
    "right_jacobian",
    "skew",
    "wrap_pi",
]


def wrap_pi(a: Array | float) -> Array:
    """Angle(s) wrapped to [-pi, pi) (radians)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def quat_mul(p: Array, q: Array) -> Array:
    """Hamilton product ``p * q`` (scalar-first), broadcast over leading axes.

    When one side is a single quaternion the product is one (M, 4) @ (4, 4) matmul.
    """
    if p.ndim == 1 and q.ndim == 1:  # one product (the step builder's pre-integration)
        pw, px, py, pz = p.tolist()
        qw, qx, qy, qz = q.tolist()
        return np.array([pw * qw - px * qx - py * qy - pz * qz,
                         pw * qx + px * qw + py * qz - pz * qy,
                         pw * qy - px * qz + py * qw + pz * qx,
                         pw * qz + px * qy - py * qx + pz * qw])
    if p.ndim == 1 and q.ndim > 1:
        w, x, y, z = p
        L = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])
        res: Array = q @ L.T
        return res
    if q.ndim == 1 and p.ndim > 1:
        w, x, y, z = q
        Rm = np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])
        res = p @ Rm.T
        return res
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    out[..., 0] = pw * qw - px * qx - py * qy - pz * qz
    out[..., 1] = pw * qx + px * qw + py * qz - pz * qy
    out[..., 2] = pw * qy - px * qz + py * qw + pz * qx
    out[..., 3] = pw * qz + px * qy - py * qx + pz * qw
    return out


def quat_conj(q: Array) -> Array:
    """Conjugate (= inverse for unit quaternions)."""
    res: Array = q * np.array([1.0, -1.0, -1.0, -1.0])
    return res


def quat_canonical(q: Array) -> Array:
    """``q`` or ``-q`` so that the scalar part is >= 0 (same rotation)."""
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_exp(v: Array) -> Array:
    """Unit quaternion of rotation vector(s) ``v`` (rad): ``[cos(|v|/2), sin(|v|/2) v/|v|]``
    (Taylor series below 1e-5 rad, so smooth at zero)."""
    v = np.asarray(v, dtype=float)
    if v.ndim == 2:
        return _exp_rows(v)  # the same formula, fewer calls
    th = np.sqrt(np.einsum("...i,...i->...", v, v))
    out = np.empty(v.shape[:-1] + (4,))
    h = 0.5 * th
    out[..., 0] = np.cos(h)
    small = th < 1e-5
    s = np.where(small, 0.5 - th * th / 48.0, np.sin(h) / np.where(small, 1.0, th))
    out[..., 1:] = s[..., None] * v
    return out


def quat_log(q: Array) -> Array:
    """Rotation vector(s) (rad) of unit quaternion(s), shortest way (angle in [0, pi]).

    ``q`` and ``-q`` give the same result (double cover handled here).
    """
    if q.ndim == 2:
        out = np.empty((q.shape[0], 3))
        _log_rows_into(q, out)  # the same formula, fewer calls
        return out
    w = q[..., 0]
    sgn = np.where(w < 0.0, -1.0, 1.0)
    w = np.abs(w)
    xyz = q[..., 1:] * sgn[..., None]
    n = np.sqrt(np.einsum("...i,...i->...", xyz, xyz))
    small = n < 1e-8
    k = np.where(
        small, 2.0 / np.maximum(w, 1e-300), 2.0 * np.arctan2(n, w) / np.where(small, 1.0, n)
    )
    res: Array = k[..., None] * xyz
    return res


def quat_to_dcm(q: Array) -> Array:
    """Rotation matrices ``(..., 3, 3)`` mapping body FRD to NED (``v_ned = R v_body``)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def dcm_to_quat(R: Array) -> Array:
    """Unit quaternion(s) (scalar-first, w >= 0) of rotation matrices ``(..., 3, 3)``."""
    from scipy.spatial.transform import Rotation

    shape = R.shape[:-2]
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    return quat_canonical(q).reshape(shape + (4,))


def quat_rotate(q: Array, v: Array) -> Array:
    """``R(q) v``: body vector(s) ``v`` expressed in NED."""
    if q.ndim == 2 and np.ndim(v) == 2 and q.shape[0] == v.shape[0]:  # rows against rows
        nb = MANIFOLD_KERNELS.get()
        if nb:
            out: Array = nb.rotate_rows(q, np.asarray(v, float))
            return out
    res: Array = np.einsum("...ij,...j->...i", quat_to_dcm(q), v)
    return res


def quat_rotate_inv(q: Array, v: Array) -> Array:
    """``R(q)^T v``: NED vector(s) ``v`` expressed in body FRD."""
    if q.ndim == 2 and np.ndim(v) == 1:  # rows against one vector (the attitude h)
        nb = MANIFOLD_KERNELS.get()
        if nb:
            res: Array = nb.rotate_inv_rows(q, np.asarray(v, float))
            return res
    res = np.einsum("...ji,...j->...i", quat_to_dcm(q), v)
    return res


def quat_to_euler(q: Array) -> Array:
    """ZYX Euler angles ``(..., 3)`` = (roll, pitch, yaw) in radians, yaw in [-pi, pi]."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def euler_to_quat(roll: Array, pitch: Array, yaw: Array) -> Array:
    """Quaternion(s) of ZYX Euler angles (radians): ``q = qz(yaw) qy(pitch) qx(roll)``,
    canonical (scalar part >= 0); equals ``Rotation.from_euler('ZYX', [yaw, pitch, roll])``
    (scalar-first). Array inputs of shape (N,) give (N, 4)."""
    cr, sr = np.cos(np.multiply(roll, 0.5)), np.sin(np.multiply(roll, 0.5))
    cp, sp = np.cos(np.multiply(pitch, 0.5)), np.sin(np.multiply(pitch, 0.5))
    cy, sy = np.cos(np.multiply(yaw, 0.5)), np.sin(np.multiply(yaw, 0.5))
    q = np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )
    return quat_canonical(q)


def skew(v: Array) -> Array:
    """Cross-product matrix ``[v]x`` ``(..., 3, 3)`` with ``[v]x u = v x u``."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def right_jacobian(phi: Array) -> Array:
    """Right Jacobian of SO(3) at rotation vector ``phi`` (3,):
    ``Exp(phi + d) ~= Exp(phi) Exp(J_r(phi) d)``."""
    phi = np.asarray(phi, dtype=float)
    th2 = float(phi @ phi)
    K = skew(phi)
    if th2 < 1e-10:
        res: Array = np.eye(3) - 0.5 * K + K @ K / 6.0
        return res
    th = np.sqrt(th2)
    res = np.eye(3) - (1 - np.cos(th)) / th2 * K + (th - np.sin(th)) / (th2 * th) * K @ K
    return res


def qmul_f(p: Quat, q: Quat) -> tuple[float, float, float, float]:
    """Hamilton product ``p * q`` of two single quaternions on Python floats (the formula of
    :func:`quat_mul`, without numpy's per-call cost)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw)


def qlog_f(q: Quat) -> tuple[float, float, float]:
    """:func:`quat_log` of one quaternion on Python floats (rad, the short way)."""
    w, x, y, z = q
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    k = 2.0 / max(w, 1e-300) if n < 1e-8 else 2.0 * math.atan2(n, w) / n
    return (k * x, k * y, k * z)


def qexp_f(v: Quat) -> tuple[float, float, float, float]:
    """:func:`quat_exp` of one rotation vector (rad) on Python floats."""
    x, y, z = v
    th = math.sqrt(x * x + y * y + z * z)
    s = 0.5 - th * th / 48.0 if th < 1e-5 else math.sin(0.5 * th) / th
    return (math.cos(0.5 * th), s * x, s * y, s * z)


def dcm_f(q: Quat) -> tuple[tuple[float, float, float], ...]:
    """:func:`quat_to_dcm` of one quaternion on Python floats: its rows (body FRD -> NED)."""
    w, x, y, z = q
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def euler_to_quat_f(roll: float, pitch: float, yaw: float
                    ) -> tuple[float, float, float, float]:
    """:func:`euler_to_quat` of one ZYX Euler triple (rad) on Python floats (canonical:
    w >= 0); the ingest converts every attitude reference sample with it."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    w = cr * cp * cy + sr * sp * sy
    x = sr * cp * cy - cr * sp * sy
    y = cr * sp * cy + sr * cp * sy
    z = cr * cp * sy - sr * sp * cy
    return (-w, -x, -y, -z) if w < 0.0 else (w, x, y, z)


def slerp_one(q0: Quat, q1: Quat, s: float) -> tuple[float, float, float, float]:
    """``q0 Exp(s Log(q0^-1 q1))`` of two single quaternions on Python floats: the
    streaming scorer and the recorder interpolate one reference sample pair per step."""
    w, x, y, z = (float(v) for v in q0)
    d = qlog_f(qmul_f((w, -x, -y, -z), tuple(float(v) for v in q1)))
    return qmul_f((w, x, y, z), qexp_f((s * d[0], s * d[1], s * d[2])))


def quat_slerp_interp(t_ref: Array, q_ref: Array, t: Array) -> tuple[Array, Array]:
    """Reference quaternions interpolated (slerp) at times ``t``.

    ``t_ref`` (K,) increasing, ``q_ref`` (K, 4); returns ``(q (N, 4), valid (N,))`` where
    ``valid`` is False outside ``[t_ref[0], t_ref[-1]]`` (those rows hold the nearest end).
    """
    t_ref = np.asarray(t_ref, float)
    t = np.asarray(t, float)
    K = t_ref.shape[0]
    if K == 0:
        return np.tile([1.0, 0, 0, 0], (t.shape[0], 1)), np.zeros(t.shape[0], bool)
    if K == 1:
        return np.tile(q_ref[0], (t.shape[0], 1)), t == t_ref[0]
    i = np.clip(np.searchsorted(t_ref, t, side="right") - 1, 0, K - 2)
    span = t_ref[i + 1] - t_ref[i]
    s = np.clip((t - t_ref[i]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    q0, q1 = q_ref[i], q_ref[i + 1]
    d = quat_log(quat_mul(quat_conj(q0), q1))
    q = quat_mul(q0, quat_exp(s[:, None] * d))
    valid = (t >= t_ref[0]) & (t <= t_ref[-1])
    return q, valid


# ------------------------------------------------------------------ fused manifold kernels
#
# The attitude filters call retract / local / mean / the gyro propagation on arrays of
# members (13 sigma points, 221 ensemble members) many times per step; the cost is numpy's
# per-call floor, not arithmetic. These kernels compute exactly what quat_mul / quat_exp /
# quat_log compose to, with a handful of numpy calls instead of ~30: the quaternion
# product as a gathered 4x4 (Hamilton) matrix, exp/log without the broadcasting machinery,
# results written into one preallocated array. Equal to the composed functions to 1e-15
# (tests/unit/test_speed_kernels.py keeps the composed form as the reference).
# With numba installed (``uavest[fast]``) the same kernels run compiled
# (:mod:`uavest.geometry._compiled`, chosen by measurement: docs/speed.md).


def _kernel_cases(nb: ModuleType) -> Iterator[tuple[str, Array, Array]]:
    """The self-check (:mod:`uavest.compiled`): the compiled retract, local, gyro
    propagation, mean and inverse rotation against the numpy kernels on a small case,
    with the argument types the filters pass (numba compiles once per type)."""
    x = np.array([0.9, 0.1, -0.3, 0.2, 1e-3, -2e-3, 3e-3])
    x[:4] /= np.sqrt(x[:4] @ x[:4])
    d = np.array([[1e-3, -2e-2, 3e-1, 1e-4, 0.0, -1e-4], [0.0, 1e-7, 0.0, 0.0, 0.0, 0.0]])
    X = _np_retract_rows(x, d)
    w = np.array([0.25, 0.75])
    yield "retract_rows", nb.retract_rows(x[None, :], d), X
    yield "local_rows", nb.local_rows(x[None, :], X), _np_local_rows(x, X)
    yield ("gyro_propagate", nb.gyro_propagate(X, d[0, :3], 0.01),
           _np_gyro_propagate(X, d[0, :3], 0.01))
    yield "mean", nb.mean(X, read_only(w), X[0]), _np_mean(X, w, X[0])
    want = np.einsum("...ji,...j->...i", quat_to_dcm(X[:, :4]), d[0, :3])
    # (both layouts a run passes, so that neither compiles at its first estimates: the
    # members' quaternion columns (strided) and a contiguous (M, 4) array)
    yield "rotate_inv_rows", nb.rotate_inv_rows(X[:, :4], d[0, :3]), want
    yield ("rotate_inv_rows C", nb.rotate_inv_rows(np.ascontiguousarray(X[:, :4]), d[0, :3]),
           want)
    # rows against rows (the carried GNSS velocity's specific force): strided and contiguous
    want = np.einsum("...ij,...j->...i", quat_to_dcm(X[:, :4]), d[:, 3:])
    yield "rotate_rows", nb.rotate_rows(X[:, :4], d[:, 3:]), want
    yield "rotate_rows A C", nb.rotate_rows(X[:, :4], np.ascontiguousarray(d[:, 3:])), want
    yield ("rotate_rows C", nb.rotate_rows(np.ascontiguousarray(X[:, :4]),
                                           np.ascontiguousarray(d[:, 3:])), want)
    # the navigation space's width (NavSpace(extra=3, mag=2): a quaternion and 17
    # Euclidean components), through the same kernels
    xn = np.concatenate([x[:4], np.linspace(-2.0, 3.0, 17)])
    dn = np.concatenate([d, np.linspace(0.5, -0.5, 28).reshape(2, 14)], axis=1)
    Xn = _np_retract_rows(xn, dn)
    yield "retract_rows nav", nb.retract_rows(xn[None, :], dn), Xn
    yield "local_rows nav", nb.local_rows(Xn[:1], Xn), _np_local_rows(Xn[0], Xn)
    yield "mean nav", nb.mean(Xn, read_only(w), xn), _np_mean(Xn, w, xn)
    # the members' moments (uavest.core.states.ensemble_moments composes them so)
    for tag, Y in (("", X), (" nav", Xn)):
        Y3 = np.concatenate([Y, Y[:1]])
        w3 = np.array([0.2, 0.5, 0.3])
        x3, d3, P3 = nb.moments(Y3, read_only(w3))
        m3 = _np_mean(Y3, w3, Y3[1])
        dm = _np_local_rows(m3, Y3)
        dm = dm - w3 @ dm
        yield "moments x" + tag, x3, m3
        yield "moments dX" + tag, d3, dm
        P = (dm.T * w3) @ dm / (1.0 - w3 @ w3)
        yield "moments P" + tag, P3, 0.5 * (P + P.T)


#: The compiled attitude-manifold kernels (:mod:`uavest.geometry._compiled`)
MANIFOLD_KERNELS = register("manifold", "uavest.geometry._compiled",
                            "numba attitude-manifold kernels", _kernel_cases, rtol=0.0,
                            atol=1e-12)


#: Gather indices and signs of the left-multiplication matrix: p * q = L(p) q with
#: L(p) = p[_LI] * _LS, [[w,-x,-y,-z],[x,w,-z,y],[y,z,w,-x],[z,-y,x,w]].
_LI = np.array([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_LS = np.array([[1.0, -1, -1, -1], [1, 1, -1, 1], [1, 1, 1, -1], [1, -1, 1, 1]])
_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def _exp_rows(v: Array) -> Array:
    """quat_exp of rows ``v`` (M, 3) -> (M, 4), the same formula in fewer calls."""
    th = np.sqrt(np.einsum("ij,ij->i", v, v))
    h = 0.5 * th
    out = np.empty((v.shape[0], 4))
    np.cos(h, out=out[:, 0])
    small = th < 1e-5
    if small.any():
        s = np.where(small, 0.5 - th * th / 48.0, np.sin(h) / np.where(small, 1.0, th))
    else:
        s = np.sin(h)
        s /= th
    np.multiply(s[:, None], v, out=out[:, 1:])
    return out


def _log_rows_into(q: Array, out: Array) -> None:
    """quat_log of rows ``q`` (M, 4) written into ``out`` (M, 3). The sign flip of the
    double cover is a multiplication by +-1 (exact), folded into the scale factor."""
    w = q[:, 0]
    xyz = q[:, 1:]
    sgn = np.where(w < 0.0, -1.0, 1.0)
    aw = np.abs(w)
    n = np.sqrt(np.einsum("ij,ij->i", xyz, xyz))
    small = n < 1e-8
    if small.any():
        k = np.where(small, 2.0 / np.maximum(aw, 1e-300),
                     2.0 * np.arctan2(n, aw) / np.where(small, 1.0, n))
    else:
        k = 2.0 * np.arctan2(n, aw) / n
    k *= sgn
    np.multiply(k[:, None], xyz, out=out)


def _normalise_into(q: Array, out: Array) -> None:
    np.divide(q, np.sqrt(np.einsum("ij,ij->i", q, q))[:, None], out=out)


def _qmul_rows(p: Array, q: Array) -> Array:
    """Row-wise Hamilton product of (M, 4) arrays (one gather and one einsum)."""
    res: Array = np.einsum("mij,mj->mi", p[:, _LI] * _LS, q)
    return res


def retract_rows(x: Array, dx: Array) -> Array:
    """:meth:`AttitudeSpace.retract` for ``x`` (7,) or (M, 7) and ``dx`` (M, 6); any
    width of a quaternion and Euclidean components (``x`` (n,) or (M, n), ``dx`` (M,
    n - 1)): :class:`~uavest.geometry.navigation.NavSpace`'s too."""
    nb = MANIFOLD_KERNELS.get()
    if nb:
        res: Array = nb.retract_rows(x.reshape(1, -1) if x.ndim == 1 else x, dx)
        return res
    return _np_retract_rows(x, dx)


def _np_retract_rows(x: Array, dx: Array) -> Array:
    M = dx.shape[0]
    E = _exp_rows(dx[:, :3])
    if x.ndim == 1:
        qe = E @ (x[:4][_LI] * _LS).T
    else:
        qe = _qmul_rows(x[:, :4], E)
    out = np.empty((M, dx.shape[1] + 1))
    _normalise_into(qe, out[:, :4])
    np.add(x[..., 4:], dx[:, 3:], out=out[:, 4:])
    return out


def local_rows(x: Array, y: Array) -> Array:
    """:meth:`AttitudeSpace.local` for ``x`` (7,) or (M, 7) and ``y`` (M, 7); any width
    as :func:`retract_rows`."""
    nb = MANIFOLD_KERNELS.get()
    if nb:
        res: Array = nb.local_rows(x.reshape(1, -1) if x.ndim == 1 else x, y)
        return res
    return _np_local_rows(x, y)


def _np_local_rows(x: Array, y: Array) -> Array:
    if x.ndim == 1:
        qq = y[:, :4] @ ((x[:4] * _CONJ)[_LI] * _LS).T
    else:
        qq = _qmul_rows(x[:, :4] * _CONJ, y[:, :4])
    out = np.empty((y.shape[0], y.shape[1] - 1))
    _log_rows_into(qq, out[:, :3])
    np.subtract(y[:, 4:], x[..., 4:], out=out[:, 3:])
    return out


def gyro_propagate(X: Array, w: Array, dt: float) -> Array:
    """q <- q * Exp((w - b) dt), b <- b for every row of ``X`` (M, 7) (the gyro
    transition), ``w`` (3,) rad/s."""
    nb = MANIFOLD_KERNELS.get()
    if nb:
        res: Array = nb.gyro_propagate(X, w, float(dt))
        return res
    return _np_gyro_propagate(X, w, dt)


def _np_gyro_propagate(X: Array, w: Array, dt: float) -> Array:
    E = _exp_rows((w - X[:, 4:]) * dt)
    out = np.empty(X.shape)
    _normalise_into(_qmul_rows(X[:, :4], E), out[:, :4])
    out[:, 4:] = X[:, 4:]
    return out


class QuatRowsSpace:
    """retract / local / mean of a state that is a quaternion (body FRD -> NED,
    scalar-first) followed by Euclidean components, ``size`` of them in all
    (:class:`AttitudeSpace`, :class:`~uavest.geometry.navigation.NavSpace`): the right
    (body-frame) error ``q <- q * Exp(dtheta)`` and addition on the rest; ``local`` its
    inverse the short way. The filters' shapes, one state or (M, size) against (M, size -
    1), go to the row kernels (compiled when in use); one state against one tangent to
    :meth:`_retract_one` / :meth:`_local_one`, which a space may do its own way; any other
    broadcast to the general forms."""

    size: int

    def _retract_one(self, x: Array, dx: Array) -> Array:
        res: Array = retract_rows(x, dx[None, :])[0]
        return res

    def _local_one(self, x: Array, y: Array) -> Array:
        res: Array = local_rows(x, y[None, :])[0]
        return res

    def retract(self, x: Array, dx: Array) -> Array:
        if dx.ndim == 2 and x.ndim <= 2 and (x.ndim == 1 or x.shape[0] == dx.shape[0]):
            return retract_rows(x, dx)
        if dx.ndim == 1 and x.ndim == 1:
            return self._retract_one(x, dx)
        return self._retract_broadcast(x, dx)

    def local(self, x: Array, y: Array) -> Array:
        if y.ndim == 2 and x.ndim <= 2 and (x.ndim == 1 or x.shape[0] == y.shape[0]):
            return local_rows(x, y)
        if y.ndim == 1 and x.ndim == 1:
            return self._local_one(x, y)
        return self._local_broadcast(x, y)

    # general broadcasting forms (any leading axes); the fused kernels above cover the
    # filters' shapes
    def _retract_broadcast(self, x: Array, dx: Array) -> Array:
        q = quat_mul(x[..., :4], quat_exp(dx[..., :3]))
        q /= np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]
        b = x[..., 4:] + dx[..., 3:]
        lead = np.broadcast_shapes(q.shape[:-1], b.shape[:-1])
        return np.concatenate(
            [np.broadcast_to(q, lead + (4,)), np.broadcast_to(b, lead + (self.size - 4,))],
            axis=-1
        )

    def _local_broadcast(self, x: Array, y: Array) -> Array:
        d = quat_log(quat_mul(quat_conj(x[..., :4]), y[..., :4]))
        db = y[..., 4:] - x[..., 4:]
        d, db = np.broadcast_arrays(d, db)
        return np.concatenate([d, db], axis=-1)

    def mean(self, X: Array, w: Array, x0: Array | None = None) -> Array:
        return mean_rows(X, w, X[0] if x0 is None else x0)

    def weighted_moments(self, X: Array, w: Array) -> tuple[Array, Array, Array] | None:
        """(x, dX, P) of the members ``X`` (M, size) under the weights ``w`` in one compiled
        call (:func:`uavest.geometry._compiled.moments`): the mean started from the
        heaviest member, the centred deviations (M, dim) and the reliability-weighted
        covariance (dim, dim), symmetrised; None without the kernels (the caller then
        composes them from :meth:`mean` and :meth:`local`, the reference)."""
        nb = MANIFOLD_KERNELS.get()
        if not nb or X.ndim != 2:
            return None
        res: tuple[Array, Array, Array] = nb.moments(X, read_only(w))
        return res


class AttitudeSpace(QuatRowsSpace):
    """State ``x = [q (4), b (3)]``: attitude quaternion (body FRD -> NED, scalar-first)
    and gyro bias ``b`` (rad/s, body FRD). ``size`` 7, tangent ``dim`` 6.

    Retraction (right, i.e. body-frame, error): ``q <- q * Exp(dtheta)``, ``b <- b + db``
    with ``dx = [dtheta (rad, body FRD), db (rad/s)]``. ``local`` is its inverse,
    ``dtheta = Log(q_x^-1 * q_y)`` taken the short way, so ``q`` and ``-q`` are the same
    point. ``mean`` is the iterated tangent (Karcher) mean started from the sign-aligned
    chordal mean.
    """

    dim = 6
    size = 7

    def __repr__(self) -> str:
        return "AttitudeSpace(q*Exp(dtheta), b+db)"


def mean_rows(X: Array, w: Array, ref: Array) -> Array:
    """:meth:`AttitudeSpace.mean` of the rows ``X`` (M, n) under the weights ``w`` (M,),
    started from ``ref`` (n,); any width as :func:`retract_rows`."""
    nb = MANIFOLD_KERNELS.get()
    if nb:
        res: Array = nb.mean(X, read_only(w), ref)  # (w: the self-check's type)
        return res
    return _np_mean(X, w, ref)


def _np_mean(X: Array, w: Array, ref: Array) -> Array:
    q = X[:, :4]
    sgn = np.where(q @ ref[:4] < 0.0, -1.0, 1.0)
    qm = (w * sgn) @ q
    nq = float(np.sqrt(qm @ qm))  # = np.linalg.norm(qm)
    start = np.empty(X.shape[1])
    start[:4] = qm / nq if nq > 1e-9 else ref[:4]
    start[4:] = w @ X[:, 4:]
    # one Gauss-Newton (Karcher) step after the chordal start: its error is third
    # order in the spread, far below sensor noise at filter spreads (tested);
    # = manifold_mean(self, X, w, start, iters=1), inlined on the fused kernels
    res: Array = _np_retract_rows(start, (w @ _np_local_rows(start, X))[None, :])[0]
    return res

