"""Radar measurement: range, azimuth, elevation and (optionally) range rate.

Frames (all right-handed, metres, radians, seconds):

* **World frame**: ENU, x east, y north, z up. Target states are world-frame
  ``[p_1..p_d, v_1..v_d, extra...]`` with ``d = ndim`` (2 or 3) axes; extra components
  (e.g. a turn rate) are ignored by the radar.
* **Sensor frame** ``s``: origin at the antenna ``position`` (world), axes given by the
  rotation ``R_ws`` (world-from-sensor; columns are the sensor axes in world
  coordinates). For a UAV-carried radar ``R_ws`` is the vehicle attitude in FLU
  convention (x forward, y left, z up; from the attitude pipeline's FRD -> NED
  quaternion use :meth:`SensorPose.from_ned_frd`); for a ground radar with identity attitude the
  sensor frame *is* ENU (x east, y north, z up).
* Line of sight ``d = R_ws^T (p - position)`` (sensor frame), then
  ``range = |d|``,
  ``azimuth = atan2(d_y, d_x)``: counter-clockwise from the sensor x axis, in [-pi, pi)
  (sampled measurements and residuals are wrapped there by :func:`wrap_angle`)
  (for a ground radar with identity attitude: counter-clockwise from east, the
  mathematical convention; *not* a compass bearing),
  ``elevation = atan2(d_z, hypot(d_x, d_y))`` in [-pi/2, pi/2] (3-D only),
  ``range_rate = d . (R_ws^T (v - velocity)) / range`` (m/s, positive when receding),
  with ``velocity`` the sensor's world velocity.

In 2-D the sensor frame is a rotation by the yaw ``psi`` in the plane and the
measurement is ``[range, azimuth(, range_rate)]``.

Angle handling: :meth:`RadarMeasurement.residual` wraps the azimuth component to
[-pi, pi); :meth:`RadarMeasurement.mean` takes the circular (weighted resultant) mean of
the azimuth, so sigma-point and ensemble means are right across +-pi. Elevation lies in
[-pi/2, pi/2] and never crosses a branch cut, so it is averaged and differenced
arithmetically.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..compiled import read_only, register
from ..core.interfaces import Measurement
from ..errors import InputError
from ..geometry.spaces import VectorSpace

Array = np.ndarray

COMPONENTS = ("range", "azimuth", "elevation", "range_rate")
_EPS = 1e-9  # m, floor of range / horizontal range in divisions
_I2 = np.eye(2)
_TWO_PI = 2.0 * math.pi


def wrap_angle(a: Array | float) -> Array:
    """Wrap angle(s) (rad) to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def rot_z(psi: float) -> Array:
    """3x3 rotation about z by ``psi`` (rad, counter-clockwise)."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def euler_zyx(yaw: float, pitch: float, roll: float) -> Array:
    """World-from-body rotation (ENU world, FLU body) from Z-Y-X Euler angles (rad):
    yaw about z (counter-clockwise from east), then pitch about y, then roll about x."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    Ry = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
    Rx = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return Rz @ Ry @ Rx


_T_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # own inverse
_T_FRD_FLU = np.diag([1.0, -1.0, -1.0])  # own inverse


@dataclass(frozen=True)
class SensorPose:
    """Radar pose in the world (ENU) frame: ``position`` (d,) m, ``R_ws`` (d, d)
    world-from-sensor rotation, ``velocity`` (d,) m/s. ``d`` = 2 or 3."""

    position: Array
    R_ws: Array
    velocity: Array

    @staticmethod
    def fixed(ndim: int, position=None, yaw: float = 0.0) -> SensorPose:
        """A ground-fixed radar at ``position`` (default origin) with heading ``yaw``."""
        p = np.zeros(ndim) if position is None else np.asarray(position, float)[:ndim]
        R = rot_z(yaw)[:ndim, :ndim]
        return SensorPose(p, R, np.zeros(ndim))

    @staticmethod
    def from_ned_frd(q, position_ned, velocity_ned=None) -> SensorPose:
        """3-D pose from the attitude pipeline's conventions: unit quaternion ``q``
        (scalar-first, rotates body FRD into NED, :mod:`uavest.geometry.rotation`) and the
        antenna position / velocity in NED (m, m/s; velocity default 0).

        ``R_ws = T_enu_ned R(q) T_frd_flu`` with ``T_enu_ned`` = ``T_ned_enu`` = [[0, 1, 0],
        [1, 0, 0], [0, 0, -1]] (swap north/east, flip down) and ``T_frd_flu`` = diag(1, -1,
        -1); position and velocity are mapped by ``T_enu_ned``. (The NED origin must be the
        world origin of the targets.)"""
        from ..geometry.rotation import quat_to_dcm

        R_nb = quat_to_dcm(np.asarray(q, float))
        R = _T_ENU_NED @ R_nb @ _T_FRD_FLU
        p = _T_ENU_NED @ np.asarray(position_ned, float)
        v = np.zeros(3) if velocity_ned is None else _T_ENU_NED @ np.asarray(velocity_ned, float)
        return SensorPose(p, R, v)


class RadarMeasurement(Measurement):
    """Radar measurement model (see module docstring for frames and conventions).

    Args:
      ndim: spatial axes of the target state (2 or 3).
      state_dim: tangent dimension of the target state (>= 2*ndim; e.g. 5 for 2-D CT).
      sigma_range: range noise std (m).
      sigma_az: azimuth noise std (rad).
      sigma_el: elevation noise std (rad; 3-D only).
      sigma_rr: range-rate noise std (m/s); None = no range-rate component.
      pose: the sensor pose (default: fixed at the origin, identity attitude).

    ``components`` lists the measurement layout, e.g. ("range", "azimuth", "elevation").
    """

    def __init__(
        self,
        ndim: int = 2,
        state_dim: int | None = None,
        sigma_range: float = 10.0,
        sigma_az: float = np.deg2rad(1.0),
        sigma_el: float = np.deg2rad(1.0),
        sigma_rr: float | None = None,
        pose: SensorPose | None = None,
    ) -> None:
        if ndim not in (2, 3):
            raise InputError("ndim must be 2 or 3")
        self.ndim = ndim
        self.space = VectorSpace(state_dim or 2 * ndim)
        comps = ["range", "azimuth"] + (["elevation"] if ndim == 3 else [])
        sig = [sigma_range, sigma_az] + ([sigma_el] if ndim == 3 else [])
        if sigma_rr is not None:
            comps.append("range_rate")
            sig.append(sigma_rr)
        self.components = tuple(comps)
        self.sigmas = np.asarray(sig, float)
        self.R = np.diag(self.sigmas**2)
        self.pose = pose or SensorPose.fixed(ndim)
        self._az = 1
        self._rr = comps.index("range_rate") if sigma_rr is not None else None

    def with_pose(self, pose: SensorPose) -> RadarMeasurement:
        """Same radar at another pose (a cheap shallow copy)."""
        m = object.__new__(RadarMeasurement)
        m.__dict__.update(self.__dict__)
        m.pose = pose
        return m

    # -- geometry -------------------------------------------------------------------------
    def _los(self, X: Array) -> tuple[Array, Array | None]:
        """Line of sight D and relative velocity V (None without a range-rate component,
        which is the only one that reads it) in the sensor frame, rows of ``X``."""
        d = self.ndim
        D = (X[:, :d] - self.pose.position) @ self.pose.R_ws  # rows: R^T (p - s)
        if self._rr is None:
            return D, None
        V = (X[:, d : 2 * d] - self.pose.velocity) @ self.pose.R_ws
        return D, V

    def h(self, X: Array) -> Array:
        """Noise-free measurements of states ``X`` (M, n) -> (M, m)."""
        if getattr(X, "ndim", 0) != 2:
            X = np.atleast_2d(X)
        if X.shape[0] == 1 and self.ndim == 2 and self._rr is None:
            # one state (the EKF): the same expressions on scalars
            dx, dy = ((X[0, :2] - self.pose.position) @ self.pose.R_ws).tolist()
            return np.array([[math.sqrt(dx * dx + dy * dy), math.atan2(dy, dx)]])
        D, V = self._los(X)
        out = np.empty((X.shape[0], 2 + (self.ndim == 3) + (self._rr is not None)))
        r = out[:, 0]  # the columns written in place (no list and stack)
        np.sqrt(np.einsum("ij,ij->i", D, D), out=r)
        np.arctan2(D[:, 1], D[:, 0], out=out[:, 1])
        c = 2
        if self.ndim == 3:
            np.arctan2(D[:, 2], np.hypot(D[:, 0], D[:, 1]), out=out[:, 2])
            c = 3
        if self._rr is not None:
            np.divide(np.einsum("ij,ij->i", D, V), np.maximum(r, _EPS), out=out[:, c])
        return out

    def H(self, x: Array) -> Array:
        """Analytic Jacobian (m, n) w.r.t. the world-frame state. Range / azimuth (2-D, no
        range rate: the EKF's single-detection case) in closed form on scalars, the same
        expressions as :meth:`H_rows`; every other layout through :meth:`H_rows`."""
        x = np.asarray(x, float)
        if self.ndim != 2 or self._rr is not None:
            return self.H_rows(x[None, :])[0]
        return self._h_H2(x)[1]

    def h_H(self, x: Array) -> tuple[Array, Array]:
        """(h(x), H(x)) of one state: the 2-D range / azimuth case from one line of sight
        (the same expressions as :meth:`h` and :meth:`H`)."""
        if self.ndim != 2 or self._rr is not None:
            return self.h(x[None, :])[0], self.H(x)
        return self._h_H2(np.asarray(x, float))

    def _h_H2(self, x: Array) -> tuple[Array, Array]:
        R = self.pose.R_ws
        aligned = self._axes_aligned()
        if aligned:  # D = (p - s) I on floats: the products by 1 and 0 are exact, and
            # the BLAS product sums them onto +0 (signed zeros as it gives them)
            px, py = float(x[0] - self.pose.position[0]), float(x[1] - self.pose.position[1])
            dx, dy = (0.0 + px) + py * 0.0, (0.0 + px * 0.0) + py
        else:
            dx, dy = ((x[:2] - self.pose.position) @ R).tolist()  # D = R^T (p - s)
        z = np.array([math.sqrt(dx * dx + dy * dy), math.atan2(dy, dx)])
        r2 = max(dx * dx + dy * dy, _EPS**2)
        r = math.sqrt(r2)
        Hm = np.zeros((2, self.space.dim))
        if aligned:  # sensor axes = world axes: R gD = gD
            Hm[0, 0], Hm[0, 1], Hm[1, 0], Hm[1, 1] = dx / r, dy / r, -dy / r2, dx / r2
        else:
            Hm[:, :2] = np.array([[dx / r, dy / r], [-dy / r2, dx / r2]]) @ R.T
        return z, Hm

    def h_H_rows(self, X: Array) -> tuple[Array, Array]:
        """(h(X), H_rows(X)) from one line of sight per row (the 2-D range / azimuth case;
        the same expressions as :meth:`h` and :meth:`H_rows`)."""
        if self.ndim != 2 or self._rr is not None:
            return self.h(X), self.H_rows(X)
        D = self._los(X)[0]
        rr = np.einsum("ij,ij->i", D, D)
        Z = np.empty((D.shape[0], 2))
        Z[:, 0] = np.sqrt(rr)
        Z[:, 1] = np.arctan2(D[:, 1], D[:, 0])
        return Z, self._H2_rows(D, np.maximum(rr, _EPS**2))

    def _H2_rows(self, D: Array, r2: Array) -> Array:
        """Range / azimuth Jacobians (M, 2, n) from the 2-D line of sight ``D`` and its
        floored squared length ``r2`` (rho = r in 2-D)."""
        Hm = np.zeros((D.shape[0], 2, self.space.dim))
        g = Hm[:, :, :2]
        g[:, 0] = D / np.sqrt(r2)[:, None]
        g[:, 1, 0], g[:, 1, 1] = -D[:, 1] / r2, D[:, 0] / r2
        if not self._axes_aligned():  # d/dp = R gD
            g[...] = g @ self.pose.R_ws.T
        return Hm

    def _axes_aligned(self) -> bool:
        """True if the 2-D sensor axes are the world axes (R_ws = I), remembered per pose."""
        pose = self.pose
        memo = self.__dict__.get("_aligned")
        if memo is None or memo[0] is not pose:
            R = pose.R_ws
            memo = (pose, R is _I2 or np.array_equal(R, _I2))
            self._aligned = memo
        return memo[1]

    def H_rows(self, X: Array) -> Array:
        """Analytic Jacobians at every row of ``X`` (M, n) -> (M, m, n), vectorised."""
        d = self.ndim
        D, V = self._los(X)
        M = D.shape[0]
        # floors as in h(): a target at the sensor (r = 0) or straight above / below it
        # (rho = 0, e.g. under a UAV radar) gives a finite (zero) gradient, not inf/NaN
        r2 = np.maximum(np.einsum("ij,ij->i", D, D), _EPS**2)
        if d == 2 and self._rr is None:  # range / azimuth: two gradient rows
            return self._H2_rows(D, r2)
        r = np.sqrt(r2)
        rho2 = np.maximum(D[:, 0] ** 2 + D[:, 1] ** 2, _EPS**2)
        zero = np.zeros((M, d))
        daz = np.zeros((M, d))
        daz[:, 0], daz[:, 1] = -D[:, 1] / rho2, D[:, 0] / rho2
        rows = [(D / r[:, None], zero), (daz, zero)]
        if d == 3:
            rho = np.sqrt(rho2)
            de = np.stack([-D[:, 0] * D[:, 2] / (r2 * rho), -D[:, 1] * D[:, 2] / (r2 * rho),
                           rho / r2], axis=1)
            rows.append((de, zero))
        if self._rr is not None:
            rr = np.einsum("ij,ij->i", D, V) / r
            rows.append(((V - (rr / r)[:, None] * D) / r[:, None], D / r[:, None]))
        Hm = np.zeros((M, len(rows), self.space.dim))
        Rt = self.pose.R_ws.T
        for i, (gD, gV) in enumerate(rows):
            # d/dp = R gD (since D = R^T (p - s)); same for v; row-wise gD @ R^T
            Hm[:, i, :d] = gD @ Rt
            Hm[:, i, d : 2 * d] = gV @ Rt
        return Hm

    def linearise_rows(self, X: Array, z: Array, w: Array
                       ) -> tuple[Array, Array, Array, Array]:
        """:meth:`Measurement.linearise_rows` (the local hybrid's Jacobians ``Hs`` (M, m, n),
        residuals ``nu`` (M, m), deviations ``dY`` (M, m) from the weighted mean and its
        residual ``nubar`` (m,)). The radar without range rate (2-D range / azimuth, 3-D
        range / azimuth / elevation) runs it as one compiled kernel if numba is there
        (:data:`RADAR_KERNELS`; ``UAVEST_NUMBA=0`` switches it off): the composed
        default's arrays to rounding, ~10x faster at M = 585. Range-rate layouts, and
        arguments of other shapes, take the default."""
        if self._rr is None:
            nb = RADAR_KERNELS.get()
            if nb:
                out = self._linearise_compiled(nb, X, z, w)
                if out is not None:
                    return out
        return super().linearise_rows(X, z, w)

    def _linearise_compiled(self, nb, X, z, w) -> tuple[Array, Array, Array, Array] | None:
        """:meth:`linearise_rows` through the kernels ``nb`` (``linearise2`` in 2-D,
        ``linearise3`` in 3-D), or None if the arguments are not (M, >= d) rows, (d,)
        and (M,) with d = ndim (the default then raises or broadcasts as it does)."""
        d = self.ndim
        # (views, no copies of float64 C arrays: one numba type whatever the caller's flags)
        X, z, w = read_only(X), read_only(z), read_only(w)
        if X.ndim != 2 or X.shape[1] < d or z.shape != (d,) or w.shape != (X.shape[0],):
            return None
        memo = self.__dict__.get("_kpose")
        if memo is None or memo[0] is not self.pose:
            memo = self._kernel_pose()
        pose, tag = memo[1], memo[2]
        if pose is None:
            return None
        M, n = X.shape[0], len(tag)
        Hs, nu, dY, nubar = np.empty((M, d, n)), np.empty((M, d)), np.empty((M, d)), np.empty(d)
        (nb.linearise2 if d == 2 else nb.linearise3)(X, pose, z, w, Hs, nu, dY, nubar, tag)
        return Hs, nu, dY, nubar

    def _kernel_pose(self) -> tuple:
        """(pose, its kernel tuple or None if its shapes are not the radar's, the tuple of
        n zeros), remembered per pose (a new pose every step costs one conversion to
        floats). 2-D: (px, py, R00, R01, R10, R11, aligned, eps2), ``aligned`` 1.0 if R_ws
        equals the identity (the test of :meth:`_axes_aligned` on floats); 3-D: (px, py,
        pz, R00, R01, ..., R22, eps2), R_ws row-major."""
        pose = self.pose
        R, p = np.asarray(pose.R_ws, float), np.asarray(pose.position, float)
        args = None
        if self.ndim == 2 and R.shape == (2, 2) and p.shape == (2,):
            (r00, r01), (r10, r11) = R.tolist()
            aligned = r00 == 1.0 and r01 == 0.0 and r10 == 0.0 and r11 == 1.0
            args = (*p.tolist(), r00, r01, r10, r11, float(aligned), _EPS**2)
        elif self.ndim == 3 and R.shape == (3, 3) and p.shape == (3,) and self.space.dim >= 3:
            args = (*p.tolist(), *R.ravel().tolist(), _EPS**2)
        memo = (pose, args, (0.0,) * self.space.dim)
        self._kpose = memo
        return memo

    # -- angle-aware arithmetic -----------------------------------------------------------
    def residual(self, a: Array, b: Array) -> Array:
        """``a - b`` with the azimuth wrapped to [-pi, pi); broadcasts (M, m) vs (m,)."""
        r = np.asarray(a, float) - np.asarray(b, float)
        if r.ndim == 1:  # one residual (the EKF, the UKF): the same wrap on a Python float
            r[self._az] = (float(r[self._az]) + math.pi) % _TWO_PI - math.pi
        else:  # wrap_angle's three operations, in place on the azimuth column
            t = r[..., self._az]
            t += np.pi
            np.remainder(t, _TWO_PI, out=t)
            t -= np.pi
        return r

    def mean(self, Y: Array, w: Array) -> Array:
        """Weighted mean of measurements ``Y`` (M, m); circular for the azimuth."""
        m = np.dot(w, Y)  # = w @ Y, less per-call overhead
        a = Y[:, self._az]
        m[self._az] = np.arctan2(np.dot(w, np.sin(a)), np.dot(w, np.cos(a)))  # not math:
        # numpy's arctan2 is its own (SIMD) implementation, libm's differs in the last bit
        return m

    def mean_rows(self, Y: Array, w: Array) -> Array:
        """:meth:`mean` of every stack ``Y[t]`` (T, M, m) with the weights ``w`` (M,)."""
        m = np.einsum("j,tjm->tm", w, Y)
        a = Y[:, :, self._az]
        m[:, self._az] = np.arctan2(np.sin(a) @ w, np.cos(a) @ w)
        return m

    # -- inverse (track initiation) -------------------------------------------------------
    def to_cartesian(self, z: Array) -> tuple[Array, Array]:
        """World position (d,) of measurement ``z`` and its linearised covariance (d, d).

        Uses range, azimuth (and elevation; 0 in 2-D). The covariance is J R J^T with J the
        Jacobian of the polar-to-Cartesian map (converted-measurement initialisation)."""
        d = self.ndim
        r, az = float(z[0]), float(z[1])
        el = float(z[2]) if d == 3 else 0.0
        ce, se, ca, sa = np.cos(el), np.sin(el), np.cos(az), np.sin(az)
        if d == 2:
            ds = np.array([r * ca, r * sa])
            J = np.array([[ca, -r * sa], [sa, r * ca]])
            Rz = self.R[:2, :2]
        else:
            ds = np.array([r * ce * ca, r * ce * sa, r * se])
            J = np.array(
                [
                    [ce * ca, -r * ce * sa, -r * se * ca],
                    [ce * sa, r * ce * ca, -r * se * sa],
                    [se, 0.0, r * ce],
                ]
            )
            Rz = self.R[:3, :3]
        Rws = self.pose.R_ws
        p = self.pose.position + Rws @ ds
        C = Rws @ J @ Rz @ J.T @ Rws.T
        return p, 0.5 * (C + C.T)

    def sample(self, X: Array, rng: np.random.Generator) -> Array:
        """Noisy measurements of states ``X`` (M, n); azimuth wrapped."""
        Z = self.h(X) + rng.standard_normal((np.atleast_2d(X).shape[0], self.dim)) * self.sigmas
        Z[:, self._az] = wrap_angle(Z[:, self._az])
        return Z

    def measurement_box(self, r_max: float, rr_max: float = 100.0) -> tuple[Array, Array]:
        """Lower/upper bounds of the measurement space used for uniform clutter:
        range [0, r_max], azimuth [-pi, pi), elevation [0, pi/4] (3-D), range rate
        [-rr_max, rr_max]."""
        lo, hi = [0.0, -np.pi], [r_max, np.pi]
        if self.ndim == 3:
            lo.append(0.0)
            hi.append(np.pi / 4)
        if self._rr is not None:
            lo.append(-rr_max)
            hi.append(rr_max)
        return np.asarray(lo), np.asarray(hi)


def _kernel_cases(nb):
    """The self-check (:mod:`uavest.compiled`): the kernel against
    :meth:`Measurement.linearise_rows` on small cases (a ground radar: axes aligned,
    n = 4, equal weights; a rotated and offset one: n = 5, unequal weights; the members'
    azimuths straddling +-pi, one member at the sensor), compared to 1e-10 of the
    Jacobian rows' largest entry, of 1e4 m for ranges and of 1 rad for angles; and a
    3-D case (a rotated, offset UAV radar, n = 6, a member at the sensor and one on its
    z axis)."""
    g = np.random.default_rng(5)
    M = 24
    poses = (SensorPose.fixed(2), SensorPose(np.array([150.0, -40.0]), rot_z(2.5)[:2, :2],
                                             np.zeros(2)))
    scale = np.array([1e4, 1.0])  # m, rad
    for i, (pose, n, w) in enumerate(((poses[0], 4, np.full(M, 1.0 / M)),
                                      (poses[1], 5, g.dirichlet(np.full(M, 2.0))))):
        radar = RadarMeasurement(2, n, pose=pose)
        X = np.zeros((M, n))  # behind the sensor's x axis, 2 km away: azimuths near +-pi
        X[:, :2] = pose.position + (np.array([-2000.0, 0.0]) + g.normal(0.0, 100.0, (M, 2))
                                    ) @ pose.R_ws.T
        X[0, :2] = pose.position
        X[:, 2:] = g.normal(0.0, 10.0, (M, n - 2))
        z = np.array([2000.0, math.pi - 0.01])
        got = radar._linearise_compiled(nb, X, z, w)
        want = Measurement.linearise_rows(radar, X, z, w)
        if got is None:
            yield f"case {i}", None, want[0]
            return
        yield from _scaled(f"case {i}", got, want, scale)
    # 3-D: a UAV radar (rotated, offset), n = 6, unequal weights, azimuths near +-pi,
    # one member at the sensor and one straight above it
    pose = SensorPose(np.array([150.0, -40.0, 300.0]), euler_zyx(2.5, 0.2, -0.3), np.zeros(3))
    radar = RadarMeasurement(3, 6, pose=pose)
    X = np.zeros((M, 6))
    X[:, :3] = pose.position + (np.array([-2000.0, 0.0, 400.0]) + g.normal(0.0, 100.0, (M, 3))
                                ) @ pose.R_ws.T
    X[0, :3] = pose.position
    X[1, :3] = pose.position + 500.0 * pose.R_ws[:, 2]
    X[:, 3:] = g.normal(0.0, 10.0, (M, 3))
    w = g.dirichlet(np.full(M, 2.0))
    z = np.array([2000.0, math.pi - 0.01, 0.2])
    got = radar._linearise_compiled(nb, X, z, w)
    want = Measurement.linearise_rows(radar, X, z, w)
    if got is None:
        yield "3-D case", None, want[0]
        return
    yield from _scaled("3-D case", got, want, np.array([1e4, 1.0, 1.0]))


def _scaled(label, got, want, scale):
    """(label, got, want) of the self-check with the Jacobian rows divided by their
    largest entry and the rest by ``scale`` (m, rad per component)."""
    row = np.abs(want[0]).max(axis=2, keepdims=True)
    row = np.where(row > 0.0, row, 1.0)
    yield f"{label} Hs", got[0] / row, want[0] / row
    for name, a, b in zip(("nu", "dY", "nubar"), got[1:], want[1:], strict=True):
        yield f"{label} {name}", np.asarray(a) / scale, np.asarray(b) / scale


#: The compiled kernel of :meth:`RadarMeasurement.linearise_rows`
#: (:mod:`uavest.models._compiled_radar`). A filter may ``get()`` it at init, so that
#: the load is not in its first step.
RADAR_KERNELS = register("radar", "uavest.models._compiled_radar",
                         "numba kernel of the radar's linearise_rows", _kernel_cases,
                         rtol=0.0, atol=1e-10)
