"""Loading an optional module of numba kernels (``uavest[fast]``), the same way for every
layer that has one: the attitude manifold (:mod:`uavest.geometry._compiled`), the UKF
(:mod:`uavest.core._compiled_ut`), the hybrid's shift and local updates
(:mod:`uavest.core._compiled_shift`, :mod:`uavest.core._compiled_local`).

Each caller keeps its own once-per-process cache (a module global its dispatch reads,
so tests can force a path) and asks :func:`load_kernels` once."""

from __future__ import annotations

import ctypes
import importlib
import logging
import os
from collections.abc import Callable
from types import ModuleType

import numpy as np

__all__ = ["bitgen_pointers", "load_kernels"]


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


#: id(bit generator) -> (the bit generator, its pointers): a strong reference keeps the
#: id from being reused while the entry lives; bounded (the oldest entries go first).
_POINTERS: dict[int, tuple[object, object]] = {}
_POINTERS_MAX = 64


def bitgen_pointers(rng):
    """The addresses a compiled kernel needs to draw from the ``numpy.random.Generator``
    ``rng`` itself (numba's own Generator support does the same at every call, for
    ~8 us): an int array (4,) of the bit generator's state address and its
    ``next_uint64``, ``next_uint32`` and ``next_double`` functions (numpy's documented
    ``BitGenerator.ctypes`` interface). Remembered per bit generator; valid while it
    lives (the caller holds ``rng`` during the kernel call)."""
    bg = rng.bit_generator
    hit = _POINTERS.get(id(bg))
    if hit is not None and hit[0] is bg:
        return hit[1]
    c = bg.ctypes
    p = np.array([c.state_address]
                 + [ctypes.cast(f, ctypes.c_void_p).value
                    for f in (c.next_uint64, c.next_uint32, c.next_double)], dtype=np.intp)
    p.flags.writeable = False
    while len(_POINTERS) >= _POINTERS_MAX:
        del _POINTERS[next(iter(_POINTERS))]
    _POINTERS[id(bg)] = (bg, p)
    return p
