"""The optional compiled (numba) kernels: one registry, one self-check, one fallback.

Where numpy's per-call floor dominates a hot loop, a module of numba kernels
(``uavest[fast]``) does the same formulas; the numpy form stays in the algorithm file as
the reference and the fallback (CONTRIBUTING.md, "The kernel pattern"). Each such module
is registered here once, by the algorithm file that uses it::

    UT_KERNELS = register("ut", "uavest.core._compiled_ut", "numba unscented kernels",
                          cases=_ut_cases, rtol=1e-12, atol=1e-12)
    ...
    nb = UT_KERNELS.get()          # the one-line dispatch: the module, or None (numpy)

and decided once per process, at its first :meth:`Kernels.get`: numba must import,
``UAVEST_NUMBA`` must not be ``0``, the module must import and compile (the first use
some seconds, then numba's on-disk cache), and the self-check must pass: every
``(label, compiled, reference)`` triple that ``cases(module)`` yields (the kernels and the
numpy reference on small cases) must have the same shape and agree to ``rtol`` / ``atol``
(:func:`numpy.allclose`; a NaN never agrees). Any failure gives the numpy path and one
warning on the algorithm's logger naming the kernels and the reason.

``REGISTRY`` lists every registered module; :func:`status` says which ones are in use
(``None``: not decided yet). Tests force a path with ``monkeypatch.setattr(KERNELS,
"loaded", False)`` (numpy) or a module, and ``None`` to decide again.

This package imports neither numba nor any kernel module; :mod:`uavest.compiled.helpers`
holds the compiled helpers the kernel modules share (one Cholesky factor, the triangular
solve, the bit-generator access).
"""

from __future__ import annotations

import ctypes
import importlib
import logging
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from types import ModuleType
from typing import Any, Literal

import numpy as np

__all__ = ["REGISTRY", "Kernels", "bitgen_pointers", "load_seconds", "read_only", "register",
           "status"]

#: (label, compiled result, numpy reference result) of one self-check comparison
Case = tuple[str, Any, Any]


@dataclass(eq=False)
class Kernels:
    """One optional module of compiled kernels and its self-check (see the module doc).

    ``name``: registry key; ``module``: the kernel module's import path; ``what``: its
    name in log lines; ``cases(module)``: the self-check's comparisons; ``rtol`` /
    ``atol``: their tolerance; ``logger``: where the one warning goes (the algorithm's
    package). ``loaded``: the module once accepted, False when refused (numpy), None
    before the first :meth:`get`; ``load_s``: how long that first :meth:`get` took (s:
    numba's import, the cache load or compilation, the self-check; summed over the
    decisions when a test makes it decide again)."""

    name: str
    module: str
    what: str
    cases: Callable[[ModuleType], Iterable[Case]]
    rtol: float
    atol: float
    logger: str
    loaded: ModuleType | Literal[False] | None = None
    load_s: float = 0.0

    def get(self) -> ModuleType | None:
        """The kernel module if it is used in this process, else None (take the numpy
        reference); decided at the first call."""
        m = self.loaded
        if m is None:
            t0 = time.perf_counter()
            # while deciding, a nested get (a self-check reference that reaches a
            # dispatching function) takes numpy: the reference is the numpy path
            self.loaded = False
            try:
                m = self.loaded = _load(self)
            finally:
                if self.loaded is False and m is None:  # (interrupted: decide again)
                    self.loaded = None
                self.load_s += time.perf_counter() - t0
        return m or None


#: name -> the registered kernel modules, in registration order
REGISTRY: dict[str, Kernels] = {}


def register(name: str, module: str, what: str, cases: Callable[[ModuleType], Iterable[Case]],
             *, rtol: float, atol: float, logger: str | None = None) -> Kernels:
    """Register the kernel ``module`` (nothing is imported or compiled here) and return
    its handle; ``logger`` defaults to the module's package (``uavest.core``...)."""
    if name in REGISTRY:
        raise ValueError(f"compiled kernels {name!r} registered twice")
    k = Kernels(name, module, what, cases, rtol, atol, logger or module.rpartition(".")[0])
    REGISTRY[name] = k
    return k


def status() -> dict[str, bool | None]:
    """{name: True (compiled) / False (numpy) / None (not decided yet)} of every
    registered kernel module."""
    return {n: None if k.loaded is None else bool(k.loaded) for n, k in REGISTRY.items()}


def load_seconds() -> float:
    """The seconds this process has spent in the kernel modules' first :meth:`Kernels.get`
    so far (once per process: a replay's speed does not count them, as it does not count
    the imports)."""
    return sum(k.load_s for k in REGISTRY.values())


def _load(k: Kernels) -> ModuleType | Literal[False]:
    """The self-check harness: the module if it can be used here, else False (one
    warning with the reason, unless numba is absent or switched off)."""
    if os.environ.get("UAVEST_NUMBA", "1") == "0":
        return False
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    log = logging.getLogger(k.logger)
    try:
        nb = importlib.import_module(k.module)
        log.info("%s: loading (the first use compiles them, then cached)", k.what)
        bad = _disagreement(k, nb)
    except Exception as e:  # noqa: BLE001 - any failure of an optional accelerator
        log.warning("%s unavailable (%s: %s); using numpy", k.what, type(e).__name__, e)
        return False
    if bad is not None:
        log.warning("%s disagree with the numpy path (%s); using numpy", k.what, bad)
        return False
    return nb


def _disagreement(k: Kernels, nb: ModuleType) -> str | None:
    """The first comparison of ``k.cases(nb)`` that fails, in words, or None."""
    for label, got, want in k.cases(nb):
        if got is None:
            return f"{label}: no result"
        a, b = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
        if a.shape != b.shape:
            return f"{label}: shape {a.shape} against {b.shape}"
        if not np.allclose(a, b, rtol=k.rtol, atol=k.atol):
            with np.errstate(invalid="ignore"):
                return f"{label}: max difference {np.max(np.abs(a - b)):.3g}"
    return None


def read_only(a: Any) -> np.ndarray:
    """``a`` as a read-only, C-contiguous float64 array (a view; a copy only if it is not
    float64 C already), for a kernel argument the kernel only reads. numba compiles a
    kernel once per argument type, and an array's type includes its writeable flag: one
    flag for every caller is one compilation, the one the self-check makes (without it a
    run's read-only weights compiled the radar's and the local hybrid's kernels again at
    the first scans)."""
    v = np.ascontiguousarray(a, dtype=float).view()
    v.flags.writeable = False
    return v


#: id(bit generator) -> (the bit generator, its pointers): a strong reference keeps the
#: id from being reused while the entry lives; bounded (the oldest entries go first).
_POINTERS: dict[int, tuple[object, np.ndarray]] = {}
_POINTERS_MAX = 64


def bitgen_pointers(rng: np.random.Generator) -> np.ndarray:
    """The addresses a compiled kernel needs to draw from the ``numpy.random.Generator``
    ``rng`` itself (numba's own Generator support does the same at every call, for
    ~8 us): an int array (4,) of the bit generator's state address and its
    ``next_uint64``, ``next_uint32`` and ``next_double`` functions (numpy's documented
    ``BitGenerator.ctypes`` interface; :func:`uavest.compiled.helpers.bitgen` reads
    them). Remembered per bit generator; valid while it lives (the caller holds ``rng``
    during the kernel call)."""
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
