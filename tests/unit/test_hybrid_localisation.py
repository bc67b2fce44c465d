"""Variable localisation in the hybrid's shift update (``Measurement.unseen_rows``,
:func:`uavest.core.hybrid.keep_unseen`): a measurement leaves the weighted mean and
covariance of the states it cannot inform as they were, whatever the ensemble's chance
correlations and the confidence weights would do to them; the rows it does inform get
exactly the update they got without it."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.core.gaussian import Gaussian
from uavest.core.hybrid import HybridShift
from uavest.core.interfaces import LinearMeasurement
from uavest.core.states import Ensemble, ensemble_estimate
from uavest.geometry.rotation import euler_to_quat
from uavest.geometry.spaces import VectorSpace
from uavest.models.attitude import MagField
from uavest.models.navigation import SPACE, SPACE_GNSS_BIAS, BaroHeight, GnssPosition, OnNav


class _Localised(LinearMeasurement):
    """x0 observed; x2 declared unseen."""

    def unseen_rows(self, n: int) -> np.ndarray:
        return np.array([2])


def _moments(E: Ensemble, rows, xrows=None) -> tuple[np.ndarray, np.ndarray]:
    """The estimate's mean at state indices ``xrows`` (default ``rows``) and covariance at
    tangent rows ``rows``."""
    g = ensemble_estimate(E)
    return g.x[rows if xrows is None else xrows], g.P[np.ix_(rows, rows)]


@pytest.mark.parametrize("reinflate", [False, True])
def test_unseen_rows_keep_their_mean_and_covariance_and_the_rest_is_unchanged(reinflate):
    H, R = np.array([[1.0, 0.0, 0.0]]), np.array([[0.05]])
    P = np.array([[1.0, 0.6, 0.0], [0.6, 1.0, 0.0], [0.0, 0.0, 2.0]])
    f = HybridShift(n_cloud=6, tau=0.5, reinflate=reinflate)
    space = VectorSpace(3)
    E0 = f.init(Gaussian(np.array([0.0, 1.0, -2.0]), P), space, np.random.default_rng(3))
    out = {}
    for name, me in (("plain", LinearMeasurement(H, R)), ("local", _Localised(H, R))):
        out[name], _ = f.update(E0, np.array([1.2]), me, np.random.default_rng(4))
    m0, C0 = _moments(E0, [2])
    # without: the weights reshape x2's spread through the expanded ensemble's layout
    # (here it shrinks by a sixth; x2's mean stays only by the ensemble's symmetry)
    _, Cp = _moments(out["plain"], [2])
    assert abs(Cp[0, 0] / C0[0, 0] - 1.0) > 0.1
    ml, Cl = _moments(out["local"], [2])
    np.testing.assert_allclose(ml, m0, atol=1e-12)
    np.testing.assert_allclose(Cl, C0, rtol=1e-10)
    # the seen rows: the same members as without, to rounding; the same weights (the
    # plain model takes the compiled path, the localised one the numpy path)
    np.testing.assert_allclose(out["local"].X[:, :2], out["plain"].X[:, :2], atol=1e-12)
    np.testing.assert_allclose(out["local"].w, out["plain"].w, rtol=1e-12)
    # and x1, correlated with x0 for real, did move
    assert abs(ensemble_estimate(out["local"]).x[1] - 1.0) > 0.3


def _nav_prior(space):
    n = space.dim
    x = np.zeros(space.size)
    x[:4] = euler_to_quat(0.05, -0.03, 1.0)
    x[4:7] = [3.0, -1.0, 0.2]
    x[7:10] = [10.0, 20.0, -30.0]
    sd = np.r_[np.full(3, np.radians(3.0)), np.full(3, 0.3), np.full(3, 1.0), np.full(3, 1e-3),
               np.full(3, 0.05), np.full(n - 15, 0.8)]
    C = np.diag(sd**2)
    # a real tilt-velocity correlation, none between attitude and position
    for i in range(3):
        C[i, 3 + i] = C[3 + i, i] = 0.5 * sd[i] * sd[3 + i]
    return Gaussian(x, C)


@pytest.mark.parametrize("space", [SPACE, SPACE_GNSS_BIAS], ids=["15", "18"])
def test_a_magnetometer_update_leaves_the_position_and_gnss_bias_where_they_were(space):
    """The navigation preset's hybrid (re-spread, confidence weights) on the navigation
    manifold: a 3-axis field update moves attitude and velocity, never the position or
    the receiver bias; without the localisation both move."""
    f = HybridShift(n_cloud=4, tau=0.9, reinflate=True)
    g = _nav_prior(space)
    E0 = f.init(g, space, np.random.default_rng(1))
    ref = np.array([0.45, 0.02, 0.89]) / np.linalg.norm([0.45, 0.02, 0.89])
    inner = MagField(ref, np.eye(3) * 0.006**2)
    z = inner.h(euler_to_quat(0.0, 0.0, 1.03)[None, :])[0]

    class Unlocalised(OnNav):
        def unseen_rows(self, n):
            return None

    rows = list(range(6, 9)) + list(range(15, space.dim))
    xrows = [r + 1 for r in rows]  # the quaternion's 4 entries against 3 tangent rows
    m0, C0 = _moments(E0, rows, xrows)
    res = {}
    for name, cls in (("local", OnNav), ("plain", Unlocalised)):
        me = cls(inner)
        me.space = space
        res[name], _ = f.update(E0, z, me, np.random.default_rng(2))
    ml, Cl = _moments(res["local"], rows, xrows)
    np.testing.assert_allclose(ml, m0, atol=1e-9)
    np.testing.assert_allclose(Cl, C0, rtol=1e-8, atol=1e-14)
    mp, Cp = _moments(res["plain"], rows, xrows)
    assert np.abs(mp - m0).max() > 1e-3 or np.abs(np.diag(Cp) / np.diag(C0) - 1).max() > 0.05
    # the yaw moved toward the measurement; the velocity with it (their correlation)
    x0, xl = ensemble_estimate(E0).x, ensemble_estimate(res["local"]).x
    assert np.abs(xl[4:7] - x0[4:7]).max() > 1e-4


def test_the_navigation_models_declare_what_they_cannot_see():
    inner = MagField(np.array([1.0, 0.0, 0.0]), np.eye(3))
    assert OnNav(inner).unseen_rows(15).tolist() == [6, 7, 8]
    assert OnNav(inner).unseen_rows(18).tolist() == [6, 7, 8, 15, 16, 17]
    baro = BaroHeight(np.eye(1))
    assert baro.unseen_rows(15).tolist() == [6, 7]
    assert baro.unseen_rows(18).tolist() == [6, 7, 15, 16]
    # a GNSS fix sees them all
    assert GnssPosition(np.eye(3)).unseen_rows(18) is None
