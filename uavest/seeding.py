"""The one seeding scheme: every random draw of a run comes from (seed, trial, stream).

``rng(seed, trial, stream)`` is ``numpy.random.default_rng(SeedSequence([seed, trial,
crc32(stream)]))``. Streams are named by what they draw: ``"truth"`` (a trial's true
trajectory and measurement noise), ``"detections"``, ``"x0"`` (a trial's filter start),
``"filter:<label>"`` (one filter's own randomness, e.g. ensemble members), ``"imu"``,
``"radar"``... So

* trial r is the same whatever the number of trials (``--runs 2`` and ``--runs 4`` share
  trials 0 and 1), and any subset of trials can run in another process or on another
  machine and give the same numbers;
* a filter's numbers do not depend on which other filters run beside it;
* adding a stream changes no other stream.

A replay or a live run is trial 0 of its ``--seed``.
"""

from __future__ import annotations

import zlib

import numpy as np

from .errors import InputError

__all__ = ["filter_stream", "rng"]


def rng(seed: int, trial: int, stream: str) -> np.random.Generator:
    """The generator of ``stream`` in ``trial`` of a run seeded with ``seed``."""
    if seed < 0 or trial < 0:
        raise InputError(f"seed and trial must be >= 0, got seed={seed}, trial={trial}")
    return np.random.default_rng(
        np.random.SeedSequence([int(seed), int(trial), zlib.crc32(stream.encode())])
    )


def filter_stream(label: str) -> str:
    """Stream name of the filter written ``label`` (its spec as the user wrote it)."""
    return f"filter:{label}"
