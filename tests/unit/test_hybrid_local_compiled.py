"""The compiled local-gain hybrid update (``uavest.core._compiled_local``, numba) equals
the numpy path (``HybridLocal._update_numpy``, the reference and the fallback without
numba or with ``UAVEST_NUMBA=0``): the same random draws, the same members, weights and
innovations to rounding, on seeded radar data and on small linear cases."""

from __future__ import annotations

import os

import numpy as np
import pytest

from uavest.core import hybrid
from uavest.core.gaussian import Gaussian
from uavest.core.hybrid import HybridLocal
from uavest.core.interfaces import LinearMeasurement
from uavest.core.linalg import NumericalError
from uavest.core.states import Ensemble, ensemble_estimate, equal_weights

nb = pytest.importorskip("uavest.core._compiled_local", exc_type=ImportError)


def _assert_cov_close(a, b, tol: float = 1e-12) -> None:
    """Covariances equal to ``tol`` relative to the standard deviations: |a_ij - b_ij| <=
    tol sqrt(b_ii b_jj) (an off-diagonal entry near 0 has its neighbours' rounding)."""
    d = np.sqrt(np.diag(b))
    assert np.all(np.abs(a - b) <= tol * np.outer(d, d)), (a, b)


def _radar_run(steps: int):
    from uavest.experiments.radar import data_rng
    from uavest.scenarios import load_typed
    from uavest.tracking.scenario import build_models, generate_run, prior

    sc = load_typed("radar_far", ["radar.sigma_az_deg=5"])
    motion, radar = build_models(sc)
    _, P0 = prior(sc)
    rd = generate_run(sc, data_rng(0, 0))
    Z = [s[o == 0][0] if np.any(o == 0) else None
         for s, o in zip(rd.scans, rd.origins, strict=True)][:steps]
    return motion, radar, Gaussian(rd.x0, P0), Z


def _radar3_run(steps: int):
    """radar_uav (3-D, a radar on a UAV): the motion model, the radar, a prior of the
    first target, its detections (None when missed) and the (estimated) sensor pose of
    each scan."""
    from uavest.experiments.radar import data_rng
    from uavest.scenarios import load_typed
    from uavest.tracking.scenario import build_models, generate_run

    sc = load_typed("radar_uav", [])
    motion, radar = build_models(sc)
    rd = generate_run(sc, data_rng(0, 0))
    Z = [s[o == 0][0] if np.any(o == 0) else None
         for s, o in zip(rd.scans, rd.origins, strict=True)][:steps]
    # a prior around the first target's truth (the tracker's initial spread: 50 m, 20 m/s)
    P0 = np.diag([50.0**2] * 3 + [20.0**2] * 3)
    x0 = rd.truths[0, 0] + np.random.default_rng(4).standard_normal(6) * np.sqrt(np.diag(P0))
    return motion, radar, Gaussian(x0, P0), Z, rd.poses_est[:steps]


def _run(f, motion, radar, prior, Z, compiled: bool, monkeypatch, poses=None):
    """Members, weights, estimates, innovations and the generator's state of every step,
    through one path (the predict's process noise too: compiled or numpy); ``poses``:
    the sensor pose of each scan (a UAV radar), else the radar's own."""
    from uavest.models import radar as radar_mod

    monkeypatch.setattr(hybrid.LOCAL_KERNELS, "loaded", nb if compiled else False)
    if not compiled:  # the whole numpy path: the radar's composed terms too
        monkeypatch.setattr(radar_mod.RADAR_KERNELS, "loaded", False)
    else:
        monkeypatch.setattr(radar_mod.RADAR_KERNELS, "loaded", None)  # decided again (UAVEST_NUMBA)
    rng = np.random.default_rng([1, 0])
    E = f.init(prior, motion.space, rng)
    out = []
    for k, z in enumerate(Z):
        E = f.predict(E, motion, float(k + 1), 1.0, None, rng)
        inn = None
        if poses is not None:
            radar = radar.with_pose(poses[k])
        if z is not None:
            if compiled:
                E, inn = f._update_compiled(nb, E, z, radar, rng)
            else:
                E, inn = f._update_numpy(E, z, radar, rng)
        g = ensemble_estimate(E)
        out.append((E.X.copy(), equal_weights(E.M) if E.w is None else E.w.copy(), g.x, g.P,
                    inn, rng.bit_generator.state["state"]["state"]))
    return out


def test_compiled_update_equals_the_numpy_path_on_radar_data(monkeypatch):
    """The radar preset (M = 585, 4-D CV, range / azimuth) over 60 scans of radar_far at
    5 deg: members, weights, the estimate (from the memo the compiled path leaves) and
    the innovation equal to 1e-12 relative, at every step (resampling steps included);
    the compiled predict and update draw the numpy path's normals from the same
    generator, so its state is the same after every step."""
    from uavest.presets import build

    motion, radar, prior, Z = _radar_run(60)
    f = build("hybrid", "radar", 4)
    assert isinstance(f, HybridLocal) and f.members(4) == 585
    a = _run(f, motion, radar, prior, Z, False, monkeypatch)
    b = _run(f, motion, radar, prior, Z, True, monkeypatch)
    resampled = 0
    for (Xa, wa, xa, Pa, ia, sa), (Xb, wb, xb, Pb, ib, sb) in zip(a, b, strict=True):
        assert sa == sb
        scale = np.abs(Xa).max()
        np.testing.assert_allclose(Xb, Xa, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(wb, wa, rtol=1e-10, atol=1e-300)
        np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(Pb, Pa, rtol=0, atol=1e-12 * np.abs(Pa).max())
        assert (ia is None) == (ib is None)
        if ia is not None:
            # nu = z - ybar: the range's rounding is relative to the range (~ |X|)
            np.testing.assert_allclose(ib.nu, ia.nu, rtol=0, atol=1e-12 * scale)
            _assert_cov_close(ib.S, ia.S)
            assert ib.nis == pytest.approx(ia.nis, rel=1e-8, abs=1e-10)
        resampled += bool(np.all(wa == wa[0]))
    assert 0 < resampled < len(a)  # both branches of the draw ran


@pytest.mark.parametrize("m", [1, 2, 3, 4])
@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("sharp", [False, True])
@pytest.mark.parametrize("weights", ["confidence", "equal"])
def test_compiled_update_equals_the_numpy_path_on_linear_cases(m, weighted, sharp, weights):
    """m = 1 and 2 (closed-form inverses), 3 and 4 (Cholesky; the numpy path's LAPACK
    ``inv`` / ``slogdet``), equal and unequal prior weights, a sharp measurement
    (resamples) and a loose one, confidence and equal weights; n = 3 (the kernels
    compile per n)."""
    g = np.random.default_rng(100 * m + 10 * weighted + sharp)
    X = g.standard_normal((35, 3)) * [10.0, 2.0, 0.5] + [100.0, -3.0, 1.0]
    w = g.dirichlet(np.full(35, 5.0)) if weighted else None
    H = g.standard_normal((m, 3))
    H[:, 2] = 0.0  # a zero column (skipped by the kernels)
    R = np.diag([0.01, 0.04, 0.02, 0.09][:m] if sharp else [25.0, 9.0, 16.0, 4.0][:m])
    for a in range(1, m):  # correlated components: a full (positive definite) R
        R[a - 1, a] = R[a, a - 1] = 0.3 * np.sqrt(R[a - 1, a - 1] * R[a, a])
    model = LinearMeasurement(H, R)
    z = H @ X.mean(axis=0) + g.standard_normal(m)
    f = HybridLocal(n_cloud=4, weights=weights)
    ra, rb = np.random.default_rng(5), np.random.default_rng(5)
    Ea, ia = f._update_numpy(Ensemble(X.copy(), model.space, w), z, model, ra)
    Eb, ib = f._update_compiled(nb, Ensemble(X.copy(), model.space, w), z, model, rb)
    assert ra.bit_generator.state == rb.bit_generator.state  # the same draws
    assert (Ea.w is None) == (Eb.w is None)
    np.testing.assert_allclose(Eb.X, Ea.X, rtol=0, atol=1e-12 * np.abs(Ea.X).max())
    if Ea.w is not None:  # m >= 3: the log-likelihoods from a Cholesky inverse against
        # LAPACK's LU inverse and slogdet, their rounding in the exponent
        np.testing.assert_allclose(Eb.w, Ea.w, rtol=1e-12 if m <= 2 else 1e-10)
    _assert_cov_close(ib.S, ia.S)
    assert ib.nis == pytest.approx(ia.nis, rel=1e-10)
    ga = ensemble_estimate(Ensemble(Ea.X, Ea.space, Ea.w))  # recomputed by numpy
    gb = ensemble_estimate(Eb)  # the memo the compiled path left
    np.testing.assert_allclose(gb.x, ga.x, rtol=0, atol=1e-12 * np.abs(ga.x).max())
    np.testing.assert_allclose(gb.P, ga.P, rtol=0, atol=1e-11 * np.abs(ga.P).max())


def test_compiled_update_raises_numerical_errors_like_the_numpy_path():
    """A non-positive innovation covariance is a NumericalError (the guard recovers) in
    both paths; a wrong-sized measurement a ValueError."""
    X = np.random.default_rng(0).standard_normal((35, 3))
    model = LinearMeasurement(np.array([[1.0, 0.0, 0.0]]), np.array([[-10.0]]))
    f = HybridLocal(n_cloud=4)
    for upd in (f._update_numpy, lambda *a: f._update_compiled(nb, *a)):
        with pytest.raises(NumericalError):
            upd(Ensemble(X.copy(), model.space), np.array([0.0]), model,
                np.random.default_rng(0))
    good = LinearMeasurement(np.eye(2, 3), np.eye(2))
    with pytest.raises(ValueError):
        f._update_compiled(nb, Ensemble(X.copy(), good.space), np.zeros(3), good,
                           np.random.default_rng(0))


def test_compiled_update_equals_the_numpy_path_on_3d_radar_data(monkeypatch):
    """The radar preset on 3-D detections (range / azimuth / elevation, m = 3, 6-D CV):
    radar_uav's first target seen from its UAV (a new sensor pose every scan) over 40
    scans, the compiled predict, 3-D radar terms and update against the whole numpy
    path: members, weights, estimate and innovation equal to 1e-12 relative at every
    step, the generator in the same state after each."""
    from uavest.presets import build

    motion, radar, prior, Z, poses = _radar3_run(40)
    f = build("hybrid", "radar", 6)
    assert isinstance(f, HybridLocal) and radar.dim == 3
    a = _run(f, motion, radar, prior, Z, False, monkeypatch, poses)
    b = _run(f, motion, radar, prior, Z, True, monkeypatch, poses)
    resampled = 0
    for (Xa, wa, xa, Pa, ia, sa), (Xb, wb, xb, Pb, ib, sb) in zip(a, b, strict=True):
        assert sa == sb
        scale = np.abs(Xa).max()
        np.testing.assert_allclose(Xb, Xa, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(wb, wa, rtol=1e-10, atol=1e-300)
        np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(Pb, Pa, rtol=0, atol=1e-12 * np.abs(Pa).max())
        assert (ia is None) == (ib is None)
        if ia is not None:
            np.testing.assert_allclose(ib.nu, ia.nu, rtol=0, atol=1e-12 * scale)
            _assert_cov_close(ib.S, ia.S)
            assert ib.nis == pytest.approx(ia.nis, rel=1e-8, abs=1e-10)
        resampled += bool(np.all(wa == wa[0]))
    assert 0 < resampled < len(a)  # both branches of the draw ran


def test_3d_radar_update_dispatches_to_the_compiled_path(monkeypatch):
    """``update`` on 3-D detections (m = 3) takes the kernels with the 3-D radar kernel
    (the numpy update and the composed radar terms fail if called); skipped without
    numba or with ``UAVEST_NUMBA=0``."""
    from conftest import compiled_kernels

    from uavest.core.interfaces import Measurement
    from uavest.models import radar as radar_mod
    from uavest.presets import build

    compiled_kernels(hybrid.LOCAL_KERNELS.get, "local hybrid kernels")
    compiled_kernels(radar_mod.RADAR_KERNELS.get, "radar kernel")

    def boom(*a, **k):
        raise AssertionError("the numpy path ran")

    motion, radar, prior, Z, poses = _radar3_run(5)
    f = build("hybrid", "radar", 6)
    monkeypatch.setattr(HybridLocal, "_update_numpy", boom)
    monkeypatch.setattr(Measurement, "linearise_rows", boom)
    rng = np.random.default_rng(0)
    E = f.init(prior, motion.space, rng)
    z = next(z for z in Z if z is not None)
    E, inn = f.update(f.predict(E, motion, 1.0, 1.0, None, rng), z, radar.with_pose(poses[0]),
                      rng)
    assert E.X.shape == (f.members(6), 6) and inn.S.shape == (3, 3)
    assert np.all(np.isfinite(E.X)) and np.isfinite(inn.nis)


def test_update_dispatches_to_the_kernels_unless_switched_off():
    """``update`` uses the kernels on a vector space (any m) when numba is enabled and
    the numpy path with ``UAVEST_NUMBA=0`` (decided once per process)."""
    k = hybrid.LOCAL_KERNELS.get()
    if os.environ.get("UAVEST_NUMBA", "1") == "0":
        assert k is None
    else:
        assert k is nb


@pytest.mark.parametrize("bitgen", [np.random.PCG64, np.random.SFC64, np.random.Philox])
def test_kernels_draw_the_generators_own_normals(bitgen):
    """``add_noise`` draws from the caller's generator through its pointers: numpy's
    normals in numpy's order for any bit generator, the generator left where numpy
    leaves it, so that the compiled and numpy paths share one random stream."""
    from uavest.compiled import bitgen_pointers

    X = np.arange(21.0).reshape(7, 3)
    L = np.linalg.cholesky(np.array([[4.0, 1.0, 0.0], [1.0, 2.0, 0.5], [0.0, 0.5, 1.0]]))
    ra, rb = np.random.Generator(bitgen(11)), np.random.Generator(bitgen(11))
    for _ in range(3):  # the pointers are remembered: later calls continue the stream
        got = nb.add_noise(bitgen_pointers(ra), X, L, nb.tag(3))
        np.testing.assert_allclose(got, X + rb.standard_normal((7, 3)) @ L.T,
                                   rtol=0, atol=1e-13)
    np.testing.assert_array_equal(ra.random(5), rb.random(5))  # the same state after
    assert bitgen_pointers(ra) is bitgen_pointers(ra)
    assert not np.array_equal(bitgen_pointers(ra), bitgen_pointers(rb))
