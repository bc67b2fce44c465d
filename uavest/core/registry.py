"""Filters by name, with parameters: ``make_filter("ukf(alpha=0.001)")``.

Names: kf, ekf, ukf, ckf (cubature UKF), srukf, enkf, etkf, hybrid, hybrid_literal, pf.
A ``_sh`` suffix wraps the filter in the Sage-Husa adaptive-noise estimator
(e.g. ``ukf_sh``, ``hybrid_sh(b=0.97)``).
"""

from __future__ import annotations

import re

from .adaptive import SageHusa
from .ensemble import ETKF, EnKF
from .hybrid import Hybrid, HybridLiteral
from .kalman import EKF, KF
from .particle import PF
from .unscented import SRUKF, UKF

_BASE = {
    "kf": KF,
    "ekf": EKF,
    "ukf": UKF,
    "ckf": lambda **k: UKF(points="cubature", name="ckf", **k),
    "srukf": SRUKF,
    "enkf": EnKF,
    "etkf": ETKF,
    "hybrid": Hybrid,
    "hybrid_literal": HybridLiteral,
    "pf": PF,
}
FILTER_NAMES = tuple(_BASE) + ("<name>_sh",)

_SPEC = re.compile(r"^\s*([a-z_][a-z0-9_]*)\s*(?:\((.*)\))?\s*$")


def _value(v: str):
    v = v.strip()
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    if v.lower() in ("none", "null"):
        return None
    if v.lower() in ("true", "false"):
        return v.lower() == "true"
    return v.strip("'\"")


def parse_filter_spec(spec: str) -> tuple[str, dict]:
    """``"ukf(alpha=0.001, kappa=0)"`` -> ("ukf", {"alpha": 0.001, "kappa": 0})."""
    m = _SPEC.match(spec)
    if not m:
        raise ValueError(f"bad filter spec {spec!r}: expected name or name(key=value, ...)")
    name, args = m.group(1), m.group(2)
    params = {}
    if args and args.strip():
        for part in args.split(","):
            if "=" not in part:
                raise ValueError(f"bad parameter {part!r} in {spec!r}: expected key=value")
            k, v = part.split("=", 1)
            params[k.strip()] = _value(v)
    return name, params


def make_filter(spec: str, **defaults):
    """Build a filter from a spec string; ``defaults`` apply unless the spec overrides."""
    name, params = parse_filter_spec(spec)
    adaptive = name.endswith("_sh")
    base = name[:-3] if adaptive else name
    if base not in _BASE:
        raise ValueError(f"unknown filter {base!r}; known: {', '.join(FILTER_NAMES)}")
    sh_keys = {"b", "adapt", "floor"}
    sh = {k: params.pop(k) for k in list(params) if adaptive and k in sh_keys}
    try:
        f = _BASE[base](**{**defaults, **params})
    except TypeError as e:
        raise ValueError(f"bad parameters for {base!r}: {e}") from None
    return SageHusa(f, **sh) if adaptive else f


def make_filter_in_context(spec: str, hybrid_defaults: dict) -> object:
    """``make_filter`` with an application's defaults for the ``hybrid`` family (plain and
    ``_sh``); parameters written in the spec still win, other filters are unaffected."""
    base = parse_filter_spec(spec)[0].removesuffix("_sh")
    return make_filter(spec, **(dict(hybrid_defaults) if base == "hybrid" else {}))


def split_filter_list(s: str) -> list[str]:
    """Split a --filters value on top-level commas only: 'a,b(x=1,y=2),c' -> 3 specs."""
    out, depth, cur = [], 0, ""
    for ch in s:
        depth += (ch == "(") - (ch == ")")
        if ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
        else:
            cur += ch
    if cur.strip():
        out.append(cur.strip())
    return out
