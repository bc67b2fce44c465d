"""Filter core: model-agnostic, generic over the state space (``retract``/``local``).

Every filter is a small frozen configuration object with pure methods::

    s = f.init(prior: Gaussian, space, rng)            # filter state
    s = f.predict(s, transition, t, dt, u, rng)        # to time t (end of step)
    s, innov = f.update(s, z, measurement, rng)        # innov: Innovation(nu, S, nis)
    g = f.estimate(s)                                  # Gaussian(x, P)

Filter states are immutable (``Gaussian``, ``SqrtGaussian``, ``Ensemble``...). Random
draws only through the ``numpy.random.Generator`` passed in.
"""

from ..geometry.spaces import Space, VectorSpace, manifold_mean
from .adaptive import SageHusa
from .base import Ensemble, Innovation, ensemble_estimate
from .ensemble import ETKF, EnKF
from .gaussian import Gaussian
from .guard import Guarded, GuardState
from .hybrid import Hybrid, HybridLiteral
from .kalman import EKF, KF
from .model import LinearMeasurement, LinearTransition, Measurement, Transition, fd_jacobian
from .particle import PF
from .registry import FILTER_NAMES, make_filter, parse_filter_spec
from .unscented import SRUKF, UKF, SqrtGaussian

__all__ = [
    "EKF", "ETKF", "EnKF", "Ensemble", "FILTER_NAMES", "Gaussian", "GuardState", "Guarded",
    "Hybrid", "HybridLiteral", "Innovation", "KF", "LinearMeasurement", "LinearTransition",
    "Measurement", "PF", "SRUKF", "SageHusa", "Space", "SqrtGaussian", "Transition", "UKF",
    "VectorSpace", "ensemble_estimate", "fd_jacobian", "make_filter", "manifold_mean",
    "parse_filter_spec",
]
