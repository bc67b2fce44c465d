"""One contract suite for every registered filter, its Sage-Husa (``_sh``) and
:class:`Guarded` wrappers, on every state space (vector space and the attitude manifold),
in the spirit of manif's common tester: every filter must pass the same checks.

Spaces: retract/local round trips, manifold means. Models: analytic Jacobians against
finite differences. Filters: KF equivalence on a linear-Gaussian model (Gaussian filters
to ~1e-9, ensemble filters statistically with the tolerances stated below), symmetric PD
covariances over a 500-step run, determinism (same seed -> identical, different seed ->
ensemble filters differ), RTS terms (shape, and against the analytic P F^T on a linear
model), mix() of identical states, the guard's error policy (programming errors raise,
numerical failures recover), and the replay/tracker behaviour of the pre-contract code
(frozen reference implementations below) reproduced bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from uavest.core import (
    UKF,
    Ensemble,
    Filter,
    Gaussian,
    Guarded,
    LinearMeasurement,
    LinearTransition,
    fd_jacobian,
    make_filter,
)
from uavest.core.interfaces import Measurement, Transition, fd_jacobians
from uavest.core.registry import REGISTRY
from uavest.geometry.navigation import NavSpace
from uavest.geometry.rotation import AttitudeSpace, euler_to_quat, quat_exp, quat_mul
from uavest.geometry.spaces import VectorSpace
from uavest.models.attitude import (
    AttitudeNoise,
    GravityDirection,
    GyroTransition,
    MagField,
    MagHeading,
    Stacked,
)
from uavest.models.benchmarks import (
    Nonlinear2DMeasurement,
    Nonlinear2DTransition,
    UNGMMeasurement,
    UNGMTransition,
)
from uavest.models.motion import NearlyConstantVelocity
from uavest.models.radar import RadarMeasurement

# Small ensembles keep the suite fast; the statistical KF test uses large ones.
BASE_SPECS = [
    "kf", "ekf", "ukf", "ckf", "srukf", "enkf(members=60)", "etkf(members=60)",
    "hybrid(n_cloud=6)", "hybrid(n_cloud=6, reinflate=true)",
    "hybrid(update_mode=local, n_cloud=6)", "hybrid_literal(n_cloud=6)",
    "pf(particles=400)",
]
SH_SPECS = ["ekf_sh", "ukf_sh", "enkf_sh(members=60)", "hybrid_sh(n_cloud=6)"]
SPECS = BASE_SPECS + SH_SPECS
ENSEMBLE = ("enkf", "etkf", "hybrid", "hybrid_literal", "pf")
WRAPS = ["plain", "guarded"]


def base_name(spec: str) -> str:
    return spec.split("(")[0].removesuffix("_sh")


def build(spec: str, wrap: str):
    f = make_filter(spec)
    return Guarded(f) if wrap == "guarded" else f


def is_ensemble(spec: str) -> bool:
    return base_name(spec) in ENSEMBLE


def test_every_registered_filter_is_in_the_contract_suite():
    assert {base_name(s) for s in BASE_SPECS} == set(REGISTRY)
    assert {s.split("(")[0] for s in BASE_SPECS if "update_mode=local" in s} == {"hybrid"}


# ------------------------------------------------------------------------------ problems

NOISE = AttitudeNoise(gyro_noise=0.01, gyro_bias_walk=1e-4, rate_walk=0.05)
M_NED = np.array([0.2, 0.02, 0.45])
M_NED = M_NED / np.linalg.norm(M_NED)


class Problem:
    """A transition, a measurement stream generator and a prior on one space."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        if kind == "vector":
            self.tr = Nonlinear2DTransition(nl=0.5)
            self.me = Nonlinear2DMeasurement(nl=0.5)
            self.prior = Gaussian(np.zeros(2), np.eye(2))
            self.dt = 1.0
        else:
            self.tr = GyroTransition(NOISE)
            self.prior = Gaussian(np.concatenate([euler_to_quat(0.1, -0.05, 0.3),
                                                  np.zeros(3)]),
                                  np.diag([0.05**2] * 3 + [0.005**2] * 3))
            self.dt = 0.05
        self.space = self.tr.space

    def stream(self, steps: int, seed: int):
        """Yield (t, dt, u, z, model) for a simulated truth."""
        rng = np.random.default_rng(seed)
        if self.kind == "vector":
            x = np.zeros(2)
            for k in range(1, steps + 1):
                x = self.tr.f(x[None], k)[0] + rng.normal(size=2)
                yield k, 1.0, None, self.me.h(x[None])[0] + rng.normal(size=2), self.me
            return
        q = self.prior.x[:4].copy()
        w = np.array([0.2, -0.1, 0.3])
        bias = np.array([0.01, -0.005, 0.002])
        g = GravityDirection(np.eye(3) * 0.03**2)
        m = MagField(M_NED, np.eye(3) * 0.03**2)
        for k in range(1, steps + 1):
            q = quat_mul(q, quat_exp(w * self.dt))
            xt = np.concatenate([q, bias])[None]
            u = w + bias + 0.01 * rng.standard_normal(3)
            z, model = Stacked.of([(g.h(xt)[0] + 0.03 * rng.standard_normal(3), g),
                                   (m.h(xt)[0] + 0.03 * rng.standard_normal(3), m)])
            yield k * self.dt, self.dt, u, z, model


PROBLEMS = {k: Problem(k) for k in ("vector", "attitude")}


def run(f, prob: Problem, steps: int, seed: int, check=None):
    rng = np.random.default_rng(seed + 100)
    s = f.init(prob.prior, prob.space, rng)
    out = []
    for t, dt, u, z, model in prob.stream(steps, seed):
        s = f.predict(s, prob.tr, t, dt, u, rng)
        s, _ = f.update(s, z, model, rng)
        g = f.estimate(s)
        if check is not None:
            check(g)
        out.append(g)
    return s, out


def skip_kf_nonlinear(spec: str, prob: Problem) -> None:
    if base_name(spec) == "kf":
        pytest.skip("KF refuses non-linear models (tested in test_kf_refuses_...)")


# --------------------------------------------------------------------------------- spaces

SPACES = {"vector3": VectorSpace(3), "attitude": AttitudeSpace(), "nav": NavSpace(),
          "nav_gnss_bias": NavSpace(extra=3), "nav_mag_ref": NavSpace(mag=2),
          "nav_gnss_bias_mag_ref": NavSpace(extra=3, mag=2),
          "nav_gnss_bias_drift_mag_ref": NavSpace(extra=3, mag=2, drift=3)}


def random_point(space, rng):
    if isinstance(space, AttitudeSpace):
        q = rng.normal(size=4)
        return np.concatenate([q / np.linalg.norm(q), rng.normal(size=3) * 0.01])
    if isinstance(space, NavSpace):
        q = rng.normal(size=4)
        return np.concatenate([q / np.linalg.norm(q), rng.normal(size=3) * 5.0,
                               rng.normal(size=3) * 100.0, rng.normal(size=3) * 0.01,
                               rng.normal(size=3) * 0.1,
                               rng.normal(size=space.size - 16)])
    return rng.normal(size=space.size)


@pytest.mark.parametrize("name", SPACES)
def test_space_retract_local_round_trip(name):
    space = SPACES[name]
    rng = np.random.default_rng(0)
    for _ in range(20):
        x = random_point(space, rng)
        d = rng.normal(size=(5, space.dim)) * 0.5
        y = space.retract(x, d)
        np.testing.assert_allclose(space.local(x, y), d, atol=1e-10)
        np.testing.assert_allclose(space.local(x, space.retract(x, np.zeros(space.dim))),
                                   np.zeros(space.dim), atol=1e-12)
        # retract(x, local(x, y)) == y as points of the space
        y1 = random_point(space, rng)
        back = space.retract(x, space.local(x, y1))
        np.testing.assert_allclose(space.local(y1, back), np.zeros(space.dim), atol=1e-10)


@pytest.mark.parametrize("name", SPACES)
def test_space_mean_of_a_symmetric_cloud_is_its_centre(name):
    space = SPACES[name]
    rng = np.random.default_rng(1)
    x = random_point(space, rng)
    d = rng.normal(size=(6, space.dim)) * 0.05
    X = space.retract(x, np.vstack([d, -d]))
    m = space.mean(X, np.full(12, 1 / 12), X[0])
    assert np.max(np.abs(space.local(x, m[None])[0])) < 1e-5


# ------------------------------------------------------------------------------ Jacobians


def _attitude_points(rng, n=4):
    return [random_point(AttitudeSpace(), rng) for _ in range(n)]


def jacobian_cases():
    rng = np.random.default_rng(2)
    cases = []
    gyro = GyroTransition(NOISE)
    for x in _attitude_points(rng):
        u = rng.normal(size=3)
        cases.append(("gyro.F", gyro, x, u))
    g_plain = GravityDirection(np.eye(3))
    g_ref = GravityDirection(np.eye(3), ref=np.array([0.3, -0.2, 0.93]) / np.linalg.norm(
        [0.3, -0.2, 0.93]))
    heading = MagHeading(np.array([0.2, 0.05, 0.4]), np.eye(1))
    field = MagField(M_NED, np.eye(3))
    stacked = Stacked([g_plain, field])
    for x in _attitude_points(rng):
        for name, m in (("gravity.H", g_plain), ("gravity_ref.H", g_ref),
                        ("mag_heading.H", heading), ("mag_field.H", field),
                        ("stacked.H", stacked)):
            cases.append((name, m, x, None))
    for x in rng.normal(size=(3, 1)) * 3:
        cases += [("ungm.F", UNGMTransition(), x, None), ("ungm.H", UNGMMeasurement(), x, None)]
    for x in rng.normal(size=(3, 2)):
        cases += [("nl2d.F", Nonlinear2DTransition(nl=0.7), x, None),
                  ("nl2d.H", Nonlinear2DMeasurement(nl=0.7), x, None)]
    cases.append(("ncv.F", NearlyConstantVelocity(2, 0.5), rng.normal(size=4), None))
    for radar in (RadarMeasurement(2), RadarMeasurement(3), RadarMeasurement(2, sigma_rr=1.0)):
        x = np.concatenate([rng.normal(size=radar.ndim) * 500 + 1000,
                            rng.normal(size=radar.ndim) * 20])
        cases.append((f"radar{radar.ndim}d{len(radar.components)}.H", radar, x, None))
    return cases


JAC_CASES = jacobian_cases()


@pytest.mark.parametrize("case", JAC_CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(JAC_CASES)])
def test_analytic_jacobian_matches_finite_differences(case):
    name, model, x, u = case
    if isinstance(model, Transition):
        J = model.F(x, 1.0, 0.1, u)
        ref = fd_jacobian(lambda X: model.f(X, 1.0, 0.1, u), model.space, model.space, x)
    else:
        assert isinstance(model, Measurement)
        J = model.H(x)
        ref = fd_jacobians(model.h, model.residual, model.space, x[None])[0]
    assert J.shape == ref.shape
    np.testing.assert_allclose(J, ref, atol=1e-5 * max(1.0, np.abs(ref).max()))


@pytest.mark.parametrize("radar", [RadarMeasurement(2), RadarMeasurement(3, sigma_rr=1.0)],
                         ids=["2d", "3d_rr"])
def test_batched_jacobians_match_single_ones(radar):
    rng = np.random.default_rng(3)
    X = np.hstack([rng.normal(size=(5, radar.ndim)) * 300 + 800,
                   rng.normal(size=(5, radar.ndim)) * 10])
    Hs = radar.H_rows(X)
    for j in range(5):
        np.testing.assert_allclose(Hs[j], radar.H(X[j]), rtol=1e-6, atol=1e-9)


# -------------------------------------------------------------------------- the contract


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("spec", SPECS)
def test_filters_satisfy_the_protocol(spec, wrap):
    f = build(spec, wrap)
    assert isinstance(f, Filter)
    assert isinstance(f.name, str) and f.name.startswith(spec.split("(")[0].removesuffix("_sh"))


def _linear_case():
    tr = LinearTransition([[1.0, 1.0], [0.0, 1.0]], np.diag([0.05, 0.1]))
    me = LinearMeasurement([[1.0, 0.0]], [[2.0]])
    rng = np.random.default_rng(7)
    x = np.array([0.0, 1.0])
    Z = []
    for _ in range(40):
        x = tr.f(x[None], 0, 1.0)[0] + rng.multivariate_normal([0, 0], tr.Q(0, 1.0))
        Z.append(x[:1] + rng.normal(0, np.sqrt(2.0), 1))
    return tr, me, Gaussian(np.array([0.0, 1.0]), np.diag([10.0, 1.0])), Z


LIN = _linear_case()


def run_linear(f, seed=0):
    tr, me, prior, Z = LIN
    rng = np.random.default_rng(seed)
    s = f.init(prior, tr.space, rng)
    out = []
    for k, z in enumerate(Z):
        s = f.predict(s, tr, k + 1.0, 1.0, None, rng)
        s, _ = f.update(s, z, me, rng)
        out.append(f.estimate(s))
    return out


KF_REF = run_linear(make_filter("kf"))


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("spec", ["kf", "ekf", "ukf", "ckf", "srukf",
                                  "ukf(alpha=0.5, beta=1, kappa=1)"])
def test_gaussian_filters_equal_kf_on_linear_model(spec, wrap):
    out = run_linear(build(spec, wrap))
    for a, b in zip(out, KF_REF, strict=True):
        np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-9)


# Ensemble filters: after 10 steps of burn-in, the RMS over steps of the state difference
# to the KF in units of the KF's posterior std must be below ``tol``, and the mean ratio of
# their variances to the KF's within 25 % (large ensembles; Monte Carlo error ~ 1/sqrt(M)).
# The literal hybrid's default cloud is not covariance-consistent (its covariance is
# (2 g^2/(2n+1) + s^2 N/(N+1)) P), so it is tested with the gamma that makes it so.
STAT_CASES = [
    ("enkf(members=2000)", 0.15), ("etkf(members=200)", 0.15), ("hybrid(n_cloud=300)", 0.15),
    ("hybrid(n_cloud=300, reinflate=true)", 0.15),
    ("hybrid(update_mode=local, n_cloud=300)", 0.15),
    (f"hybrid_literal(weights=equal, process_noise=members, n_cloud=300, "
     f"gamma={np.sqrt((1 - 0.25 * 300 / 301) * 2.5)})", 0.25),
    ("pf(particles=4000)", 0.2),
]


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("spec, tol", STAT_CASES, ids=[c[0].split(",")[0] for c in STAT_CASES])
def test_ensemble_filters_match_kf_statistically(spec, tol, wrap):
    out = run_linear(build(spec, wrap), seed=3)
    dx = np.array([(a.x - b.x) / np.sqrt(np.diag(b.P)) for a, b in zip(out, KF_REF,
                                                                         strict=True)])
    assert np.sqrt(np.mean(dx[10:] ** 2)) < tol
    ratio = np.array([np.diag(a.P) / np.diag(b.P) for a, b in zip(out, KF_REF,
                                                                    strict=True)])[10:]
    assert np.all(np.abs(ratio.mean(axis=0) - 1.0) < 0.25)


def _check_pd(g: Gaussian) -> None:
    assert np.all(np.isfinite(g.x)) and np.all(np.isfinite(g.P))
    np.testing.assert_allclose(g.P, g.P.T, atol=1e-9 * max(1.0, np.abs(g.P).max()))
    assert np.linalg.eigvalsh(0.5 * (g.P + g.P.T)).min() > 0.0


LITERAL_DIVERGES = pytest.mark.xfail(
    strict=True, reason="the literal reconstruction is not covariance-consistent: unguarded "
    "on the attitude manifold its bias covariance explodes (the guard resets it)")


def _pd_cases():
    """500 steps on the vector space; on the attitude manifold 200 steps (10 s at 20 Hz)
    by default and 500 under the ``slow`` marker (about 40 s for the whole set)."""
    for spec in SPECS:
        for wrap in WRAPS:
            for prob, steps in (("vector", 500), ("attitude", 200), ("attitude", 500)):
                marks = [pytest.mark.slow] if prob == "attitude" and steps == 500 else []
                if spec.startswith("hybrid_literal") and wrap == "plain" and prob != "vector":
                    marks.append(LITERAL_DIVERGES)
                yield pytest.param(spec, wrap, prob, steps, marks=marks,
                                   id=f"{spec}-{wrap}-{prob}-{steps}")


@pytest.mark.parametrize("spec, wrap, prob, steps", list(_pd_cases()))
def test_covariance_stays_symmetric_pd_over_a_long_run(spec, wrap, prob, steps):
    p = PROBLEMS[prob]
    skip_kf_nonlinear(spec, p)
    s, out = run(build(spec, wrap), p, steps, seed=4, check=_check_pd)
    assert len(out) == steps


@pytest.mark.parametrize("prob", PROBLEMS)
@pytest.mark.parametrize("spec", SPECS)
def test_same_seed_identical_different_seed_differs_for_ensembles(spec, prob):
    p = PROBLEMS[prob]
    skip_kf_nonlinear(spec, p)
    f = build(spec, "guarded")
    _, a = run(f, p, 15, seed=5)
    _, b = run(f, p, 15, seed=5)
    for ga, gb in zip(a, b, strict=True):
        assert np.array_equal(ga.x, gb.x) and np.array_equal(ga.P, gb.P)
    # same data, different filter stream
    rng1, rng2 = np.random.default_rng(1), np.random.default_rng(2)
    s1, s2 = f.init(p.prior, p.space, rng1), f.init(p.prior, p.space, rng2)
    for t, dt, u, z, model in p.stream(5, seed=5):
        s1, _ = f.update(f.predict(s1, p.tr, t, dt, u, rng1), z, model, rng1)
        s2, _ = f.update(f.predict(s2, p.tr, t, dt, u, rng2), z, model, rng2)
    differs = not np.array_equal(f.estimate(s1).x, f.estimate(s2).x)
    assert differs == is_ensemble(spec)


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("spec", SPECS)
def test_rts_terms_on_linear_model_match_analytic_kf(spec, wrap):
    """C = P F^T exactly for every Gaussian filter and the sigma-point fallback, within
    Monte Carlo error (0.1 of the scale of P F^T, M >= 400) for member-wise ensembles;
    the paired prediction is the filter's own for Gaussian filters."""
    tr, me, prior, Z = LIN
    big = {"enkf(members=60)": "enkf(members=3000)", "etkf(members=60)": "etkf(members=400)",
           "hybrid(n_cloud=6)": "hybrid(n_cloud=300)",
           "hybrid(n_cloud=6, reinflate=true)": "hybrid(n_cloud=300, reinflate=true)",
           "enkf_sh(members=60)":
           "enkf_sh(members=3000)", "hybrid_sh(n_cloud=6)": "hybrid_sh(n_cloud=300)",
           "hybrid(update_mode=local, n_cloud=6)": "hybrid(update_mode=local, n_cloud=300)"}
    f = build(big.get(spec, spec), wrap)
    rng = np.random.default_rng(8)
    s0 = f.init(prior, tr.space, rng)
    s0, _ = f.update(s0, Z[0], me, rng)
    s1 = f.predict(s0, tr, 2.0, 1.0, None, rng)
    g0 = f.estimate(s0)
    gp, C = f.rts_terms(s0, s1, tr, 2.0, 1.0)
    assert C.shape == (2, 2) and gp.P.shape == (2, 2)
    np.testing.assert_array_equal(C, f.cross_covariance(s0, s1, tr, 2.0, 1.0))
    want = g0.P @ tr.F(g0.x, 2.0, 1.0).T
    if is_ensemble(spec) and base_name(spec) not in ("pf", "hybrid_literal"):
        assert np.max(np.abs(C - want)) < 0.1 * np.abs(want).max()
    else:
        np.testing.assert_allclose(C, want, rtol=1e-9, atol=1e-9)
    if not is_ensemble(spec):
        np.testing.assert_allclose(gp.x, f.estimate(s1).x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(gp.P, f.estimate(s1).P, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("prob", PROBLEMS)
@pytest.mark.parametrize("spec", SPECS)
def test_rts_terms_shape_and_psd_joint_on_every_space(spec, prob):
    """[[P_f, C], [C^T, P_p]] must be a covariance (PSD up to Monte Carlo error)."""
    p = PROBLEMS[prob]
    skip_kf_nonlinear(spec, p)
    f = build(spec, "guarded")
    rng = np.random.default_rng(9)
    s0 = f.init(p.prior, p.space, rng)
    (t, dt, u, z, model), = list(p.stream(1, seed=9))
    s0, _ = f.update(s0, z, model, rng)
    s1 = f.predict(s0, p.tr, t + dt, dt, u, rng)
    gp, C = f.rts_terms(s0, s1, p.tr, t + dt, dt, u)
    n = p.space.dim
    assert C.shape == (n, n) and np.all(np.isfinite(C))
    J = np.block([[f.estimate(s0).P, C], [C.T, gp.P]])
    scale = np.abs(J).max()
    assert np.linalg.eigvalsh(0.5 * (J + J.T)).min() > -0.05 * scale


@pytest.mark.parametrize("prob", PROBLEMS)
@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("spec", SPECS)
def test_mix_of_identical_states_returns_that_state(spec, wrap, prob):
    p = PROBLEMS[prob]
    skip_kf_nonlinear(spec, p)
    f = build(spec, wrap)
    rng = np.random.default_rng(10)
    s = f.init(p.prior, p.space, rng)
    (t, dt, u, z, model), = list(p.stream(1, seed=10))
    s, _ = f.update(f.predict(s, p.tr, t, dt, u, rng), z, model, rng)
    g = f.estimate(s)
    one = f.estimate(f.mix([s], np.array([1.0]), p.space, rng))
    two = f.estimate(f.mix([s, s, s], np.array([0.2, 0.5, 0.3]), p.space, rng))
    if is_ensemble(spec):
        # a systematic redraw of the same (weighted) members: the same moments up to
        # resampling noise (M = 60..400 here: means within 0.5 std, variances within 60 %)
        sd = np.sqrt(np.diag(g.P))
        for m in (one, two):
            assert np.all(np.abs(p.space.local(g.x, m.x[None])[0]) < 0.5 * sd)
            assert np.all(np.abs(np.diag(m.P) / np.diag(g.P) - 1) < 0.6)
    else:
        for m in (one, two):
            np.testing.assert_allclose(p.space.local(g.x, m.x[None])[0], 0.0, atol=1e-9)
            np.testing.assert_allclose(m.P, g.P, rtol=1e-9, atol=1e-12)


def test_mix_of_two_gaussians_is_moment_matched():
    f = Guarded(make_filter("ekf"))
    sp = VectorSpace(1)
    a = f.init(Gaussian.of(0.0, 1.0), sp)
    b = f.init(Gaussian.of(2.0, 1.0), sp)
    g = f.estimate(f.mix([a, b], np.array([0.5, 0.5]), sp, np.random.default_rng(0)))
    assert g.x[0] == pytest.approx(1.0) and g.P[0, 0] == pytest.approx(2.0)


# ------------------------------------------------------------------------------- the guard


@pytest.mark.parametrize("spec", SPECS)
def test_guard_raises_on_wrong_measurement_shape(spec):
    """A 3-element z for a 1-D linear measurement is a programming error, not a
    divergence: it must raise instead of counting resets."""
    f = Guarded(make_filter(spec))
    tr, me, prior, _ = LIN
    rng = np.random.default_rng(11)
    s = f.predict(f.init(prior, tr.space, rng), tr, 1.0, 1.0, None, rng)
    with pytest.raises((ValueError, IndexError)):
        f.update(s, np.array([1.0, 2.0, 3.0]), me, rng)


def test_guard_raises_on_wrong_model_type():
    f = Guarded(make_filter("kf"))
    p = PROBLEMS["vector"]
    s = f.init(p.prior, p.space)
    with pytest.raises(TypeError):
        f.predict(s, p.tr, 1, 1.0)


class NaNTransition(Transition):
    """A transition that returns NaN at step 3 (a numerical failure of the model)."""

    linear = True

    def __init__(self, space, bad_t: float) -> None:
        self.space, self.bad_t = space, bad_t
        self.linear = isinstance(space, VectorSpace)

    def f(self, X, t, dt, u=None):
        return np.full_like(X, np.nan) if t == self.bad_t else X.copy()

    def Q(self, t, dt, u=None):
        return 1e-3 * np.eye(self.space.dim)

    def F(self, x, t, dt, u=None):
        return np.full((self.space.dim,) * 2, np.nan) if t == self.bad_t else np.eye(
            self.space.dim)


@pytest.mark.parametrize("prob", PROBLEMS)
@pytest.mark.parametrize("spec", SPECS)
def test_guard_recovers_from_a_nan_returning_model(spec, prob):
    p = PROBLEMS[prob]
    f = Guarded(make_filter(spec))
    tr = NaNTransition(p.space, bad_t=3.0)
    if base_name(spec) == "kf" and prob != "vector":
        pytest.skip("KF needs a linear model")
    rng = np.random.default_rng(12)
    s = f.init(p.prior, p.space, rng)
    resets = []
    for k in range(1, 6):
        s = f.predict(s, tr, float(k), 1.0, None, rng)
        resets.append(s.resets)
        g = f.estimate(s)
        assert np.all(np.isfinite(g.x)) and np.all(np.isfinite(g.P))
    assert resets[1] == 0 and resets[2] == 1 and resets[-1] == 1


def test_numerical_errors_are_linalg_errors():
    from uavest.core import NotPositiveDefinite, NumericalError
    from uavest.core.linalg import chol
    from uavest.core.particle import systematic_resample

    assert issubclass(NotPositiveDefinite, NumericalError)
    assert issubclass(NumericalError, np.linalg.LinAlgError)
    with pytest.raises(NumericalError):
        chol(np.array([[-1.0, np.nan], [np.nan, 1.0]]))
    with pytest.raises(NumericalError):
        chol(-np.eye(2))
    with pytest.raises(NumericalError):
        systematic_resample(np.array([0.5, np.nan]), np.random.default_rng(0))


def test_nis_gate_is_the_chi_square_quantile():
    from scipy.stats import chi2

    from uavest.core.guard import nis_gate

    for m in (1, 2, 3, 6):
        assert nis_gate(m, 0.9999) == pytest.approx(chi2.ppf(0.9999, m), rel=1e-12)


# ----------------------------------------------- pre-contract behaviour, reproduced exactly


def old_record_cross(f, s0, s1, gf, model, t, dt, u):
    """Frozen copy of the smoothing terms of ``pipeline/replay.py::_Run._record_cross``
    before the contract (isinstance chains), for the regression test below."""
    from uavest.core import EKF, ETKF, KF, EnKF, HybridLocal, HybridShift
    from uavest.core.contract import ensemble_cross

    def unwrap(f, s):
        while hasattr(f, "filter"):
            f, s = f.filter, s.inner
        return f, s

    def keeps(f, E):  # only the hybrid knew; EnKF/ETKF always; anything else never
        if isinstance(f, (HybridShift, HybridLocal)):
            return bool(f.keeps_members(E))
        return isinstance(f, (EnKF, ETKF))

    core, inner0 = unwrap(f, s0)
    _, inner1 = unwrap(f, s1)
    gp = f.estimate(s1)
    if isinstance(core, (EKF, KF)) and not s1.reset:
        C = gf.P @ model.F(gf.x, t, dt, u).T
    elif (isinstance(inner0, Ensemble) and isinstance(inner1, Ensemble) and not s1.reset
          and inner0.M == inner1.M and keeps(core, inner0)):
        C = ensemble_cross(inner0, inner1, gf.x, gp.x)
    else:
        ukf = core if isinstance(core, UKF) else UKF()
        gp, C = ukf.predict_cross(gf, model, t, dt, u)
    return gp, C


@pytest.mark.parametrize("spec", SPECS + ["ukf(alpha=0.5)", "hybrid(n_cloud=6, regen_ess=1.0)",
                                          "hybrid(n_cloud=6, sampling=random)"])
def test_rts_terms_reproduce_the_replay_smoother_exactly(spec):
    """Replay records (prediction, C) with the recorded filtered estimate of the previous
    step as ``prev``; the contract must give the same numbers as the old isinstance code,
    including a guard reset in a predict (the NaN step)."""
    p = PROBLEMS["attitude"]
    if base_name(spec) == "kf":
        pytest.skip("KF needs a linear model")
    f = Guarded(make_filter(spec))
    rng = np.random.default_rng(13)
    s = f.init(p.prior, p.space, rng)
    gf = p.prior
    nan_tr = NaNTransition(p.space, bad_t=0.25)
    for t, dt, u, z, model in p.stream(8, seed=13):
        tr = nan_tr if t == 0.25 else p.tr
        s1 = f.predict(s, tr, t, dt, u, rng)
        if t == 0.25:
            assert s1.reset
            tr = p.tr  # the smoother's fallback reads the nominal model
        want = old_record_cross(f, s, s1, gf, tr, t, dt, u)
        got = f.rts_terms(s, s1, tr, t, dt, u, prev=gf)
        for a, b in zip(got[0].x, want[0].x, strict=True):
            assert a == b
        np.testing.assert_array_equal(got[0].P, want[0].P)
        np.testing.assert_array_equal(got[1], want[1])
        s, _ = f.update(s1, z, model, rng)
        gf = f.estimate(s)


def old_mix_states(f, states, w, space, rng):
    """Frozen copy of ``tracking/tracker.py::mix_states`` before the contract."""
    from uavest.core.particle import systematic_resample

    inner = [s.inner for s in states]
    resets = max(s.resets for s in states)
    if all(isinstance(e, Ensemble) for e in inner) and len({e.M for e in inner}) == 1:
        M = inner[0].M
        X = np.concatenate([e.X for e in inner])
        wx = np.concatenate([wh * (np.full(M, 1.0 / M) if e.w is None else e.w)
                             for wh, e in zip(w, inner, strict=True)])
        idx = systematic_resample(wx / wx.sum(), rng, M)
        return f.adopt(states[0], Ensemble(X[idx], inner[0].space), space, rng, resets)
    gs = [f.estimate(s) for s in states]
    x = space.mean(np.stack([g.x for g in gs]), w, gs[int(np.argmax(w))].x)
    P = np.zeros_like(gs[0].P)
    for wh, g in zip(w, gs, strict=True):
        d = space.local(x, g.x[None, :])[0]
        P += wh * (g.P + np.outer(d, d))
    g = Gaussian(x, 0.5 * (P + P.T))
    new = g if isinstance(inner[0], Gaussian) else f.filter.init(g, space, rng)
    return f.adopt(states[0], new, space, rng, resets)


@pytest.mark.parametrize("spec", BASE_SPECS)
def test_mix_reproduces_the_tracker_jpda_mixture_exactly(spec):
    """The tracker's JPDA mixture through ``Guarded.mix`` equals the pre-contract code
    (same seed, same numbers) for every filter without the Sage-Husa wrapper (whose old
    mixture reset the adaptation: a documented change)."""
    p = PROBLEMS["vector"]
    if base_name(spec) == "kf":
        pytest.skip("KF needs a linear model")
    f = Guarded(make_filter(spec))
    rng = np.random.default_rng(14)
    s = f.predict(f.init(p.prior, p.space, rng), p.tr, 1, 1.0, None, rng)
    zs = [z for *_, z, _ in p.stream(3, seed=14)]
    hyps = [f.update(s, z, p.me, rng)[0] for z in zs] + [s]
    w = np.array([0.5, 0.2, 0.1, 0.2])
    a = f.estimate(f.mix(hyps, w, p.space, np.random.default_rng(3)))
    b = f.estimate(old_mix_states(f, hyps, w, p.space, np.random.default_rng(3)))
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
