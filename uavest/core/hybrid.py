"""The hybrid sampling-driven Kalman filter (UKF characteristic sampling + EnKF random
sampling + confidence weights; Cui, Sun and Wen, Sensors 2022).

Implementations sharing the sampling code:

:class:`HybridLiteral` (``hybrid_literal``)
    The reconstruction of the paper, step by step (sigma points with gamma outside the
    root, N-member clouds around each, inverse-distance confidence weights with a
    centroid share omega, perturbed-observation analysis, fresh sampling every step).
    Every **choice** of the reconstruction is a named parameter. Kept for the ablation
    and for measuring the paper's claims; on the UNGM it loses to a plain EnKF
    (docs/filters.md).

:class:`HybridShift` (``hybrid``, ``update_mode=shift``, the default) and :class:`HybridLocal`
(``hybrid(update_mode=local)``)
    Keep the paper's two ideas while staying consistent:
    *expanded sampling*: the ensemble is built from the 2n+1 sigma points each expanded
    into a cloud and then moment-matched, so the cloud reproduces exactly the mean and
    covariance it stands for; members persist across steps and, when the weights have
    degenerated (ESS below a threshold), are regenerated as clouds around the credible
    members (systematic selection + a covariance-preserving shrink kernel);
    *confidence weights*: a member's credibility is how well it explains the measurement.
    They differ only in the update strategy, and each class declares only the
    parameters its strategy uses:
    ``shift``: w_j <- w_j * p(z | X_j)^(1 - tau); the remaining share tau of the
    measurement is then assimilated by an EnKF shift with R / tau, all moments with one
    weight set, process noise on the members. ``local``: a Gaussian-mixture update with
    a local gain per member (:meth:`HybridLocal.update`). All weights are positive and
    sum to 1.

Switches (all classes): ``sampling`` in {"expanded", "random"} and ``weights`` in
{"confidence", "equal"}. random + equal is a plain EnKF (re-sampled from the Gaussian
every step); expanded + confidence is the hybrid. Parameters that a switch makes
irrelevant are refused in specs (their ``when`` declaration).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from types import ModuleType
from typing import Any, ClassVar

import numpy as np

from ..compiled import bitgen_pointers, read_only, register
from ..geometry.spaces import Space, VectorSpace
from .contract import EnsembleFilter, FilterBase
from .ensemble import propagate_members
from .gaussian import Gaussian
from .interfaces import Measurement, Transition, plain_measurement
from .linalg import NotPositiveDefinite, NumericalError, chol, gain, is_pd, symmetrize
from .particle import ess, log_likelihood
from .resample import systematic_resample
from .spec import Param, param
from .states import (
    Ensemble,
    Innovation,
    ensemble_estimate,
    ensemble_moments,
    equal_weights,
    innovation,
    mean_start,
)

Array = np.ndarray
Rng = np.random.Generator

SAMPLINGS = ("expanded", "random")
UPDATE_MODES = ("shift", "local")
WEIGHTINGS = ("confidence", "equal")


def default_gamma(n: int) -> float:
    """Default sigma scaling: sqrt(3) for n <= 3, else sqrt(n)."""
    return float(np.sqrt(3.0) if n <= 3 else np.sqrt(n))


def expanded_offsets(
    L: Array, gamma: float, n_cloud: int, spread: float, rng: np.random.Generator
) -> Array:
    """Tangent offsets of the expanded ensemble, (2n+1)(N+1) rows, first row zero.

    Sigma offsets {0, +gamma L_i, -gamma L_i}; around each, ``n_cloud`` draws of
    N(0, spread^2 L L^T); the sigma point itself is kept in its cloud.
    """
    n = L.shape[0]
    sig = np.vstack([np.zeros((1, n)), gamma * L.T, -gamma * L.T])  # (2n+1, n)
    E = rng.standard_normal((2 * n + 1, n_cloud, n)) @ (spread * L.T)
    cloud = np.concatenate([np.zeros((2 * n + 1, 1, n)), E], axis=1)
    res: Array = (sig[:, None, :] + cloud).reshape(-1, n)
    return res


def sample_offsets(
    sampling: str, L: Array, gamma: float | None, n_cloud: int, spread: float, rng: Any
) -> Array:
    """Tangent offsets of M = (2n+1)(N+1) members around the mean for a covariance with
    lower factor ``L``: ``expanded`` (sigma points + clouds, first row the centre) or
    ``random`` (iid N(0, L L^T) draws, first row set to the centre so a centroid exists)."""
    n = L.shape[0]
    if sampling == "expanded":
        return expanded_offsets(L, gamma or default_gamma(n), n_cloud, spread, rng)
    D = rng.standard_normal(((2 * n + 1) * (n_cloud + 1), n)) @ L.T
    D[0] = 0.0
    res: Array = D
    return res


def match_moments(D: Array, L: Array) -> Array:
    """Affine map of offsets ``D`` (M, n) so that their equal-weight mean is 0 and their
    1/(M-1) covariance is exactly L L^T (statistically constrained sampling)."""
    D = D - D.mean(axis=0)
    C = D.T @ D / (D.shape[0] - 1)
    Lc = chol(C)
    res: Array = np.linalg.solve(Lc, D.T).T @ L.T
    return res


def confidence_weights(
    d: Array, omega: float, eps: float, distance: str, centre: int = 0
) -> Array:
    """Step 4 of the paper: inverse-distance weights of a cloud given its deviations ``d`` (M, k)
    from the centroid (row ``centre``). Mahalanobis under the cloud's own sample
    covariance, or Euclidean; raw weight 1/max(d_j, eps), centroid raw 0; normalised to
    1 - omega; the centroid gets omega. All weights > 0, sum 1."""
    if distance == "mahalanobis":
        C = np.cov(d, rowvar=False, ddof=1).reshape(d.shape[1], d.shape[1])
        u = np.linalg.solve(chol(C), d.T)
        dist = np.sqrt(np.einsum("ij,ij->j", u, u))
    elif distance == "euclidean":
        dist = np.sqrt(np.einsum("ij,ij->i", d, d))
    else:
        raise ValueError(f"distance must be 'mahalanobis' or 'euclidean', not {distance!r}")
    raw = 1.0 / np.maximum(dist, eps)
    raw[centre] = 0.0
    w = (1.0 - omega) * raw / raw.sum()
    w[centre] = omega
    res: Array = w
    return res


# ------------------------------------------------------------------------------ literal


@dataclass(frozen=True, slots=True)
class HybridPrior:
    """Predicted state of :class:`HybridLiteral`: the Gaussian and the predicted cloud
    (members ``X``, weights ``w``) that the update reuses."""

    g: Gaussian
    X: Array
    w: Array


_EXPANDED = {"sampling": ("expanded",)}
_CONFIDENCE = {"weights": ("confidence",)}


def _sampling_param() -> dict[str, Param]:
    return param("choice", choices=SAMPLINGS, doc="expanded (sigma clouds) | random")


def _weights_param() -> dict[str, Param]:
    return param("choice", choices=WEIGHTINGS, doc="confidence | equal")


def _gamma_param() -> dict[str, Param]:
    return param("float", lo=0.0, lo_open=True, none_ok=True, when=_EXPANDED,
                 doc="sigma scaling; none = sqrt(3) for n <= 3 else sqrt(n)")


@dataclass(frozen=True)
class HybridLiteral(FilterBase):
    """The paper's hybrid filter (Cui, Sun and Wen, Sensors 2022) as reconstructed step
    by step (steps 1-7).

    Parameters (the reconstruction's **choices**, defaults as reconstructed):
      sampling: "expanded" (sigma points + clouds) | "random" (EnKF draws; the centre x is
        kept as member 0 so a centroid exists), same member count M = (2n+1)(N+1).
      weights: "confidence" | "equal".
      gamma: sigma scaling outside the root; None = sqrt(3) for n <= 3 else sqrt(n).
      n_cloud: N members per cloud (20). spread: cloud std factor s (0.5).
      omega: centroid share of the confidence weights (0.5). eps: distance floor (1e-6).
      distance: "mahalanobis" | "euclidean".
      process_noise: "covariance" (add Q to P-, the paper's) | "members" (w_j ~ N(0,Q)).
      cross_weights: weights of Pxy: "state" (the paper's) | "measurement" | "product".
      posterior: "kalman" (P- - K Pyy K^T, falling back to the weighted sample covariance of
        the analysed cloud when not PD) | "sample" (always the sample covariance).
    RTS smoothing: the sigma-point fallback (members are redrawn every step).
    """

    sampling: str = field(default="expanded", metadata=_sampling_param())
    weights: str = field(default="confidence", metadata=_weights_param())
    gamma: float | None = field(default=None, metadata=_gamma_param())
    n_cloud: int = field(default=20, metadata=param("int", lo=1, doc="members per cloud N"))
    spread: float = field(default=0.5, metadata=param(
        "float", lo=0.0, lo_open=True, when=_EXPANDED, doc="cloud std factor"))
    omega: float = field(default=0.5, metadata=param(
        "float", lo=0.0, hi=1.0, hi_open=True, when=_CONFIDENCE, doc="centroid share"))
    eps: float = field(default=1e-6, metadata=param(
        "float", lo=0.0, lo_open=True, when=_CONFIDENCE, doc="distance floor"))
    distance: str = field(default="mahalanobis", metadata=param(
        "choice", choices=("mahalanobis", "euclidean"), when=_CONFIDENCE))
    process_noise: str = field(default="covariance", metadata=param(
        "choice", choices=("covariance", "members")))
    cross_weights: str = field(default="state", metadata=param(
        "choice", choices=("state", "measurement", "product"), when=_CONFIDENCE))
    posterior: str = field(default="kalman", metadata=param(
        "choice", choices=("kalman", "sample")))
    name: str = "hybrid_literal"

    def __post_init__(self) -> None:
        _check_switches(self.sampling, self.weights)
        if self.process_noise not in ("covariance", "members"):
            raise ValueError("process_noise must be 'covariance' or 'members'")
        if self.cross_weights not in ("state", "measurement", "product"):
            raise ValueError("cross_weights must be 'state', 'measurement' or 'product'")
        if self.posterior not in ("kalman", "sample"):
            raise ValueError("posterior must be 'kalman' or 'sample'")

    def members(self, n: int) -> int:
        return (2 * n + 1) * (self.n_cloud + 1)

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> Gaussian:
        return prior

    def _weights(self, d: Array) -> Array:
        if self.weights == "equal":
            return np.full(d.shape[0], 1.0 / d.shape[0])
        return confidence_weights(d, self.omega, self.eps, self.distance)

    def predict(self, s: Gaussian | HybridPrior, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Any = None) -> HybridPrior:
        g = s.g if isinstance(s, HybridPrior) else s
        space = model.space
        D = sample_offsets(self.sampling, chol(g.P), self.gamma, self.n_cloud, self.spread, rng)
        X = model.f(space.retract(g.x, D), t, dt, u)
        Q = model.Q(t, dt, u)
        if self.process_noise == "members":
            X = space.retract(X, rng.standard_normal(D.shape) @ chol(Q).T)
        w = self._weights(space.local(X[0], X))
        x = space.mean(X, w, X[0])
        dX = space.local(x, X)
        P = (dX.T * w) @ dX
        if self.process_noise == "covariance":
            P = P + Q
        return HybridPrior(Gaussian(x, symmetrize(P)), X, w)

    def update(self, s: Gaussian | HybridPrior, z: Array, model: Measurement, rng: Any = None
               ) -> tuple[Gaussian, Innovation]:
        if not isinstance(s, HybridPrior):  # update without a predict: sample the cloud now
            s = _prior_from_gaussian(self, s, model.space, rng)
        space = model.space
        X, wx, g = s.X, s.w, s.g
        Y = model.h(X)
        wy = self._weights(model.residual(Y, Y[0]))
        ybar = model.mean(Y, wy)
        dY = model.residual(Y, ybar)
        dX = space.local(g.x, X)
        S = symmetrize((dY.T * wy) @ dY + model.R)
        if self.cross_weights == "state":
            wc = wx
        elif self.cross_weights == "measurement":
            wc = wy
        else:
            wc = wx * wy / float(wx @ wy)
        K = gain((dX.T * wc) @ dY, S)
        V = rng.standard_normal((X.shape[0], model.dim)) @ chol(model.R).T
        A = space.retract(X, (model.residual(z, Y) + V) @ K.T)
        wa = self._weights(space.local(A[0], A))
        x = space.mean(A, wa, A[0])
        P = symmetrize(g.P - K @ S @ K.T)
        if self.posterior == "sample" or not is_pd(P):
            dA = space.local(x, A)
            P = symmetrize((dA.T * wa) @ dA)
        return Gaussian(x, P), innovation(model.residual(z, ybar), S)

    def estimate(self, s: Gaussian | HybridPrior) -> Gaussian:
        return s.g if isinstance(s, HybridPrior) else s


def _prior_from_gaussian(f: HybridLiteral, g: Gaussian, space: Space, rng: Any
                         ) -> HybridPrior:
    D = sample_offsets(f.sampling, chol(g.P), f.gamma, f.n_cloud, f.spread, rng)
    X = space.retract(g.x, D)
    return HybridPrior(g, X, f._weights(D))


def _check_switches(sampling: str, weights: str) -> None:
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {SAMPLINGS}, not {sampling!r}")
    if weights not in WEIGHTINGS:
        raise ValueError(f"weights must be one of {WEIGHTINGS}, not {weights!r}")


# ------------------------------------------------------------------------------ default

_PHI_GRID = np.linspace(0.0, 1.0, 17)


# The hot paths below call ``np.dot`` rather than ``@`` (the same BLAS routine and the
# same numbers for these 1-D / 2-D operands, without the gufunc's per-call overhead, which
# dominates on ensembles of ~100 members) and ``np.add.reduce`` / ``np.maximum.reduce``
# rather than the ``.sum()`` / ``.max()`` methods (the same reduction, one call less).
_dot = np.dot
_empty = np.empty
_sum = np.add.reduce
_max = np.maximum.reduce


@lru_cache(maxsize=32)
def _log_equal(M: int) -> Array:
    """log(max(1/M, 1e-300)) as :func:`tempered_weights` computes it for equal weights."""
    a = np.log(np.maximum(equal_weights(M), 1e-300))
    a.flags.writeable = False
    res: Array = a
    return res


@lru_cache(maxsize=32)
def _equal_writable(M: int) -> Array:
    """The equal weights 1/M as a writable array, for the kernels only (they never write
    to it): numba types a read-only array apart, and each type is one more compilation
    of every kernel it reaches."""
    return np.full(M, 1.0 / M)


def tempered_weights(
    w: Array, loglik: Array, phi_max: float, min_ess: float
) -> tuple[Array, float]:
    """Weights w * p^phi for the largest phi in [0, phi_max] (grid of 17) whose effective
    sample size stays >= min_ess * M (or, if even phi = 0 is below it, phi = 0).

    Returns (normalised weights, phi). Vectorised over the grid: one (17, M) evaluation.
    """
    M = w.shape[0]
    logw0 = _log_equal(M) if w is equal_weights(M) else np.log(np.maximum(w, 1e-300))
    L1 = logw0 + phi_max * loglik  # common case first: the full share keeps the ESS floor
    W1 = np.exp(L1 - _max(L1))
    W1 /= _sum(W1)
    if 1.0 / _dot(W1, W1) >= min_ess * M:
        return W1, float(phi_max)
    phis = phi_max * _PHI_GRID
    L = logw0 + phis[:, None] * loglik
    W = np.exp(L - _max(L, axis=1, keepdims=True))
    W /= _sum(W, axis=1, keepdims=True)
    ok = _sum(W * W, axis=1) * (min_ess * M) <= 1.0  # ESS = 1 / sum w^2 >= min_ess M
    i = int(np.nonzero(ok)[0][-1]) if ok.any() else 0
    return W[i], float(phis[i])


def _mean(space: Space, X: Array, w: Array) -> Array:
    """``space.mean`` of members ``X`` with weights ``w`` (``np.dot`` on a plain vector
    space: the same numbers as its ``w @ X``)."""
    if type(space) is VectorSpace:
        res: Array = _dot(w, X)
        return res
    return space.mean(X, w, mean_start(space, X, w))


def _shift_cases(nb: ModuleType) -> Iterator[tuple[str, Any, Any]]:
    """The self-check (:mod:`uavest.compiled`): the kernels against the numpy path on
    small ensembles, 2-D with a 2-D measurement (the general loops) and 1-D (their own
    loops): one regeneration and one tempered shift update each."""

    class _Sq(Measurement):
        def __init__(self, n: int) -> None:
            self.R = np.array([[0.5, 0.1], [0.1, 0.8]])[:n, :n]
            self.space = VectorSpace(n)

        def h(self, X: Array) -> Array:
            Y: Array = X * X
            return Y

    f = HybridShift(n_cloud=2)
    for n in (2, 1):
        rng = np.random.default_rng(n)
        X = rng.standard_normal((15, n))
        w = rng.uniform(0.5, 1.5, 15)
        w /= w.sum()
        E = Ensemble(X, VectorSpace(n), w)
        me = _Sq(n)
        z = np.array([0.7, 1.9])[:n]
        a, ia = f._update_numpy(E, z, me, np.random.default_rng(2))
        got = f._update_compiled(nb, E, z, me, np.random.default_rng(2))
        if got is None:
            yield f"n={n} update", None, a.X
            return
        b, ib = got
        ga, gb = ensemble_estimate(a), ensemble_estimate(b)
        ra = f._regenerate(E, np.random.default_rng(3))
        rng = np.random.default_rng(3)  # systematic_resample's uniform, then the normals
        u = rng.random()
        rb = np.empty((15, n))
        st = nb.regenerate(X, w, u, rng.standard_normal((15, n)), f.kernel, rb)
        yield f"n={n} regenerate status", st, 0
        for label, p, q in (("X", a.X, b.X), ("w", a.w, b.w), ("x", ga.x, gb.x),
                            ("P", ga.P, gb.P), ("nu", ia.nu, ib.nu), ("S", ia.S, ib.S),
                            ("nis", ia.nis, ib.nis), ("regenerated X", ra.X, rb)):
            yield f"n={n} {label}", q, p
    yield from _tangent_cases(nb)


def _tangent_cases(nb: ModuleType) -> Iterator[tuple[str, Any, Any]]:
    """The reinflated update on a manifold (:func:`~uavest.core._compiled_shift.shift_tangent`
    through :meth:`HybridShift._update_tangent`) against the numpy path: 26 weighted
    members of the attitude space, a 3-D direction measurement and an angle (its heading,
    the members on both sides of +-pi)."""
    from ..geometry.rotation import AttitudeSpace, quat_rotate_inv, wrap_pi

    space = AttitudeSpace()

    class _Dir(Measurement):
        R = np.diag([0.02, 0.03, 0.025])

        def __init__(self) -> None:
            self.space = space

        def h(self, X: Array) -> Array:
            return quat_rotate_inv(X[:, :4], np.array([0.6, 0.0, 0.8]))

    class _Yaw(_Dir):  # an angle: the heading of that direction, wrapped
        R = np.array([[0.01]])

        def h(self, X: Array) -> Array:
            d = super().h(X)
            res: Array = np.arctan2(d[:, 1], d[:, 0])[:, None]
            return res

        def residual(self, a: Array, b: Array) -> Array:
            return wrap_pi(a - b)

        def mean(self, Y: Array, w: Array) -> Array:
            return wrap_pi(Y[0] + w @ wrap_pi(Y - Y[0]))

        def arithmetic(self) -> str | None:
            return "angle"

    rng = np.random.default_rng(5)
    f = HybridShift(n_cloud=1, reinflate=True)
    x0 = np.array([0.0, 0.1, -0.2, 0.9, 0.01, 0.0, -0.02])  # (the heading near +-pi)
    x0[:4] /= np.linalg.norm(x0[:4])
    X = space.retract(x0, 0.2 * rng.standard_normal((26, 6)))
    w = rng.uniform(0.5, 1.5, 26)
    E = Ensemble(X, space, w / w.sum())
    ensemble_moments(E)  # the prior's memo, which the kernel reads
    for tag, me, z in (("", _Dir(), np.array([0.5, 0.1, 0.85])),
                       (" angle", _Yaw(), np.array([3.1]))):
        a, ia = f._update_numpy(E, z, me, np.random.default_rng(6))
        got = f._update_tangent(nb, E, z, me, np.random.default_rng(6))
        if got is None:
            yield "tangent update" + tag, None, a.X
            return
        b, ib = got
        for label, p, q in (("X", a.X, b.X), ("w", a.w, b.w), ("nu", ia.nu, ib.nu),
                            ("S", ia.S, ib.S), ("nis", ia.nis, ib.nis)):
            yield f"tangent{tag} {label}", q, p


#: The compiled kernels of :class:`HybridShift` on vector spaces
#: (:mod:`uavest.core._compiled_shift`)
SHIFT_KERNELS = register("shift", "uavest.core._compiled_shift", "numba shift kernels",
                         _shift_cases, rtol=1e-12, atol=1e-12)


def _plain_vector(model: Measurement) -> bool:
    """A measurement of a vector state with the plain mean and residual (the kernels'
    case)."""
    return type(model.space) is VectorSpace and plain_measurement(model)


def _float_vector(z: object, m: int) -> bool:
    """``z`` is a float64 array of shape (m,) (what the kernels read)."""
    return type(z) is np.ndarray and z.dtype == np.float64 and z.shape == (m,)


def sampling_shrink(Pyy: Array, R: Array, w: Array) -> float:
    """The share by which one EnKF shift with a gain from sample moments shrinks the
    members' spread beyond what the exact gain would, to first order: tr(S^-1 Pyy) / N,
    with S = Pyy + R the shift's innovation covariance and N = 1 / sum w^2 the effective
    number of members.

    Why: a state's sample covariance with the predicted measurement carries a sampling
    error of variance ~ P_xx Pyy / N whatever the true correlation, and the shift removes
    the square of it as if it were correlation (the "inbreeding" of Houtekamer and
    Mitchell, "Data assimilation using an ensemble Kalman filter technique", Monthly
    Weather Review 1998). On a weakly observed, long-memory state (a navigation filter's
    position, aided through its velocity) nothing refreshes the spread, and the shrink
    accumulates (docs/filters.md, "Long memory")."""
    return float(np.trace(np.linalg.solve(Pyy + R, Pyy))) * float(_dot(w, w))


class _HybridBase(EnsembleFilter):
    """Sampling, regeneration and prediction shared by :class:`HybridShift` and
    :class:`HybridLocal` (fields declared by the subclasses)."""

    sampling: str
    weights: str
    gamma: float | None
    n_cloud: int
    spread: float
    regen_ess: float
    kernel: float

    def members(self, n: int) -> int:
        """Ensemble size M = (2n+1)(N+1) for tangent dimension n."""
        return (2 * n + 1) * (self.n_cloud + 1)

    def _draw(self, g: Gaussian, space: Space, rng: Any) -> Array:
        L = chol(g.P)
        if self.sampling == "expanded":
            D = match_moments(expanded_offsets(
                L, self.gamma or default_gamma(L.shape[0]), self.n_cloud, self.spread, rng), L)
        else:  # iid draws; no centre member is needed (no centroid weights here)
            D = rng.standard_normal((self.members(L.shape[0]), L.shape[0])) @ L.T
        return space.retract(g.x, D)

    def init(  # type: ignore[override]  # (a generator is required here)
        self, prior: Gaussian, space: Space, rng: np.random.Generator
    ) -> Ensemble:
        return Ensemble(self._draw(prior, space, rng), space)

    def _regenerate(self, E: Ensemble, rng: Any) -> Ensemble:
        x, dX, w, P = ensemble_moments(E)
        idx = systematic_resample(w, rng)
        h = self.kernel
        a = math.sqrt(1.0 - h * h)
        J = _dot(rng.standard_normal((E.M, E.space.dim)), (h * chol(P)).T)
        return Ensemble(E.space.retract(x, a * dX[idx] + J), E.space)

    def keeps_members(self, E: Ensemble) -> bool:
        """True if ``predict(E)`` will propagate these very members (row j stays member j),
        so that member-wise cross-covariances (ensemble RTS smoothing) are meaningful;
        False if it will redraw (``sampling="random"``) or regenerate them."""
        if self.sampling == "random":
            return False
        return E.w is None or ess(E.w) >= self.regen_ess * E.M

    def predict(self, E: Ensemble, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Any = None) -> Ensemble:
        if self.sampling == "random":
            E = Ensemble(self._draw(ensemble_estimate(E), E.space, rng), E.space)
        elif not self.keeps_members(E):
            E = self._regenerate(E, rng)
        return self._propagate(E, model, t, dt, u, rng)

    def _propagate(self, E: Ensemble, model: Transition, t: float, dt: float,
                   u: Array | None, rng: Any) -> Ensemble:
        """f on every member plus process noise (:func:`propagate_members`)."""
        return propagate_members(E, model, t, dt, u, rng)

    def estimate(self, E: Ensemble) -> Gaussian:
        return ensemble_estimate(E)


@dataclass(frozen=True)
class HybridShift(_HybridBase):
    """Consistent hybrid filter with the tempered-weights + EnKF-shift update (the
    default ``hybrid``, ``update_mode=shift``). See the module docstring.

    Parameters:
      sampling: "expanded" (sigma points + moment-matched clouds, persistent members,
        regeneration around credible members) | "random" (iid Gaussian redraw each step).
      weights: "confidence" (likelihood credibility, tempered) | "equal" (pure EnKF shift).
      gamma: sigma-point scaling, None = sqrt(3) for n <= 3 else sqrt(n).
      n_cloud: N, members per sigma point besides the point itself; M = (2n+1)(N+1).
      spread: cloud std factor s around each sigma point before moment matching (0.5).
      tau: share of the measurement assimilated by the EnKF shift (R / tau); the rest,
        1 - tau, goes into the confidence weights (0 < tau <= 1).
      min_ess: floor on the effective sample size an update may leave, as a fraction of M
        (0.2). The weighting exponent phi <= 1 - tau is the largest on a grid that keeps
        ESS >= min_ess * M; the EnKF shift then takes the rest, R / (1 - phi) (adaptive
        tempering, as in the ensemble Kalman particle filter of Frei and Kuensch,
        "Bridging the ensemble Kalman and particle filters", Biometrika 2013).
      stages: at most this many tempering stages per update (1). When the ESS floor stops
        the weighting short of 1 - tau (a measurement much sharper than the ensemble, e.g.
        a 10 m range against a 1 km prior), the members are regenerated around the
        credible ones and weighted again with the rest (progressive correction); the
        EnKF shift takes what is left. 6 stages with n_cloud=64 help the far radar case
        (PCRLB ratio 1.53 -> 1.31) but cost on the bimodal UNGM (docs/filters.md).
      shifts: split the EnKF shift into this many smaller ones, each with R * shifts / share
        and a gain recomputed from the moved members (multiple data assimilation, Emerick
        and Reynolds, "Ensemble smoother with multiple data assimilation", Computers and
        Geosciences 2013), for measurements much more nonlinear than one linear
        regression across the ensemble can follow (1).
      regen_ess: regenerate when the effective sample size < regen_ess * M (0.5).
      kernel: bandwidth h of the regeneration kernel; members are shrunk by sqrt(1-h^2)
        towards the mean and jittered with N(0, h^2 P), preserving mean and covariance.
      reinflate: after each EnKF shift, spread the members out about their weighted mean
        by sqrt(1 + tr(S^-1 Pyy) / N) (:func:`sampling_shrink`): what a gain made from
        sample moments takes out of the spread beyond the exact gain (False; the
        navigation preset's hybrid has it on). The members are rebuilt about the prior
        mean: on a manifold the result differs from the plain shift at second order in
        the spread, and the compiled kernels are not used.
    ``tau``, ``min_ess``, ``stages``, ``kernel`` have an effect only with confidence
    weights, ``regen_ess`` only with expanded sampling and confidence weights, ``gamma``
    and ``spread`` only with expanded sampling.
    """

    update_mode: ClassVar[str] = "shift"

    sampling: str = field(default="expanded", metadata=_sampling_param())
    weights: str = field(default="confidence", metadata=_weights_param())
    gamma: float | None = field(default=None, metadata=_gamma_param())
    n_cloud: int = field(default=32, metadata=param("int", lo=1, doc="members per sigma point N"))
    spread: float = field(default=0.5, metadata=param(
        "float", lo=0.0, lo_open=True, when=_EXPANDED, doc="cloud std factor"))
    tau: float = field(default=0.3, metadata=param(
        "float", lo=0.0, hi=1.0, lo_open=True, when=_CONFIDENCE, doc="EnKF-shift share"))
    min_ess: float = field(default=0.2, metadata=param(
        "float", lo=0.0, hi=1.0, when=_CONFIDENCE, doc="ESS floor of one update, / M"))
    stages: int = field(default=1, metadata=param(
        "int", lo=1, when=_CONFIDENCE, doc="tempering stages per update"))
    shifts: int = field(default=1, metadata=param("int", lo=1, doc="EnKF shifts per update"))
    regen_ess: float = field(default=0.5, metadata=param(
        "float", lo=0.0, hi=1.0, when={**_EXPANDED, **_CONFIDENCE},
        doc="regenerate below this ESS / M"))
    kernel: float = field(default=0.3, metadata=param(
        "float", lo=0.0, hi=1.0, lo_open=True, when=_CONFIDENCE,
        doc="regeneration kernel bandwidth h"))
    reinflate: bool = field(default=False, metadata=param(
        "bool", doc="undo the gain's sampling-error shrink after each shift"))
    name: str = "hybrid"

    def __post_init__(self) -> None:
        _check_switches(self.sampling, self.weights)
        if not 0.0 < self.tau <= 1.0:
            raise ValueError("tau must be in (0, 1]")

    def init(  # type: ignore[override]  # (a generator is required here)
        self, prior: Gaussian, space: Space, rng: np.random.Generator
    ) -> Ensemble:
        if type(space) is VectorSpace:
            SHIFT_KERNELS.get()  # numba's import and cache load here, not in the first step
        return super().init(prior, space, rng)

    # -- the compiled path (numba installed; vector spaces, one stage, one shift) -------
    # What ``_HybridBase.predict`` and ``_update_numpy`` do, with the work between the
    # model calls and the random draws in one kernel call each (uavest/core/
    # _compiled_shift.py): the same draws in the same order and shapes, the same formulas,
    # equal to rounding (tests/unit/test_fast_paths.py). Failures (non-finite weights or
    # results, a covariance that is not positive definite) go to the numpy path, which
    # raises or continues as it always has.

    def predict(self, E: Ensemble, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Any = None) -> Ensemble:
        """``_HybridBase.predict`` (regenerate if the ESS is low, then propagate with
        process noise); with the shift kernels on a vector space with expanded sampling,
        the regeneration and the noise in kernel calls (a failure of the chol of Q
        raises before any draw here, after the regeneration's draws there)."""
        nb = SHIFT_KERNELS.get()
        space = model.space
        if not nb or self.sampling != "expanded" or type(space) is not VectorSpace:
            return super().predict(E, model, t, dt, u, rng)
        X, w, M = E.X, E.w, E.M
        regen = False
        if w is not None:
            e = ess(w)
            if e < self.regen_ess * M:  # ``keeps_members`` is False: regenerate
                if not 0.0 < e < math.inf:  # (non-finite weights: numpy raises)
                    return super().predict(E, model, t, dt, u, rng)
                regen = True
            elif not e >= self.regen_ess * M:  # NaN: the numpy path decides
                return super().predict(E, model, t, dt, u, rng)
        L = chol(model.Q(t, dt, u))
        if regen:
            # systematic_resample's uniform, then the shrink kernel's normals and the
            # process noise's in one call (the same numbers as two calls of M rows)
            v = rng.random()
            Z = rng.standard_normal((2 * M, X.shape[1]))
            X = _empty(X.shape)
            st = nb.regenerate(E.X, w, v, Z[:M], self.kernel, X)
            if st:
                raise NotPositiveDefinite("covariance has non-finite entries" if st == 1
                                          else "covariance is not positive definite")
            w = None
            X = model.f(X, t, dt, u)
            Z = Z[M:]
        else:
            X = model.f(X, t, dt, u)
            Z = rng.standard_normal(X.shape)
        out = _empty(X.shape)
        nb.add_noise(X, Z, L, out)
        return Ensemble(out, space, w)

    def update(self, E: Ensemble, z: Array, model: Measurement, rng: Any = None
               ) -> tuple[Ensemble, Innovation]:
        """Tempered confidence weights, then the EnKF shift (the module docstring;
        :meth:`_update_numpy`); one kernel call for one stage and one shift on a vector
        space with a plain measurement model and a float64 ``z`` of its size."""
        nb = SHIFT_KERNELS.get()
        out = self._update_compiled(nb, E, z, model, rng) if nb else None
        return out if out is not None else self._update_numpy(E, z, model, rng)

    def _update_compiled(self, nb: ModuleType, E: Ensemble, z: Array, model: Measurement,
                         rng: Any
                         ) -> tuple[Ensemble, Innovation] | None:
        """The update through :func:`uavest.core._compiled_shift.shift_update`; its
        result carries its estimate (``Ensemble.gaussian``). None, before any draw, where
        the kernel does not apply (more than one stage or shift, a measurement model that
        is not plain on a vector space, a ``z`` that is not the model's float64 vector).
        A failure hands the drawn normals to :meth:`_update_numpy`."""
        if self.reinflate:
            return self._update_tangent(nb, E, z, model, rng)
        if not (self.stages == self.shifts == 1 and _plain_vector(model)
                and _float_vector(z, model.dim)):
            return None
        M = E.M
        w = _equal_writable(M) if E.w is None else E.w
        Y = model.h(E.X)
        V = rng.standard_normal((M, model.dim))  # the shift's perturbations
        confidence = self.weights == "confidence"
        n, m = E.X.shape[1], V.shape[1]
        # the outputs, allocated here: arrays numba makes and returns cost ~1 us each
        X, wn, nu, S, x, P = (_empty((M, n)), _empty(M), _empty(m), _empty((m, m)),
                              _empty(n), _empty((n, n)))
        st, nis = nb.shift_update(E.X, Y, z, w, model.R, V, self.tau, self.min_ess,
                                  confidence, X, wn, nu, S, x, P)
        if st:
            return self._update_numpy(E, z, model, rng, V)
        return (Ensemble(X, E.space, wn if confidence else None, gaussian=Gaussian(x, P)),
                Innovation(nu, S, nis))

    def _update_tangent(self, nb: ModuleType, E: Ensemble, z: Array, model: Measurement,
                        rng: Any) -> tuple[Ensemble, Innovation] | None:
        """The update with ``reinflate`` on a manifold (the navigation preset's hybrid)
        through :func:`uavest.core._compiled_shift.shift_tangent`, then the space's
        retraction of the new tangent vectors at the prior's mean. None, before any draw,
        where the kernel does not apply: more than one stage or shift, a vector space, a
        prior without its memoised moments (the numpy path's ``L0`` is then not centred),
        a measurement whose residual and mean are neither plain nor an angle's
        (``Measurement.arithmetic``), a ``z`` that is not the model's float64 vector. A
        failure hands the drawn normals to :meth:`_update_numpy`."""
        space = model.space
        how = model.arithmetic()
        if not (self.stages == self.shifts == 1 and E.moments is not None
                and type(space) is not VectorSpace and how in ("plain", "angle")
                and _float_vector(z, model.dim)):
            return None
        x, L0 = E.moments[0], E.moments[1]
        M = E.M
        w = _equal_writable(M) if E.w is None else E.w
        Y = np.ascontiguousarray(model.h(E.X))  # (some h give a transposed view)
        V = rng.standard_normal((M, model.dim))  # the shift's perturbations
        confidence = self.weights == "confidence"
        n, m = L0.shape[1], V.shape[1]
        T, wn, nu, S = _empty((M, n)), _empty(M), _empty(m), _empty((m, m))
        st, nis = nb.shift_tangent(L0, Y, z, w, model.R, V, self.tau, self.min_ess,
                                   confidence, T, wn, nu, S, how == "angle")
        if st:
            return self._update_numpy(E, z, model, rng, V)
        return (Ensemble(space.retract(x, T), E.space, wn if confidence else None),
                Innovation(nu, S, nis))

    def _update_numpy(self, E: Ensemble, z: Array, model: Measurement, rng: Any = None,
                      V0: Array | None = None
                      ) -> tuple[Ensemble, Innovation]:
        """The update on numpy arrays (any space, stages and shifts; the reference of the
        compiled path). ``V0``: the first shift's standard normals if already drawn."""
        space = model.space
        M = E.M
        w = equal_weights(M) if E.w is None else E.w
        Y = model.h(E.X)
        r = model.residual(z, Y)
        ybar = model.mean(Y, w)
        dY0 = model.residual(Y, ybar)
        innov = innovation(model.residual(z, ybar), _dot(dY0.T * w, dY0) + model.R)
        tau = 1.0
        if self.weights == "confidence":
            left = 1.0 - self.tau  # share of the likelihood still to go into the weights
            for stage in range(self.stages):
                w, phi = tempered_weights(w, log_likelihood(r, model.R), left, self.min_ess)
                left -= phi
                if left <= 1e-9 or stage == self.stages - 1:
                    break
                E = self._regenerate(Ensemble(E.X, E.space, w), rng)
                w = equal_weights(M)
                Y = model.h(E.X)
                r = model.residual(z, Y)
            tau = self.tau + left
        X = E.X
        c = 1.0 / max(1.0 - float(_dot(w, w)), 1e-12)
        Rt = model.R * (self.shifts / tau)
        Lr = chol(Rt)
        flat = type(space) is VectorSpace
        plain = flat and plain_measurement(model)
        for i in range(self.shifts):
            if i:
                Y = model.h(X)
                r = model.residual(z, Y)
            dY = model.residual(Y, model.mean(Y, w))
            if not plain:  # a manifold, or e.g. a circular mean: centre them exactly
                dY = dY - _dot(w, dY)
            # weighted sums of outer products: symmetric by construction (Cholesky reads
            # the lower triangle), so no symmetrising on this hot path
            if flat:
                # on a vector space sum_j w_j (X_j - x) dY_j^T = sum_j w_j X_j dY_j^T (the
                # weighted dY sum to zero), so neither the mean nor dX is needed
                A = dY.T * (c * w)
                Pyy = _dot(A, dY)
                K = gain(_dot(A, X).T, Pyy + Rt)
            else:
                if self.reinflate and i == 0 and E.moments is not None:
                    # the prior's mean and deviations (the estimate's memo), recentred
                    # below under the update's weights: the new members are built on it
                    x, L0 = E.moments[0], E.moments[1]
                else:
                    x = _mean(space, X, w)
                    L0 = space.local(x, X)
                dX = L0 - _dot(w, L0)
                Pyy = _dot(c * (dY.T * w), dY)
                K = gain(_dot(c * (dX.T * w), dY), Pyy + Rt)
            V = rng.standard_normal((M, model.dim)) if i or V0 is None else V0
            D = _dot(r + _dot(V, Lr.T), K.T)  # each member's shift
            if not self.reinflate:
                X = space.retract(X, D)
            elif flat:
                X = X + D
                x = _dot(w, X)
                X = x + math.sqrt(1.0 + sampling_shrink(Pyy, Rt, w)) * (X - x)
            else:  # the shifted members about the prior mean, spread out about their mean
                D += L0
                d = _dot(w, D)
                a = math.sqrt(1.0 + sampling_shrink(Pyy, Rt, w))
                X = space.retract(x, d + a * (D - d))
        return Ensemble(X, E.space, None if self.weights == "equal" else w), innov



@dataclass(frozen=True)
class HybridLocal(_HybridBase):
    """Consistent hybrid filter with the local-gain Gaussian-mixture update
    (``hybrid(update_mode=local)``; the ensemble Gaussian-mixture / kernel filter of
    Anderson and Anderson, "A Monte Carlo implementation of the nonlinear filtering
    problem to produce ensemble assimilations and forecasts", Monthly Weather Review
    1999, with the hybrid's sampling and confidence weights).

    Parameters: ``sampling``, ``weights``, ``gamma``, ``n_cloud``, ``spread`` as
    :class:`HybridShift`; ``regen_ess``: resample the mixture components when the ESS of the
    updated weights is < regen_ess * M (0.5; confidence weights only); ``bandwidth``: the
    kernel bandwidth h as a fraction of the ensemble spread (None: Silverman's rule).
    The update leaves either equal weights or weights with ESS >= regen_ess * M, so the
    predict never regenerates (the fixed ``kernel`` below is never used by a spec'd run).
    """

    update_mode: ClassVar[str] = "local"
    kernel: ClassVar[float] = 0.3  # type: ignore[misc]  # regeneration kernel of an externally weighted state

    sampling: str = field(default="expanded", metadata=_sampling_param())
    weights: str = field(default="confidence", metadata=_weights_param())
    gamma: float | None = field(default=None, metadata=_gamma_param())
    n_cloud: int = field(default=32, metadata=param("int", lo=1, doc="members per sigma point N"))
    spread: float = field(default=0.5, metadata=param(
        "float", lo=0.0, lo_open=True, when=_EXPANDED, doc="cloud std factor"))
    regen_ess: float = field(default=0.5, metadata=param(
        "float", lo=0.0, hi=1.0, when=_CONFIDENCE, doc="resample below this ESS / M"))
    bandwidth: float | None = field(default=None, metadata=param(
        "float", lo=0.0, hi=1.0, lo_open=True, hi_open=True, none_ok=True,
        doc="kernel bandwidth h; none = Silverman's rule"))
    name: str = "hybrid"

    def __post_init__(self) -> None:
        _check_switches(self.sampling, self.weights)
        if self.bandwidth is not None and not 0.0 < self.bandwidth < 1.0:
            raise ValueError("bandwidth must be in (0, 1)")

    def init(  # type: ignore[override]  # (a generator is required here)
        self, prior: Gaussian, space: Space, rng: np.random.Generator
    ) -> Ensemble:
        if type(space) is VectorSpace:
            LOCAL_KERNELS.get()  # numba's import and cache load here, not in the first step
        return super().init(prior, space, rng)

    def _propagate(self, E: Ensemble, model: Transition, t: float, dt: float,
                   u: Array | None, rng: Any) -> Ensemble:
        """:func:`propagate_members`; on a vector space with the compiled kernels the
        process noise is drawn and added in one compiled loop (``add_noise``: the same
        normals from ``rng``, in the same order; the sum equal to rounding)."""
        if type(model.space) is VectorSpace:
            nb = LOCAL_KERNELS.get()
            if nb:
                X = np.ascontiguousarray(model.f(E.X, t, dt, u), dtype=float)
                L = np.ascontiguousarray(chol(model.Q(t, dt, u)))
                return Ensemble(nb.add_noise(bitgen_pointers(rng), X, L, nb.tag(model.space.dim)),
                                model.space, E.w)
        return propagate_members(E, model, t, dt, u, rng)

    def update(self, E: Ensemble, z: Array, model: Measurement, rng: Any = None
               ) -> tuple[Ensemble, Innovation]:
        """Kernel (Gaussian-mixture) update with a local gain per member.

        The weighted members are read as a mixture sum_j w_j N(C_j, B): centres shrunk
        towards the mean, C_j = x + a (X_j - x), kernel B = h^2 P, a = sqrt(1 - h^2), so
        the mixture keeps the ensemble's mean and covariance. Each component gets its own
        Kalman update with the Jacobian H_j at its centre (exact for a component small
        enough that h is linear across it), and its confidence weight is its predictive
        likelihood: w_j <- w_j N(z; h(C_j), H_j B H_j^T + R). New members are drawn from
        the posterior mixture (systematic selection first if ESS < regen_ess M), as
        C_j+ + (I - K_j H_j) e_j + K_j v_j with e_j ~ N(0, B), v_j ~ N(0, R): exactly
        N(C_j+, B_j+) without a Cholesky factor per component. Everything is vectorised
        over the components; the m x m innovation covariances (m <= 2) are inverted in
        closed form on the whole stack.

        On a :class:`~uavest.geometry.spaces.VectorSpace` (any m) and numba installed
        (``uavest[fast]``; ``UAVEST_NUMBA=0`` switches it off) the same update runs as
        compiled loops over the members (:data:`LOCAL_KERNELS`, :meth:`_update_compiled`):
        the same model calls and random draws in the same order, equal to this numpy
        path to rounding.
        """
        if type(E.space) is VectorSpace:
            nb = LOCAL_KERNELS.get()
            if nb:
                return self._update_compiled(nb, E, z, model, rng)
        return self._update_numpy(E, z, model, rng)

    def _update_numpy(self, E: Ensemble, z: Array, model: Measurement, rng: Any = None
                      ) -> tuple[Ensemble, Innovation]:
        """:meth:`update` in numpy, vectorised over the members (every space, every m;
        the reference of the compiled path)."""
        space = E.space
        x, dX, w, P = ensemble_moments(E)
        M, n = dX.shape
        m = model.dim
        h = self.bandwidth or silverman_bandwidth(M, n)
        C = space.retract(x, math.sqrt(1.0 - h * h) * dX)
        B = (h * h) * P
        Hs, nu, dY, nubar = model.linearise_rows(C, z, w)  # (M, m, n), (M, m) x 2, (m,)
        if nu.shape[-1] != m:  # (einsum would broadcast a wrong-sized z silently)
            raise ValueError(f"measurement has {nu.shape[-1]} components, the model {m}")
        HB = _dot(Hs.reshape(M * m, n), B).reshape(M, m, n)  # H_j B, one product
        # S_j = H_j B H_j^T + R, its inverse and log-determinant (closed form, m <= 2)
        Si, logdet, Sw = _innovation_stack(HB, Hs, model.R, w)
        u = np.einsum("jab,jb->ja", Si, nu)  # S_j^-1 nu_j
        KT = Si @ HB  # the local gains K_j = B H_j^T S_j^-1, transposed (M, m, n)
        innov = innovation(nubar, _dot(dY.T * w, dY) + Sw)
        if self.weights == "confidence":
            loglik = -0.5 * (np.einsum("jm,jm->j", nu, u) + logdet)
            logw = np.log(np.maximum(w, 1e-300)) + loglik
            w = np.exp(logw - _max(logw))
            w /= _sum(w)
        resample = ess(w) < self.regen_ess * M
        if resample:
            idx = systematic_resample(w, rng)
            wn = None
        else:
            wn = w if self.weights == "confidence" else None
        # a draw from N(C_j + K_j nu_j, B_j+), B_j+ = B - K_j H_j B, without factoring
        # each B_j+: with e ~ N(0, B) and v ~ N(0, R), (I - K_j H_j) e + K_j v has exactly
        # that covariance (the Joseph form of the optimal gain)
        e = _dot(rng.standard_normal((M, n)), chol(B).T)
        v = _dot(rng.standard_normal((M, m)), chol(model.R).T)
        if resample or type(space) is not VectorSpace:  # the centres C_j + K_j nu_j
            Cp = space.retract(C, np.einsum("jm,jmn->jn", u, HB))
            if resample:  # the selected components' centres and gains
                Cp, Hs, KT = Cp[idx], Hs[idx], KT[idx]
            d = v - np.einsum("jmn,jn->jm", Hs, e)
        else:  # on a vector space K_j nu_j + K_j (v_j - H_j e_j) in one product
            Cp = C
            d = nu + v - np.einsum("jmn,jn->jm", Hs, e)
        X = space.retract(Cp, e + np.einsum("jm,jmn->jn", d, KT))
        return Ensemble(X, space, wn), innov

    def _update_compiled(self, nb: ModuleType, E: Ensemble, z: Array, model: Measurement,
                         rng: Any = None
                         ) -> tuple[Ensemble, Innovation]:
        """:meth:`update` on a vector space through the compiled kernels
        ``nb`` (:mod:`uavest.core._compiled_local`): the numpy path's model calls and
        ``rng`` draws, in the same order and shapes; the member loops compiled. Also
        leaves the moments of the prior and of the posterior ensemble in their memos
        (the estimate and the guard read them)."""
        space = E.space
        M, n = E.X.shape
        m = model.dim
        h = self.bandwidth or silverman_bandwidth(M, n)
        a = math.sqrt(1.0 - h * h)
        tg = nb.tag(n)
        # (the weights read-only whoever made them: one numba type, the self-check's)
        if E.moments is None:
            w = read_only(equal_weights(M) if E.w is None else E.w)
            x, dX, P, C = nb.prior_moments(E.X, w, a, tg)
            object.__setattr__(E, "moments", (x, dX, w, P))  # as ensemble_moments does
        else:
            x, dX, w, P = E.moments
            w = read_only(w)
            C = nb.centres(x, dX, a, tg)
        B = (h * h) * P
        Hs, nu, dY, nubar = model.linearise_rows(C, z, w)  # (M, m, n), (M, m) x 2, (m,)
        if nu.shape[-1] != m:  # (the kernels would read a wrong-sized z out of bounds)
            raise ValueError(f"measurement has {nu.shape[-1]} components, the model {m}")
        if Hs.shape != (M, m, n):
            raise ValueError(f"linearise_rows gave Jacobians {Hs.shape}, expected {(M, m, n)}")
        # (one array type per argument: a broadcast H_rows, an integer R... are copied,
        # so that numba compiles each kernel once; the radar's arrays pass as they are)
        Hs, nu = np.ascontiguousarray(Hs, dtype=float), np.ascontiguousarray(nu, dtype=float)
        R = np.ascontiguousarray(model.R, dtype=float)
        dY = np.ascontiguousarray(dY, dtype=float)
        conf = self.weights == "confidence"
        Lb, Lr = chol(B), chol(R)  # (before the draws: nothing random in either)
        X, xp, dXp, Pp, wu, Pyy, resample, bad = nb.local_update(
            bitgen_pointers(rng), C, Hs, B, R, nu, dY, w, conf, self.regen_ess, Lb, Lr, tg,
            nb.tag(m))
        if bad == 1:
            raise NumericalError("innovation covariance not positive definite")
        if bad:  # (NaN weights have a NaN ESS, which never resamples: not reached so far)
            raise NumericalError("resampling weights are not finite")
        innov = _innovation2(nubar, Pyy)
        wn = wu if conf and not resample else None
        wp = equal_weights(M) if wn is None else wn
        # Pp is symmetric by construction: the Gaussian ensemble_estimate would build
        return Ensemble(X, space, wn, moments=(xp, dXp, wp, Pp),
                        gaussian=Gaussian(xp, Pp)), innov


def _innovation2(nu: Array, S: Array) -> Innovation:
    """:func:`~uavest.core.states.innovation` with the NIS of a 2 x 2 ``S`` in closed form
    on floats (equal to the Cholesky solve to rounding); other sizes, and an ``S`` that
    is not positive definite or not finite (the Cholesky then raises), through it."""
    if S.shape[0] == 2:
        (a, b), (_, d) = S.tolist()
        det = a * d - b * b
        if a > 0.0 and det > 0.0 and math.isfinite(a + d + det):
            n0, n1 = nu.tolist()
            return Innovation(nu, S, (d * n0 * n0 - 2.0 * b * n0 * n1 + a * n1 * n1) / det)
    return innovation(nu, S)


def _local_cases(nb: ModuleType) -> Iterator[tuple[str, Any, Any]]:
    """The self-check (:mod:`uavest.compiled`): :meth:`HybridLocal._update_compiled`
    against :meth:`HybridLocal._update_numpy` (members, weights, innovation), and the
    process noise of :meth:`HybridLocal._propagate` against numpy's draws, on linear cases
    of the ``radar`` preset's shapes, so that the kernels a tracker runs are the ones
    compiled here (numba compiles per state and measurement size; left to the first scans,
    a fresh install's tracker compiled them there): n = 4, m = 2 (the 2-D radar's
    constant velocity): an equally weighted ensemble that resamples, then the same
    ensemble weighted that does not; n = 6, m = 3 (the 3-D radar: the Cholesky path);
    the last two twice (the second update on the posterior's moments:
    :func:`~uavest.core._compiled_local.centres`). Other sizes (m = 1...) compile at
    their first use; the unit tests compare them all."""
    from .interfaces import LinearMeasurement

    g = np.random.default_rng(7)
    f = HybridLocal(n_cloud=2)
    M = 15
    X4 = g.standard_normal((M, 4)) * [1.0, 2.0, 0.5, 1.5]
    X6 = g.standard_normal((M, 6)) * [1.0, 2.0, 0.5, 1.5, 0.7, 1.2]
    H3 = np.array([[1.0, 0.0, 0.5, 0.0, 0.0, 0.1], [0.2, 1.0, 0.0, 0.0, 0.3, 0.0],
                   [0.0, -0.3, 1.0, 0.1, 0.0, 0.0]])
    cases = (  # (X, H, R, weights, z, updates): the first resamples (ESS < M / 2)
        (X4, np.array([[1.0, 0.5, 0.0, 0.0], [0.0, 1.0, -1.0, 0.0]]), np.diag([0.01, 0.04]),
         None, np.array([1.5, -1.0]), 1),
        (X4, np.array([[0.5, -1.0, 2.0, 0.0], [0.0, 0.0, 0.3, 1.0]]), np.diag([25.0, 16.0]),
         g.dirichlet(np.full(M, 9.0)), np.array([1.0, 0.5]), 2),
        (X6, H3, np.array([[0.5, 0.1, 0.0], [0.1, 0.4, 0.05], [0.0, 0.05, 0.3]]), None,
         np.array([0.4, -1.2, 0.3]), 2),
    )
    for i, (X, H, R, w, z, updates) in enumerate(cases):
        model = LinearMeasurement(H, R)
        out = []
        for upd in (lambda *a: f._update_compiled(nb, *a), f._update_numpy):
            E1, rng = Ensemble(X.copy(), model.space, w), np.random.default_rng(3)
            for _ in range(updates):
                E1, inn = upd(E1, z, model, rng)
            out.append((E1.X, np.array([E1.w is None]),
                        equal_weights(M) if E1.w is None else E1.w, inn.S,
                        np.array([inn.nis])))
        for label, a, b in zip(("X", "resampled", "w", "S", "nis"), *out, strict=True):
            yield f"case {i} {label}", a, b
    for X in (X4, X6):  # the process noise: L z_j, z_j numpy's normals in its order
        n = X.shape[1]
        L = np.tril(g.standard_normal((n, n))) + 3.0 * np.eye(n)
        yield (f"process noise n = {n}", nb.add_noise(
            bitgen_pointers(np.random.default_rng(4)), X, L, nb.tag(n)),
               X + np.random.default_rng(4).standard_normal(X.shape) @ L.T)


#: The compiled kernels of :meth:`HybridLocal.update` and its process noise on vector
#: spaces (:mod:`uavest.core._compiled_local`)
LOCAL_KERNELS = register("local", "uavest.core._compiled_local",
                         "numba kernels of the local hybrid", _local_cases, rtol=1e-10,
                         atol=1e-12)


@lru_cache(maxsize=64)
def silverman_bandwidth(M: int, n: int) -> float:
    """Silverman's rule for a Gaussian kernel, (4 / (M (n + 2)))^(1 / (n + 4)), as a
    fraction of the ensemble's standard deviation (clipped to [0.05, 0.95])."""
    return float(np.clip((4.0 / (M * (n + 2))) ** (1.0 / (n + 4)), 0.05, 0.95))


def _innovation_stack(HB: Array, Hs: Array, R: Array, w: Array
                      ) -> tuple[Array, Array, Array]:
    """Inverses (M, m, m) and log-determinants (M,) of S_j = H_j B H_j^T + R given
    ``HB`` = H_j B and ``Hs`` = H_j, and the weighted sum sum_j w_j S_j (m, m).

    For m = 1 and m = 2 in closed form from the entries (elementwise over the members;
    numpy's batched matrix routines call one small kernel per member); otherwise batched
    ``matmul`` / ``inv`` / ``slogdet``. A non-positive determinant raises
    :class:`~uavest.core.linalg.NumericalError` (for the guard)."""
    M, m, _ = Hs.shape
    if m <= 2:
        diag = np.einsum("jmn,jmn->jm", HB, Hs)
        diag += R.diagonal()  # (M, m): S_j's diagonal
        a = diag[:, 0]
        if m == 1:
            if not np.all(a > 0.0):
                raise NumericalError("innovation covariance not positive definite")
            return (1.0 / a)[:, None, None], np.log(a), np.array([[_dot(w, a)]])
        d = diag[:, 1]
        b = np.einsum("jn,jn->j", HB[:, 0], Hs[:, 1])
        b += R[0, 1]
        det = a * d - b * b
        if not np.all(det > 0.0):
            raise NumericalError("innovation covariance not positive definite")
        i = 1.0 / det
        Si = np.empty((M, 2, 2))
        Si[:, 0, 0] = d * i
        Si[:, 1, 1] = a * i
        Si[:, 0, 1] = Si[:, 1, 0] = -b * i
        (sa, sd), sb = _dot(w, diag).tolist(), float(_dot(w, b))
        return Si, np.log(det), np.array([[sa, sb], [sb, sd]])
    S = HB @ Hs.transpose(0, 2, 1) + R
    sign, logdet = np.linalg.slogdet(S)
    if not np.all(sign > 0):
        raise NumericalError("innovation covariance not positive definite")
    return np.linalg.inv(S), logdet, np.einsum("j,jab->ab", w, S)
