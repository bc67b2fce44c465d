"""The compiled ``RadarMeasurement.linearise_rows`` (``uavest.models._compiled_radar``,
numba; the 2-D range / azimuth and the 3-D range / azimuth / elevation radar) equals
the composed default (``Measurement.linearise_rows``: ``h_H_rows``, the circular
``mean``, three wrapped ``residual`` calls, which is also the fallback without numba or
with ``UAVEST_NUMBA=0``) to rounding; the range-rate layouts and the forced-off kernel
take the default."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import compiled_kernels

from uavest.core.interfaces import Measurement
from uavest.models import radar as radar_mod
from uavest.models.radar import _EPS, RadarMeasurement, SensorPose, euler_zyx, rot_z

TOL = 1e-12


@pytest.fixture
def nb():
    """The kernel module, loaded through :func:`radar_kernels` (its self-check must
    pass: a failure there is a failure here, not a skip)."""
    return compiled_kernels(radar_mod.RADAR_KERNELS.get, "radar kernel")


@pytest.fixture
def no_default(monkeypatch):
    """Make the composed default's first call (``h_H_rows``) fail, so that a test knows
    the kernel ran."""
    def boom(self, X):
        raise AssertionError("the composed default ran")
    monkeypatch.setattr(RadarMeasurement, "h_H_rows", boom)


def _poses():
    return {
        "aligned": SensorPose.fixed(2),
        "offset": SensorPose.fixed(2, position=[-350.0, 1200.0]),  # aligned, not at 0
        "rotated": SensorPose(np.array([150.0, -40.0]), rot_z(2.5)[:2, :2], np.zeros(2)),
        "rotated_neg": SensorPose(np.array([-7.0, 3.0]), rot_z(-1.1)[:2, :2], np.zeros(2)),
    }


def _members(pose, n, M, g, bearing=math.pi, dist=3000.0, spread=150.0):
    """M states whose line of sight from ``pose`` has the (sensor-frame) azimuth
    ``bearing`` +- spread / dist (bearing pi: members on both sides of the cut)."""
    d = dist * np.array([math.cos(bearing), math.sin(bearing)])
    X = np.empty((M, n))
    X[:, :2] = pose.position + (d + g.normal(0.0, spread, (M, 2))) @ pose.R_ws.T
    X[:, 2:] = g.normal(0.0, 20.0, (M, n - 2))
    return X


def _weights(kind, M, g):
    return np.full(M, 1.0 / M) if kind == "equal" else g.dirichlet(np.full(M, 0.7))


def _assert_matches(got, want, rscale, tol=TOL):
    """The kernel's arrays equal the default's: types and shapes exactly; the Jacobian
    rows to ``tol`` of their largest entry (the velocity / extra columns exactly 0);
    range components to ``tol`` (``rscale`` + |value|) (m), azimuths to ``tol`` (1 +
    |value|) rad (azimuth, elevation); NaN where the default has NaN; azimuth residuals
    in [-pi, pi]. 2-D and 3-D (the layout read from the arrays)."""
    assert len(got) == 4
    for a, b in zip(got, want, strict=True):
        assert type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous
        assert a.shape == b.shape
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    Hs, Hw = got[0], want[0]
    d = Hs.shape[1]  # 2 or 3 components, as many position columns
    np.testing.assert_array_equal(Hs[:, :, d:], 0.0)
    ok = ~np.isnan(Hw)
    bound = tol * np.nanmax(np.abs(Hw), axis=2, keepdims=True)
    assert np.all((np.abs(Hs - Hw) <= bound)[ok]), np.nanmax(np.abs(Hs - Hw) / bound)
    scale = np.array([rscale, 1.0, 1.0][:d])
    for a, b in zip(got[1:], want[1:], strict=True):
        ok = ~np.isnan(b)
        err = np.abs(a - b)
        assert np.all((err <= tol * (scale + np.abs(b)))[ok]), (np.nanmax(err, axis=0), scale)
        az = a[..., 1][~np.isnan(a[..., 1])]
        assert np.all((-math.pi <= az) & (az <= math.pi))


def _default(radar, X, z, w):
    return Measurement.linearise_rows(radar, X, z, w)


@pytest.mark.parametrize("pose", list(_poses()))
@pytest.mark.parametrize("weights", ["equal", "unequal"])
@pytest.mark.parametrize("n", [4, 5])
def test_equals_the_composed_default(nb, pose, weights, n):
    g = np.random.default_rng([4, n, len(pose), len(weights)])
    p = _poses()[pose]
    radar = RadarMeasurement(2, n, pose=p)
    for M, bearing in ((585, 0.4), (585, math.pi), (7, -2.0), (1, 1.0)):
        X = _members(p, n, M, g, bearing)
        w = _weights(weights, M, g)
        for z in (np.array([3010.0, bearing + 0.01]), np.array([2900.0, -bearing])):
            want = _default(radar, X, z, w)
            _assert_matches(radar.linearise_rows(X, z, w), want, 3000.0)


@pytest.mark.parametrize("pose", ["aligned", "rotated"])
def test_kernel_runs_not_the_default(nb, no_default, pose):
    g = np.random.default_rng(1)
    p = _poses()[pose]
    radar = RadarMeasurement(2, 4, pose=p)
    X = _members(p, 4, 50, g)
    Hs, nu, dY, nubar = radar.linearise_rows(X, np.array([3000.0, 3.1]), np.full(50, 0.02))
    assert Hs.shape == (50, 2, 4) and nu.shape == dY.shape == (50, 2) and nubar.shape == (2,)


@pytest.mark.parametrize("pose", ["aligned", "rotated"])
def test_straddling_the_branch_cut(nb, pose):
    """Members on both sides of +-pi (sensor frame): the circular mean lands near +-pi
    (the arithmetic mean would be near 0), the deviations are small, not ~2 pi."""
    g = np.random.default_rng(2)
    p = _poses()[pose]
    radar = RadarMeasurement(2, 5, pose=p)
    X = _members(p, 5, 585, g, math.pi, spread=200.0)
    w = g.dirichlet(np.ones(585))
    a = radar.h(X)[:, 1]
    assert np.any(a > 3.0) and np.any(a < -3.0)  # both sides of the cut
    for z1 in (math.pi - 1e-3, -math.pi + 1e-3, -math.pi, 3.0, -3.0):
        z = np.array([3000.0, z1])
        got = radar.linearise_rows(X, z, w)
        want = _default(radar, X, z, w)
        _assert_matches(got, want, 3000.0)
        assert np.abs(got[2][:, 1]).max() < 0.5  # deviations from the circular mean
        assert np.abs(got[1][:, 1]).max() < 0.7 and abs(got[3][1]) < 0.2  # z1 within 0.15


def test_azimuth_exactly_pi_and_signed_zeros(nb):
    """Members straight behind the sensor (D_y = +-0, D_x < 0: azimuth +-pi), on its axes
    and the diagonals, and exact residuals at the wrap's boundaries."""
    radar = RadarMeasurement(2, 4)
    pts = [(-1000.0, 0.0), (-1000.0, -0.0), (1000.0, 0.0), (0.0, 1000.0), (0.0, -1000.0),
           (-0.0, 1000.0), (700.0, 700.0), (-700.0, 700.0), (-700.0, -700.0),
           (700.0, -700.0)]
    X = np.zeros((len(pts), 4))
    X[:, :2] = pts
    w = np.full(len(pts), 1.0 / len(pts))
    for z1 in (math.pi, -math.pi, 0.0, -0.0, math.pi / 2, 2.0 * math.pi, -2.0 * math.pi):
        z = np.array([1000.0, z1])
        _assert_matches(radar.linearise_rows(X, z, w), _default(radar, X, z, w), 1000.0)
    got = radar.linearise_rows(X, np.array([1000.0, math.pi]), w)
    want = _default(radar, X, np.array([1000.0, math.pi]), w)
    np.testing.assert_array_equal(got[1][:3, 1], want[1][:3, 1])  # exactly, at the cut


@pytest.mark.parametrize("pose", ["aligned", "rotated"])
def test_target_at_the_sensor(nb, pose):
    """A member at the antenna (r = 0: the Jacobian rows are 0 through the floor _EPS,
    the azimuth atan2(0, 0)), one within the floor (1e-12 m), one whose r^2 underflows
    (1e-200 m) and one 1e-140 m away."""
    g = np.random.default_rng(3)
    p = _poses()[pose]
    radar = RadarMeasurement(2, 4, pose=p)
    X = _members(p, 4, 40, g, 0.3)
    for j, off in enumerate(([0.0, 0.0], [1e-12, -3e-13], [1e-200, 2e-200],
                             [-1e-140, 5e-141])):
        X[j, :2] = p.position + np.asarray(off) @ p.R_ws.T
    X[5, :2] = p.position  # once more, with all weight on the near members below
    for w in (np.full(40, 1.0 / 40), np.r_[np.full(6, 1.0 / 6), np.zeros(34)]):
        z = np.array([10.0, 0.3])
        got = radar.linearise_rows(X, z, w)
        want = _default(radar, X, z, w)
        _assert_matches(got, want, 3000.0)
        np.testing.assert_array_equal(got[0][[0, 5]], 0.0)
        assert np.all(np.abs(got[0][1, :, :2]) > 0.0)
        assert np.abs(got[0][1, 1]).max() < 1.0 / _EPS  # floored: |D| / eps^2 < 1 / eps


def test_unwrapped_measurement_and_far_residuals(nb):
    """Measured azimuths outside [-pi, pi) (beyond the kernel's fast wrap range, which
    then takes the modulo) give the default's wrapped residuals."""
    g = np.random.default_rng(6)
    radar = RadarMeasurement(2, 4, pose=_poses()["rotated"])
    X = _members(radar.pose, 4, 100, g, 2.0)
    w = g.dirichlet(np.ones(100))
    for z1 in (2.0 + 2 * math.pi, 2.0 - 6 * math.pi, 40.0, -1e6, 7.0 * math.pi):
        z = np.array([3000.0, z1])
        _assert_matches(radar.linearise_rows(X, z, w), _default(radar, X, z, w), 3000.0)


def test_non_finite_members(nb):
    """A NaN member (and one 1e200 m away, whose r^2 overflows) give NaN / inf where the
    default does; the mean is then NaN everywhere, as it is there."""
    g = np.random.default_rng(7)
    radar = RadarMeasurement(2, 4)
    X = _members(radar.pose, 4, 30, g, 1.0)
    X[3, 0] = np.nan
    X[4, :2] = [1e200, -1e200]
    w = np.full(30, 1.0 / 30)
    z = np.array([3000.0, 1.0])
    got = radar.linearise_rows(X, z, w)
    want = _default(radar, X, z, w)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
    X[3, 0] = 1.0
    X[4, :2] = [1e152, 3e151]  # r^2 > 1e300: sin / cos of the angle
    w = np.full(30, 1e-160)
    w[5:] = (1.0 - 5e-160) / 25
    got = radar.linearise_rows(X, z, w)
    _assert_matches(got, _default(radar, X, z, w), 3000.0)


def test_argument_types(nb):
    """Non-contiguous, integer and list arguments are converted (one compiled version);
    wrong shapes go to the default, which raises as it does."""
    g = np.random.default_rng(8)
    radar = RadarMeasurement(2, 4, pose=_poses()["rotated"])
    big = np.asfortranarray(np.hstack([_members(radar.pose, 4, 20, g, 0.5),
                                       np.ones((20, 3))]))
    X = big[:, :4]  # not C-contiguous
    w = np.ones(40)[::2] / 20  # strided
    z = [3000, 0.5]
    got = radar.linearise_rows(X, z, w)
    _assert_matches(got, _default(radar, X, np.asarray(z, float), w), 3000.0)
    Xi = np.round(X).astype(np.int64)
    _assert_matches(radar.linearise_rows(Xi, z, w), _default(radar, Xi, z, w), 3000.0)
    empty = radar.linearise_rows(np.zeros((0, 4)), np.array([1.0, 0.0]), np.zeros(0))
    _assert_matches(empty, _default(radar, np.zeros((0, 4)), np.array([1.0, 0.0]),
                                    np.zeros(0)), 1.0)
    with pytest.raises(ValueError):
        radar.linearise_rows(np.ascontiguousarray(X), np.array([3000.0, 0.5]), np.ones(19))
    with pytest.raises((ValueError, IndexError)):
        radar.linearise_rows(np.ones(4), np.array([3000.0, 0.5]), np.ones(1))


def test_new_pose_every_step(nb):
    """``with_pose`` copies (a UAV radar's pose each step): the kernel reads each copy's
    own pose, not the one remembered from the first."""
    g = np.random.default_rng(9)
    base = RadarMeasurement(2, 4)
    X = _members(base.pose, 4, 60, g, 1.0)
    w = np.full(60, 1.0 / 60)
    z = np.array([3000.0, 1.0])
    base.linearise_rows(X, z, w)
    for pose in _poses().values():
        m = base.with_pose(pose)
        _assert_matches(m.linearise_rows(X, z, w), _default(m, X, z, w), 5000.0)


def test_atan2_within_an_ulp_or_two(nb):
    """The kernel's atan2 against numpy's: within 2 ulp on random and near-octant
    arguments (each is within 1 ulp of the exact value); signed zeros and axes exact."""
    g = np.random.default_rng(10)
    N = 4000
    ang = g.uniform(-math.pi, math.pi, N)
    mag = 10.0 ** g.uniform(-6.0, 9.0, N)
    ys = np.r_[mag * np.sin(ang), g.uniform(0.62, 0.70, N), g.uniform(0.999, 1.001, N)]
    xs = np.r_[mag * np.cos(ang), np.ones(N), -np.ones(N)]
    got = np.array([nb.atan2(y, x) for y, x in zip(ys.tolist(), xs.tolist(), strict=True)])
    want = np.arctan2(ys, xs)
    assert np.all(np.abs(got - want) <= 2.0 * np.spacing(np.abs(want)))
    for y in (0.0, -0.0, 1.0, -1.0, 1e-310, 1e300, math.nan):
        for x in (0.0, -0.0, 1.0, -1.0, 1e-310, 1e300, math.nan):
            a, b = nb.atan2(y, x), math.atan2(y, x)
            if math.isnan(b):
                assert math.isnan(a), (y, x)
            else:
                assert a == b and math.copysign(1.0, a) == math.copysign(1.0, b), (y, x)


def test_wrap_as_numpy_remainder(nb):
    """The kernel's wrap of azimuth residuals (the fast one where it says it is right,
    and the modulo) equal ``RadarMeasurement.residual``'s (numpy's remainder) exactly,
    at the boundaries of both."""
    pi = math.pi
    d = np.array([0.0, -0.0, pi, -pi, 2 * pi, -2 * pi, 3 * pi, -3 * pi, pi - 1e-16,
                  -pi - 4e-16, 3 * pi - 4e-16, -3 * pi + 4e-16, 1e-20, -1e-20, 5.5, -5.5,
                  12.0, -12.0, 40.0, -1e6, 1e17])
    d = np.r_[d, np.random.default_rng(11).uniform(-12.0, 12.0, 2000)]
    want = RadarMeasurement(2).residual(np.c_[d, d], np.zeros(2))[:, 1]
    for v, e in zip(d.tolist(), want.tolist(), strict=True):
        assert nb.wrap_pi(v) == e, v  # (compiled.helpers.wrap_pi, which the kernels call)
        f, outside = nb._wrap_fast(v)
        t = v + pi
        assert outside == (not -2.0 * pi <= t < 4.0 * pi), v
        if not outside:
            assert f == e, v


@pytest.mark.parametrize("ndim,rr", [(2, 1.0), (3, 1.0)])
def test_other_layouts_take_the_default(monkeypatch, ndim, rr):
    """Range-rate radars (2-D and 3-D) never call a kernel and give the default exactly."""
    def boom(*a):
        raise AssertionError("the kernel ran")
    monkeypatch.setattr(radar_mod.RADAR_KERNELS, "loaded",
                        type("K", (), {"linearise2": boom, "linearise3": boom})())
    g = np.random.default_rng(12)
    radar = RadarMeasurement(ndim, sigma_rr=rr)
    X = np.c_[g.normal(1000.0, 50.0, (30, ndim)), g.normal(0.0, 5.0, (30, ndim))]
    z, w = radar.h(X[:1])[0] + 0.01, np.full(30, 1.0 / 30)
    for a, b in zip(radar.linearise_rows(X, z, w), _default(radar, X, z, w), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("ndim", [2, 3])
def test_forced_off_uses_the_default(monkeypatch, ndim):
    """``loaded = False`` (numba missing, disabled or failed) gives the default exactly."""
    monkeypatch.setattr(radar_mod.RADAR_KERNELS, "loaded", False)
    g = np.random.default_rng(13)
    if ndim == 2:
        radar = RadarMeasurement(2, 5, pose=_poses()["rotated"])
        X = _members(radar.pose, 5, 100, g)
        z = np.array([3000.0, 3.1])
    else:
        radar = RadarMeasurement(3, 6, pose=_poses3()["uav"])
        X = _members3(radar.pose, 6, 100, g)
        z = np.array([3000.0, 3.1, 0.1])
    w = g.dirichlet(np.ones(100))
    for a, b in zip(radar.linearise_rows(X, z, w), _default(radar, X, z, w), strict=True):
        np.testing.assert_array_equal(a, b)


def test_uavest_numba_0_switches_it_off(monkeypatch):
    monkeypatch.setattr(radar_mod.RADAR_KERNELS, "loaded", None)
    monkeypatch.setenv("UAVEST_NUMBA", "0")
    assert radar_mod.RADAR_KERNELS.get() is None
    assert radar_mod.RADAR_KERNELS.loaded is False


# -- 3-D: range / azimuth / elevation (linearise3) -------------------------------------


def _poses3():
    return {
        "ground": SensorPose.fixed(3),
        "offset": SensorPose.fixed(3, position=[-350.0, 1200.0, 40.0], yaw=0.7),
        "uav": SensorPose(np.array([150.0, -40.0, 500.0]), euler_zyx(2.5, 0.2, -0.3),
                          np.array([30.0, 0.0, 0.0])),
        # the attitude pipeline's FRD -> NED quaternion (unit), 800 m up
        "banked": SensorPose.from_ned_frd(np.array([0.9, 0.1, -0.3, 0.3]) / math.sqrt(0.99),
                                          [40.0, -20.0, -800.0]),
    }


def _members3(pose, n, M, g, bearing=math.pi, elev=0.15, dist=3000.0, spread=150.0):
    """M states whose (sensor-frame) line of sight from ``pose`` has the azimuth
    ``bearing`` and the elevation ``elev`` +- spread / dist."""
    d = dist * np.array([math.cos(elev) * math.cos(bearing),
                         math.cos(elev) * math.sin(bearing), math.sin(elev)])
    X = np.empty((M, n))
    X[:, :3] = pose.position + (d + g.normal(0.0, spread, (M, 3))) @ pose.R_ws.T
    X[:, 3:] = g.normal(0.0, 20.0, (M, n - 3))
    return X


def _radar3(pose, n):
    return RadarMeasurement(3, n, pose=_poses3()[pose])


@pytest.mark.parametrize("pose", ["ground", "offset", "uav", "banked"])
@pytest.mark.parametrize("weights", ["equal", "unequal"])
@pytest.mark.parametrize("n", [6, 7])
def test_3d_equals_the_composed_default(nb, pose, weights, n):
    """M = 585 (the radar preset), 7 and 1 members, azimuths on and off the cut,
    elevations low, high and negative, against the composed default to 1e-12."""
    g = np.random.default_rng([14, n, len(pose), len(weights)])
    radar = _radar3(pose, n)
    p = radar.pose
    for M, bearing, elev in ((585, 0.4, 0.1), (585, math.pi, 0.3), (7, -2.0, -0.4),
                             (1, 1.0, 1.2), (585, 2.5, 1.52)):
        X = _members3(p, n, M, g, bearing, elev)
        w = _weights(weights, M, g)
        for z in (np.array([3010.0, bearing + 0.01, elev - 0.01]),
                  np.array([2900.0, -bearing, -elev])):
            _assert_matches(radar.linearise_rows(X, z, w), _default(radar, X, z, w), 3000.0)


def test_3d_kernel_runs_not_the_default(nb, no_default):
    g = np.random.default_rng(15)
    radar = _radar3("uav", 6)
    X = _members3(radar.pose, 6, 50, g)
    Hs, nu, dY, nubar = radar.linearise_rows(X, np.array([3000.0, 3.1, 0.1]),
                                             np.full(50, 0.02))
    assert Hs.shape == (50, 3, 6) and nu.shape == dY.shape == (50, 3) and nubar.shape == (3,)


@pytest.mark.parametrize("pose", ["ground", "uav"])
def test_3d_straddling_the_branch_cut(nb, pose):
    """Members on both sides of +-pi: the circular azimuth mean near +-pi, small
    deviations (an arithmetic mean would put them ~2 pi apart)."""
    g = np.random.default_rng(16)
    radar = _radar3(pose, 6)
    X = _members3(radar.pose, 6, 585, g, math.pi, spread=200.0)
    w = g.dirichlet(np.ones(585))
    a = radar.h(X)[:, 1]
    assert np.any(a > 3.0) and np.any(a < -3.0)
    for z1 in (math.pi - 1e-3, -math.pi + 1e-3, -math.pi, 3.0, -3.0, 3.0 + 4 * math.pi):
        z = np.array([3000.0, z1, 0.15])
        got = radar.linearise_rows(X, z, w)
        _assert_matches(got, _default(radar, X, z, w), 3000.0)
        assert np.abs(got[2][:, 1]).max() < 0.5


@pytest.mark.parametrize("pose", ["ground", "uav"])
def test_3d_target_at_the_sensor_and_on_its_axis(nb, pose):
    """A member at the antenna (r = 0), members straight above and below it (rho = 0:
    the azimuth atan2(0, 0), the floors of r^2 and rho^2), within the floor, with an
    underflowing rho^2 and 1e-140 m off the axis: as the default, finite Jacobians."""
    g = np.random.default_rng(17)
    radar = _radar3(pose, 6)
    p = radar.pose
    X = _members3(p, 6, 40, g, 0.3)
    offs = ([0.0, 0.0, 0.0], [0.0, 0.0, 800.0], [0.0, 0.0, -300.0], [1e-12, -3e-13, 1e-12],
            [1e-200, 2e-200, 500.0], [-1e-140, 5e-141, 900.0], [3e-10, 0.0, 1000.0])
    for j, off in enumerate(offs):
        X[j, :3] = p.position + np.asarray(off) @ p.R_ws.T
    for w in (np.full(40, 1.0 / 40), np.r_[np.full(7, 1.0 / 7), np.zeros(33)]):
        z = np.array([10.0, 0.3, 1.0])
        got = radar.linearise_rows(X, z, w)
        _assert_matches(got, _default(radar, X, z, w), 3000.0)
        assert np.all(np.isfinite(got[0]))
        if pose == "ground":  # exactly on the axes: D exact, the floors reached
            # at the antenna: zero range / azimuth rows, the elevation row rho / r^2 =
            # 1 / eps (both floored), as the default has it
            np.testing.assert_array_equal(got[0][0, :2], 0.0)
            np.testing.assert_allclose(got[0][0, 2, :3], [0.0, 0.0, 1.0 / _EPS], rtol=1e-12)
            assert np.abs(got[0][1:3, 1:]).max() < 1.0 / _EPS


def test_3d_non_finite_members(nb):
    """A NaN member and one whose r^2 overflows: NaN / inf where the default has them."""
    g = np.random.default_rng(18)
    radar = _radar3("ground", 6)
    X = _members3(radar.pose, 6, 30, g, 1.0)
    X[3, 0] = np.nan
    X[4, :3] = [1e200, -1e200, 1e199]
    z, w = np.array([3000.0, 1.0, 0.1]), np.full(30, 1.0 / 30)
    got = radar.linearise_rows(X, z, w)
    with np.errstate(over="ignore", invalid="ignore"):  # (the default's overflows)
        want = _default(radar, X, z, w)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
    X[3, 0] = 1.0
    X[4, :3] = [1e152, 3e151, 2e151]  # rho^2 > 1e300: sin / cos of the angle, hypot
    w = np.full(30, 1e-160)
    w[5:] = (1.0 - 5e-160) / 25
    got = radar.linearise_rows(X, z, w)
    with np.errstate(over="ignore"):
        want = _default(radar, X, z, w)
    _assert_matches(got, want, 3000.0)


def test_3d_argument_types_and_new_poses(nb):
    """Non-contiguous and integer members, a list z; wrong shapes to the default (which
    raises); each ``with_pose`` copy (a UAV radar's pose every step) read afresh."""
    g = np.random.default_rng(19)
    radar = _radar3("uav", 6)
    big = np.asfortranarray(np.hstack([_members3(radar.pose, 6, 20, g, 0.5),
                                       np.ones((20, 2))]))
    X = big[:, :6]
    w = np.ones(40)[::2] / 20
    z = [3000, 0.5, 0]
    _assert_matches(radar.linearise_rows(X, z, w),
                    _default(radar, X, np.asarray(z, float), w), 3000.0)
    Xi = np.round(X).astype(np.int64)
    _assert_matches(radar.linearise_rows(Xi, z, w), _default(radar, Xi, z, w), 3000.0)
    with pytest.raises(ValueError):
        radar.linearise_rows(np.ascontiguousarray(X), np.array([3000.0, 0.5, 0.0]),
                             np.ones(19))
    base = RadarMeasurement(3, 6)
    X = _members3(base.pose, 6, 60, g, 1.0)
    w = np.full(60, 1.0 / 60)
    z = np.array([3000.0, 1.0, 0.1])
    base.linearise_rows(X, z, w)
    for name in _poses3():
        m = base.with_pose(_radar3(name, 6).pose)
        _assert_matches(m.linearise_rows(X, z, w), _default(m, X, z, w), 5000.0)
