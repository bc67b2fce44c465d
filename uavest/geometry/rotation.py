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

import numpy as np

from .spaces import manifold_mean

Array = np.ndarray

#: Standard gravity (m/s^2 per g), also MAVLink's "milli-g" unit.
G0 = 9.80665

__all__ = [
    "G0",
    "AttitudeSpace",
    "dcm_to_quat",
    "euler_to_quat",
    "quat_canonical",
    "quat_conj",
    "quat_exp",
    "quat_log",
    "quat_mul",
    "quat_rotate",
    "quat_rotate_inv",
    "quat_slerp_interp",
    "quat_to_dcm",
    "quat_to_euler",
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
    if p.ndim == 1 and q.ndim > 1:
        w, x, y, z = p
        L = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])
        return q @ L.T
    if q.ndim == 1 and p.ndim > 1:
        w, x, y, z = q
        Rm = np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])
        return p @ Rm.T
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
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_canonical(q: Array) -> Array:
    """``q`` or ``-q`` so that the scalar part is >= 0 (same rotation)."""
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_exp(v: Array) -> Array:
    """Unit quaternion of rotation vector(s) ``v`` (rad): ``[cos(|v|/2), sin(|v|/2) v/|v|]``
    (Taylor series below 1e-5 rad, so smooth at zero)."""
    v = np.asarray(v, dtype=float)
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
    w = q[..., 0]
    sgn = np.where(w < 0.0, -1.0, 1.0)
    w = np.abs(w)
    xyz = q[..., 1:] * sgn[..., None]
    n = np.sqrt(np.einsum("...i,...i->...", xyz, xyz))
    small = n < 1e-8
    k = np.where(
        small, 2.0 / np.maximum(w, 1e-300), 2.0 * np.arctan2(n, w) / np.where(small, 1.0, n)
    )
    return k[..., None] * xyz


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
    return np.einsum("...ij,...j->...i", quat_to_dcm(q), v)


def quat_rotate_inv(q: Array, v: Array) -> Array:
    """``R(q)^T v``: NED vector(s) ``v`` expressed in body FRD."""
    return np.einsum("...ji,...j->...i", quat_to_dcm(q), v)


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
        return np.eye(3) - 0.5 * K + K @ K / 6.0
    th = np.sqrt(th2)
    return np.eye(3) - (1 - np.cos(th)) / th2 * K + (th - np.sin(th)) / (th2 * th) * K @ K


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


class AttitudeSpace:
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

    def retract(self, x: Array, dx: Array) -> Array:
        q = quat_mul(x[..., :4], quat_exp(dx[..., :3]))
        q /= np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]
        b = x[..., 4:] + dx[..., 3:]
        lead = np.broadcast_shapes(q.shape[:-1], b.shape[:-1])
        return np.concatenate(
            [np.broadcast_to(q, lead + (4,)), np.broadcast_to(b, lead + (3,))], axis=-1
        )

    def local(self, x: Array, y: Array) -> Array:
        d = quat_log(quat_mul(quat_conj(x[..., :4]), y[..., :4]))
        db = y[..., 4:] - x[..., 4:]
        d, db = np.broadcast_arrays(d, db)
        return np.concatenate([d, db], axis=-1)

    def mean(self, X: Array, w: Array, x0: Array | None = None) -> Array:
        ref = X[0] if x0 is None else x0
        q = X[:, :4]
        sgn = np.where(q @ ref[:4] < 0.0, -1.0, 1.0)
        qm = (w * sgn) @ q
        nq = np.linalg.norm(qm)
        start = np.concatenate([qm / nq if nq > 1e-9 else ref[:4], w @ X[:, 4:]])
        # one Gauss-Newton (Karcher) step after the chordal start: its error is third
        # order in the spread, far below sensor noise at filter spreads (tested)
        return manifold_mean(self, X, w, start, iters=1)

    def __repr__(self) -> str:
        return "AttitudeSpace(q*Exp(dtheta), b+db)"
