"""Values to message fields: times, JSON text, NaN-safe floats, colours, row arrays,
and the recorder's packed triangles read back (:func:`b64_floats`, :func:`triu_to_full`)."""

from __future__ import annotations

import base64
import json
import math

import numpy as np
from foxglove.messages import Color, Timestamp

Array = np.ndarray

__all__ = ["b64_floats", "triu_to_full"]


def _ns(t: float) -> int:
    return max(int(round(t * 1e9)), 0)



def _ts(t: float):

    ns = _ns(t)
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)



def _ns_rows(T: Array) -> list[int]:
    """:func:`_ns` of an array of times (s) as a list of ints (ns)."""
    return np.maximum(np.rint(T * 1e9), 0.0).astype(np.int64).tolist()



def _n(v) -> str:
    """A float as JSON text: %.17g (exact round trip), null for None/NaN/inf."""
    if v is None or not math.isfinite(v):
        return "null"
    return "%.17g" % v  # noqa: UP031



def _g(v: float) -> str:
    """A derived display quantity (Euler angles, 3-sigma, errors, NEES, wall time) as JSON
    text: 10 significant digits (%.10g, about 4x cheaper to format than the exact
    %.17g), null for NaN/inf."""
    return "%.10g" % v if v - v == 0.0 else "null"  # noqa: UP031



_QUOTED: dict[str, str] = {}



def _q(s: str) -> str:
    """A string as JSON text (cached: sources, labels, kinds repeat)."""
    out = _QUOTED.get(s)
    if out is None:
        out = json.dumps(s)
        if len(_QUOTED) < 10_000:
            _QUOTED[s] = out
    return out



def _fin(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None



def _clean(v):
    """JSON-safe floats (NaN/inf -> None)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, list):
        return [_clean(x) for x in v]
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    return v



def _floats(a) -> list:
    lst = np.asarray(a, float).ravel().tolist()
    return [x if math.isfinite(x) else None for x in lst]



def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, np.generic):
        return o.item()
    if o is None or isinstance(o, bool | int | float | str):
        return o
    return str(o)



def _rgba(hex_colour: str, alpha: float = 1.0):

    h = hex_colour.lstrip("#")
    return Color(r=int(h[0:2], 16) / 255, g=int(h[2:4], 16) / 255, b=int(h[4:6], 16) / 255,
                 a=alpha)



def _rows(a) -> Array:
    """``a`` as (N, m) rows; an empty scan (``[]``, (0,) or (0, m)) gives (0, m) (m = 0
    when unknown) instead of the ``reshape(0, -1)`` error numpy raises for size 0."""
    a = np.asarray(a, float)
    if a.size == 0:
        return a.reshape(0, a.shape[-1] if a.ndim > 1 else 0)
    return a.reshape(len(a), -1)



def _stack3(vs: list) -> Array:
    """Rows of 3-vectors (a list of (3,) arrays) as (N, 3) float."""
    return np.array(vs, float).reshape(-1, 3)



_TRIU: dict[int, tuple] = {}



def _triu(n: int) -> tuple:
    """``numpy.triu_indices(n)`` (cached)."""
    if n not in _TRIU:
        _TRIU[n] = np.triu_indices(n)
    return _TRIU[n]



def b64_floats(s: str | list[str]) -> Array:
    """float64 array(s) from the recorder's base64 fields (a list gives a stacked array)."""
    if isinstance(s, str):
        return np.frombuffer(base64.b64decode(s), "<f8")
    if len(s) == 0:
        return np.empty((0, 0))
    return np.stack([np.frombuffer(base64.b64decode(x), "<f8") for x in s])



def triu_to_full(v, n: int) -> Array:
    """Symmetric (..., n, n) matrices from their upper triangles (..., n (n + 1) / 2) as
    written by the recorder (``P_triu`` of ``uavest.AttitudeEstimate``; ``P_triu_b64`` of
    channel set 1, decoded with :func:`b64_floats`)."""
    v = np.asarray(v, float)
    out = np.empty(v.shape[:-1] + (n, n))
    i, j = np.triu_indices(n)
    out[..., i, j] = v
    out[..., j, i] = v
    return out

