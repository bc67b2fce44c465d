"""Compiled (numba) helpers shared by the kernel modules (``uavest/*/_compiled_*.py``):
one Cholesky factor, the plain factor with its 1 x 1 shortcut, the lower-triangular
solve, an angle wrapped to [-pi, pi), and numba's bit-generator struct from
:func:`uavest.compiled.bitgen_pointers`.

Importing this module imports numba and compiles nothing (each helper compiles into the
kernels that call it). numba's on-disk cache of a kernel does not notice an edit here:
after changing a helper, remove the ``__pycache__`` ``*.nbi`` / ``*.nbc`` files of the
kernel modules (or set ``NUMBA_CACHE_DIR`` to a fresh directory); the self-check of
:mod:`uavest.compiled` still compares every kernel with its numpy reference at load.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit, types
from numba.core import cgutils
from numba.core.extending import intrinsic

__all__ = ["bitgen", "chol_into", "chol_n", "factor", "solve_lower", "wrap_pi"]

Array = np.ndarray


@njit(cache=True)
def chol_into(P: Array, L: Array) -> bool:  # pragma: no cover - compiled
    """:func:`chol_n` of the whole of ``P`` (n, n) (n = ``P.shape[0]``)."""
    return chol_n(P, L, P.shape[0])


@njit(cache=True, inline="always")
def chol_n(P: Array, L: Array, n: int) -> bool:  # pragma: no cover - compiled
    """Lower Cholesky factor of the lower triangle of ``P`` (n, n) into ``L`` (its upper
    triangle zeroed); False if a pivot is not finite and positive. The caller then takes
    the numpy path, which decides what a covariance with no plain factor means; ``L``
    is then meaningless but safe to use: each failed pivot is set to 1 and the factor
    completed, so every diagonal entry of ``L`` is in (0, inf) and a triangular solve or
    inverse that follows cannot divide by zero (a numba ``ZeroDivisionError``) before
    the caller reads the status (``_compiled_local.local_gains`` inverts it unread).

    A pivot must be in (0, inf): ``not s > 0`` alone would let an infinite pivot through
    and return a factor of infinities and NaNs (t / inf, inf - inf) as a success, i.e.
    NaN in a filter's state; with this test a factor returned with True is finite.

    The leading ``n`` x ``n`` block is factored; inlined into its caller (numba IR), so
    that a kernel whose ``n`` is a compile-time constant (``_compiled_local``'s m) gets
    the loops unrolled as a hand-written copy would."""
    ok = True
    for j in range(n):
        s = P[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not 0.0 < s < math.inf:
            ok = False
            s = 1.0
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = P[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
        for i in range(j):
            L[i, j] = 0.0
    return ok


@njit(cache=True)
def factor(S: Array) -> tuple[bool, Array]:  # pragma: no cover - compiled
    """(ok, L): the plain lower factor of ``S`` (m, m) (no jitter: the numpy path decides
    what a failed one means); 1 x 1: the square root (LAPACK's factor)."""
    m = S.shape[0]
    L = np.zeros((m, m))
    if m == 1:
        s = S[0, 0]
        if 0.0 < s < math.inf:
            L[0, 0] = math.sqrt(s)
            return True, L
        return False, L
    return chol_into(S, L), L


@njit(cache=True)
def solve_lower(L: Array, b: Array) -> Array:  # pragma: no cover - compiled
    """L^-1 b for a lower-triangular L (m, m) and b (m,); 1 x 1: b times 1 / L_00 (as
    LAPACK's triangular solve)."""
    m = b.shape[0]
    y = np.empty(m)
    for i in range(m):
        t = b[i]
        for k in range(i):
            t -= L[i, k] * y[k]
        y[i] = t * (1.0 / L[i, i]) if m == 1 else t / L[i, i]
    return y


_TWO_PI = 2.0 * math.pi


@njit(cache=True, error_model="numpy")
def wrap_pi(a: float) -> float:  # pragma: no cover - compiled
    """``uavest.geometry.rotation.wrap_pi`` of one angle (rad): (a + pi) mod 2 pi - pi,
    with the floored float modulo of Python and numpy (the sign of the divisor)."""
    res: float = (a + math.pi) % _TWO_PI - math.pi
    return res


_BITGEN = types.NumPyRandomBitGeneratorType("bit_generator")


@intrinsic
def bitgen(tyctx: Any, state: Any, next_u64: Any, next_u32: Any, next_dbl: Any
           ) -> tuple[Any, Callable[..., Any]]:  # pragma: no cover - compiled
    """numba's bit-generator struct (what it unboxes from a ``Generator`` argument) from
    the addresses of :func:`uavest.compiled.bitgen_pointers`, so that numba's own
    ``random_standard_normal`` / ``next_double`` (numpy's algorithms: numpy's values, in
    numpy's order) draw from the caller's generator without the ~8 us that numba spends
    per call unboxing a ``Generator`` through ctypes."""
    sig = _BITGEN(types.intp, types.intp, types.intp, types.intp)

    def codegen(cgctx: Any, builder: Any, sig: Any, args: Any) -> Any:
        st = cgutils.create_struct_proxy(_BITGEN)(cgctx, builder)  # type: ignore[no-untyped-call]
        st.state_address = args[0]
        st.state = args[0]
        st.fnptr_next_uint64 = args[1]
        st.fnptr_next_uint32 = args[2]
        st.fnptr_next_double = args[3]
        st.bit_generator = cgctx.get_constant(types.uintp, 0)
        st.parent = cgutils.get_null_value(  # type: ignore[no-untyped-call]
            cgctx.get_value_type(types.pyobject))
        return st._getvalue()

    return sig, codegen
