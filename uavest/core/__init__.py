"""Filter core: model-agnostic, generic over the state space (``retract``/``local``).

Every filter is a small frozen configuration object with pure methods (the contract
:class:`Filter`, :mod:`uavest.core.contract`)::

    s = f.init(prior: Gaussian, space, rng)            # filter state
    s = f.predict(s, transition, t, dt, u, rng)        # to time t (end of step)
    s, innov = f.update(s, z, measurement, rng)        # innov: Innovation(nu, S, nis)
    g = f.estimate(s)                                  # Gaussian(x, P)
    gp, C = f.rts_terms(s0, s1, transition, t, dt, u)  # RTS smoothing terms
    s = f.mix(states, w, space, rng)                   # mixture (JPDA)

Filters are named by validated specs (:mod:`uavest.core.spec`,
:func:`uavest.core.registry.parse_spec`, :func:`uavest.core.registry.build`).

Filter states are immutable (``Gaussian``, ``SqrtGaussian``, ``Ensemble``...). Random
draws only through the ``numpy.random.Generator`` passed in.
"""

from ..geometry.spaces import Space, VectorSpace, manifold_mean
from .adaptive import SageHusa
from .contract import EnsembleFilter, Filter, FilterBase, ensemble_cross
from .ensemble import ETKF, EnKF
from .gaussian import Gaussian
from .guard import Guarded, GuardState
from .hybrid import HybridLiteral, HybridLocal, HybridShift
from .interfaces import LinearMeasurement, LinearTransition, Measurement, Transition, fd_jacobian
from .kalman import EKF, KF
from .linalg import NotPositiveDefinite, NumericalError
from .particle import PF
from .registry import (
    FILTER_NAMES,
    build,
    make_filter,
    make_filter_in_context,
    parse_filter_list,
    parse_filter_spec,
    parse_spec,
    split_filter_list,
)
from .spec import FilterSpec, SpecError
from .states import Ensemble, Innovation, ensemble_estimate
from .unscented import CKF, SRUKF, UKF, SqrtGaussian

__all__ = [
    "CKF", "EKF", "ETKF", "EnKF", "Ensemble", "EnsembleFilter", "FILTER_NAMES", "Filter",
    "FilterBase", "FilterSpec", "Gaussian", "GuardState", "Guarded", "HybridShift",
    "HybridLiteral", "HybridLocal", "Innovation", "KF", "LinearMeasurement",
    "LinearTransition", "Measurement", "NotPositiveDefinite", "NumericalError", "PF",
    "SRUKF", "SageHusa", "Space", "SpecError", "SqrtGaussian", "Transition", "UKF",
    "VectorSpace", "build", "ensemble_cross", "ensemble_estimate", "fd_jacobian",
    "make_filter", "make_filter_in_context", "manifold_mean", "parse_filter_list",
    "parse_filter_spec", "parse_spec", "split_filter_list",
]
