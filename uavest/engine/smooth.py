"""Forward-backward (Rauch-Tung-Striebel) smoothing on a manifold state space.

One backward recursion serves every filter; the filters differ only in how the
cross-covariance ``C_k = Cov(e_{k-1}, e_k)`` between consecutive tangent errors is
obtained during the forward pass:

* EKF (RTS):            C_k = P_{k-1|k-1} F_k^T     (F_k the tangent Jacobian of f)
* UKF (unscented RTS):  C_k = sum_j Wc_j D_j dY_j^T (sigma offsets D, propagated
                        deviations dY; :meth:`uavest.core.UKF.predict_cross`)
* hybrid (ensemble RTS): C_k = weighted cross-covariance of the filtered members and the
                        same members after propagation (members persist through a
                        predict unless regenerated; then the sigma-point C is used).

Backward pass, k = N-1 .. 0 (G the smoother gain):
    G   = C_{k+1} P_{k+1|k}^-1                       (solve, not inverse)
    x_s = retract(x_{k|k}, G local(x_{k+1|k}, x_{k+1|N}))
    P_s = P_{k|k} + G (P_{k+1|N} - P_{k+1|k}) G^T
Tangent spaces at different base points are identified (no parallel transport), as
usual for multiplicative-error smoothers on SO(3) at these step sizes.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..core.linalg import symmetrize
from ..geometry.spaces import Space

Array = np.ndarray

__all__ = ["rts_backward", "smooth_records"]


class KeptRecords(Protocol):
    """What :func:`smooth_records` reads of a :class:`uavest.sinks.base.Collector`: the
    start ``(t0, x0, P0)`` and the stacked record fields of each label."""

    starts: dict[str, tuple[float, Array, Array]]

    def arrays(self, label: str) -> dict[str, Array]: ...


def rts_backward(
    space: Space, x_f: Array, P_f: Array, x_p: Array, P_p: Array, C: Array
) -> tuple[Array, Array]:
    """Smoothed states/covariances from a forward pass.

    ``x_f`` (N+1, size) / ``P_f`` (N+1, n, n): filtered estimates at steps 0..N;
    ``x_p``, ``P_p`` (N+1, ...): predictions to step k from k-1 (row 0 unused);
    ``C`` (N+1, n, n): cross-covariance Cov(e_{k-1}, e_k) (row 0 unused).
    Returns ``(x_s, P_s)`` shaped like ``x_f``, ``P_f``.
    """
    x_s = x_f.copy()
    P_s = P_f.copy()
    N = x_f.shape[0] - 1
    for k in range(N - 1, -1, -1):
        try:
            G = np.linalg.solve(P_p[k + 1], C[k + 1].T).T
        except np.linalg.LinAlgError:
            continue  # keep the filtered estimate at this step
        d = space.local(x_p[k + 1], x_s[k + 1])
        x_s[k] = space.retract(x_f[k], G @ d)
        P_s[k] = symmetrize(P_f[k] + G @ (P_s[k + 1] - P_p[k + 1]) @ G.T)
    return x_s, P_s


def smooth_records(coll: KeptRecords, label: str, space: Space) -> tuple[Array, Array, Array]:
    """RTS-smoothed run of ``label`` from a :class:`uavest.sinks.base.Collector` that kept
    a runner's records made with ``smooth=True``: step times (K,), smoothed means
    (K, size) and covariances (K, n, n) (the start, row 0 of the recursion, left out)."""
    a = coll.arrays(label)
    _, x0, P0 = coll.starts[label]
    x = np.vstack([x0, a["x"]])
    P = np.concatenate([P0[None], a["P"]])
    xp = np.vstack([x0, a["x_pred"]])
    Pp = np.concatenate([P0[None], a["P_pred"]])
    C = np.concatenate([np.zeros_like(P0)[None], a["C"]])
    xs, Ps = rts_backward(space, x, P, xp, Pp, C)
    return a["t"], xs[1:], Ps[1:]
