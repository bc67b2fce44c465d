"""Systematic resampling (Kitagawa; Douc, Cappe and Moulines, "Comparison of resampling
schemes for particle filtering"): shared by the particle filter (:mod:`.particle`), the
hybrid filter and the contract's ensemble pooling (:mod:`.contract`), below all three."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from .linalg import NumericalError

Array = np.ndarray


def systematic_resample(w: Array, rng: np.random.Generator, n: int | None = None) -> Array:
    """Indices (n,) drawn by systematic resampling from normalised weights ``w`` (N,);
    n defaults to N. Raises :class:`NumericalError` for non-finite weights."""
    N = w.shape[0] if n is None else n
    cs = w.cumsum()
    if not math.isfinite(cs[-1]):
        raise NumericalError("resampling weights are not finite")
    cs[-1] = 1.0
    return cs.searchsorted((rng.random() + _arange(N)) * (1.0 / N))


@lru_cache(maxsize=32)
def _arange(N: int) -> Array:
    """0, 1, ..., N-1 as floats (what ``u + np.arange(N)`` adds), shared and read-only."""
    a = np.arange(N, dtype=float)
    a.flags.writeable = False
    return a

