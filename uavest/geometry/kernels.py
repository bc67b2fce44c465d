"""Loading an optional module of numba kernels (``uavest[fast]``), the same way for every
layer that has one: the attitude manifold (:mod:`uavest.geometry._compiled`), the UKF
(:mod:`uavest.core._compiled_ut`), the hybrid's shift and local updates
(:mod:`uavest.core._compiled_shift`, :mod:`uavest.core._compiled_local`).

Each caller keeps its own once-per-process cache (a module global its dispatch reads,
so tests can force a path) and asks :func:`load_kernels` once."""

from __future__ import annotations

import importlib
import logging
import os
from collections.abc import Callable
from types import ModuleType

__all__ = ["load_kernels"]


def load_kernels(module: str, what: str, agrees: Callable[[ModuleType], bool],
                 logger: str) -> ModuleType | bool:
    """The kernels ``module`` if they can be used here, else False (the caller's numpy
    path is used): numba must import, ``UAVEST_NUMBA`` must not be ``0``, the module must
    import and compile (the first use some seconds, then numba's on-disk cache) and
    ``agrees(module)`` must be true (the kernels against the numpy path on a small case).
    A failure is logged on ``logger`` (``what`` names the kernels) and gives False."""
    if os.environ.get("UAVEST_NUMBA", "1") == "0":
        return False
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    log = logging.getLogger(logger)
    try:
        nb = importlib.import_module(module)
        log.info("%s: loading (the first use compiles them, then cached)", what)
        ok = agrees(nb)
    except Exception as e:  # noqa: BLE001 - any failure of an optional accelerator
        log.warning("%s unavailable (%s: %s); using numpy", what, type(e).__name__, e)
        return False
    if not ok:
        log.warning("%s disagree with the numpy path; using numpy", what)
        return False
    return nb
