"""The navigation state space: attitude x velocity x position x gyro bias x accel bias.

State ``x`` (size 16)::

    x = [q (4), v (3), p (3), bg (3), ba (3)]

- ``q``  attitude quaternion, body FRD -> NED, scalar-first (as :class:`AttitudeSpace`);
- ``v``  velocity in NED, m/s;
- ``p``  position in NED, m, relative to a :class:`~uavest.geometry.geodesy.LocalFrame`
  origin;
- ``bg`` gyro bias, rad/s, body FRD;
- ``ba`` accelerometer bias, m/s^2, body FRD.

Tangent ``dx`` (dim 15) = ``[dtheta (rad, body FRD), dv, dp, dbg, dba]``. The retraction
is the right (body-frame) perturbation used by the attitude space, ``q <- q * Exp(dtheta)``,
and plain addition on the Euclidean blocks; ``local`` is its inverse with the short-way
quaternion log, so ``q`` and ``-q`` are the same point. ``mean`` is the sign-aligned
chordal mean of the quaternions plus the weighted sum of the vector blocks, refined by one
Gauss-Newton (Karcher) step, as :class:`AttitudeSpace` does.

Everything is vectorised over rows: ``x`` (16,) or (M, 16) against ``dx`` (M, 15).

``NavSpace(extra=3)`` appends Euclidean components after ``ba`` (``x`` size 19, ``dx``
dim 18): the navigation model's GNSS receiver bias ``bp`` (m, NED) when it has one
(:class:`uavest.models.navigation.NavNoise`, ``gnss_bias_tau``). ``mag=2`` appends two
more after those: the errors (rad) of the magnetic reference's inclination and declination
(``NavNoise.mag_ref_inc`` / ``mag_ref_dec``), so ``NavSpace(extra=3, mag=2)`` has ``x``
size 21 and ``dx`` dim 20. ``drift=3`` puts three between the ``extra`` and the ``mag``
ones: the gyro bias's rate of change ``dbg/dt`` (rad/s^2, body FRD;
``NavNoise.gyro_drift_walk``). Every appended component is Euclidean.
"""

from __future__ import annotations

import math

import numpy as np

from uavest.geometry.rotation import (
    QuatRowsSpace,
    _np_local_rows,
    _np_mean,
    _np_retract_rows,
    qexp_f,
    qmul_f,
)

Array = np.ndarray

#: slices of the ambient state (size 16)
Q, V, P, BG, BA = slice(0, 4), slice(4, 7), slice(7, 10), slice(10, 13), slice(13, 16)
#: slices of the tangent vector (dim 15)
DTH, DV, DP, DBG, DBA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)

SIZE = 16
DIM = 15


#: :meth:`NavSpace.retract`'s numpy rows for ``x`` (16,) or (M, 16) and ``dx`` (M, 15)
#: (or the same with extra Euclidean components), :meth:`NavSpace.local`'s and
#: :meth:`NavSpace.mean`'s: the attitude space's fused kernels, which take any width of a
#: quaternion and Euclidean components (the references of the compiled kernels the
#: space uses when they are in use: :func:`~uavest.geometry.rotation.retract_rows`)
nav_retract_rows = _np_retract_rows
nav_local_rows = _np_local_rows
nav_mean = _np_mean


def nav_retract_one(x: Array, dx: Array) -> Array:
    """:meth:`NavSpace.retract` of one state ``x`` (16,) by one tangent ``dx`` (15,) (or
    the same with extra components): the rotation on Python floats (``qexp_f``,
    ``qmul_f``), the formula of :func:`nav_retract_rows` without numpy's per-call cost
    (the EKF retracts once per update). A rotation that is not finite takes the rows
    (numpy's NaN, where ``math.sin`` would raise); a zero quaternion normalises to NaN as
    numpy's division does."""
    th = dx[:3].tolist()
    if not (math.isfinite(th[0]) and math.isfinite(th[1]) and math.isfinite(th[2])):
        res: Array = nav_retract_rows(x, dx[None, :])[0]
        return res
    q = qmul_f(x[:4].tolist(), qexp_f(th))
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    k = 1.0 / n if n > 0.0 else math.nan
    out = np.empty(dx.shape[0] + 1)
    out[:4] = (q[0] * k, q[1] * k, q[2] * k, q[3] * k)
    np.add(x[4:], dx[3:], out=out[4:])
    return out


class NavSpace(QuatRowsSpace):
    """SO(3) x R^3 (v NED) x R^3 (p NED) x R^3 (gyro bias) x R^3 (accel bias).

    ``size`` 16, tangent ``dim`` 15 (``extra`` more of each: Euclidean components after
    the accelerometer bias, then ``mag`` more: the magnetic reference's errors); see the
    module docstring for the layout and units.
    """

    def __init__(self, extra: int = 0, mag: int = 0, drift: int = 0) -> None:
        self.extra = int(extra)
        self.mag = int(mag)
        self.drift = int(drift)
        self.dim = DIM + self.extra + self.drift + self.mag
        self.size = SIZE + self.extra + self.drift + self.mag

    @property
    def mag_slice(self) -> slice:
        """The magnetic reference's error components in ``x`` (empty without them); in the
        tangent they are one index lower."""
        return slice(self.size - self.mag, self.size)

    @property
    def drift_slice(self) -> slice:
        """The gyro bias's rate components in ``x`` (after the ``extra`` ones; empty
        without them); in the tangent they are one index lower."""
        a = SIZE + self.extra
        return slice(a, a + self.drift)

    @property
    def drift_tangent(self) -> slice:
        """:attr:`drift_slice` in the tangent (one index lower)."""
        a = DIM + self.extra
        return slice(a, a + self.drift)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, NavSpace) and other.extra == self.extra
                and other.mag == self.mag and other.drift == self.drift)

    def __hash__(self) -> int:
        return hash(("NavSpace", self.extra, self.mag, self.drift))

    # the filters' shapes go to the attitude space's row kernels (QuatRowsSpace); one
    # state's retraction to the float path (the EKF's update), one state's local to the
    # numpy rows
    def _retract_one(self, x: Array, dx: Array) -> Array:
        return nav_retract_one(x, dx)

    def _local_one(self, x: Array, y: Array) -> Array:
        res: Array = nav_local_rows(x, y[None, :])[0]
        return res

    def __repr__(self) -> str:
        extra = f", +{self.extra}" if self.extra else ""
        extra += f", +{self.drift} drift" if self.drift else ""
        extra += f", +{self.mag} mag" if self.mag else ""
        return f"NavSpace(q*Exp(dtheta), v+dv, p+dp, bg+dbg, ba+dba{extra})"
