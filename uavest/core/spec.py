"""Typed, validated filter specs.

A spec string such as ``"hybrid(n_cloud=20, tau=0.5)"`` is parsed once into a frozen
:class:`FilterSpec` (registry name, fully resolved parameters, the label as written).
Every parameter is declared next to its filter as dataclass field metadata
(``field(default=..., metadata=param(...))``, see :func:`param`), so the table the
validator reads cannot drift from the code. Errors raise :class:`SpecError` (a
``ValueError``) with one line naming the filter, the parameter, the value and what is
allowed, e.g. ``hybrid: n_cloud must be an integer >= 1, got 2.5``.

Grammar: ``name`` or ``name(key=value, ...)``; values are numbers, ``true``/``false``,
``none``, or bare/quoted words. A ``_sh`` suffix wraps the filter in the Sage-Husa
adaptive-noise estimator (its parameters ``b``, ``adapt``, ``floor`` join the filter's).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from ..errors import InputError


class SpecError(InputError):
    """A filter spec that cannot be built; the message is one line."""


# ------------------------------------------------------------------------ declarations


@dataclass(frozen=True)
class Param:
    """Type and range of one filter parameter.

    ``kind``: "int", "float", "choice", "bool". Numbers: ``lo``/``hi`` bounds (None:
    unbounded), ``lo_open``/``hi_open`` for strict inequalities; floats must be finite.
    ``choices`` for "choice". ``none_ok``: None is allowed (meaning documented in
    ``doc``). ``when``: {other parameter: allowed values}; the parameter has an effect
    only then (writing it otherwise is an error).
    """

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] = ()
    none_ok: bool = False
    when: Mapping[str, tuple[Any, ...]] = dataclasses.field(default_factory=dict)
    doc: str = ""

    def allowed(self) -> str:
        """What is allowed, in words (used in error messages)."""
        if self.kind == "choice":
            out = "one of " + ", ".join(self.choices)
        elif self.kind == "bool":
            out = "true or false"
        else:
            out = "an integer" if self.kind == "int" else "a number"
            lo = None if self.lo is None else f"{_num(self.lo)}"
            hi = None if self.hi is None else f"{_num(self.hi)}"
            if lo is not None and hi is not None:
                out += (f" in {'(' if self.lo_open else '['}{lo}, {hi}"
                        f"{')' if self.hi_open else ']'}")
            elif lo is not None:
                out += f" {'>' if self.lo_open else '>='} {lo}"
            elif hi is not None:
                out += f" {'<' if self.hi_open else '<='} {hi}"
        return out + (" or none" if self.none_ok else "")

    def check(self, filt: str, key: str, v: Any) -> Any:
        """``v`` converted to this parameter's type, or :class:`SpecError`."""
        if v is None:
            if self.none_ok:
                return None
            raise self._err(filt, key, v)
        if self.kind == "bool":
            if isinstance(v, bool):
                return v
            raise self._err(filt, key, v)
        if self.kind == "choice":
            if isinstance(v, str) and v in self.choices:
                return v
            raise self._err(filt, key, v)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self._err(filt, key, v)
        if self.kind == "int":
            if isinstance(v, float):
                if not (math.isfinite(v) and v.is_integer()):
                    raise self._err(filt, key, v)
                v = int(v)
        else:
            v = float(v)
            if not math.isfinite(v):
                raise self._err(filt, key, v)
        if self.lo is not None and (v < self.lo or (self.lo_open and v == self.lo)):
            raise self._err(filt, key, v)
        if self.hi is not None and (v > self.hi or (self.hi_open and v == self.hi)):
            raise self._err(filt, key, v)
        return v

    def _err(self, filt: str, key: str, v: Any) -> SpecError:
        return SpecError(f"{filt}: {key} must be {self.allowed()}, got {_show(v)}")


def param(kind: str, doc: str = "", **kw: Any) -> dict[str, Param]:
    """Field metadata declaring a spec parameter: ``field(default=1.0,
    metadata=param("float", lo=0, lo_open=True, doc="..."))``."""
    return {"param": Param(kind, doc=doc, **kw)}


def declared_params(cls: type) -> dict[str, tuple[Param, Any]]:
    """{name: (Param, default)} of a dataclass's declared spec parameters, in order."""
    out = {}
    for f in dataclasses.fields(cls):
        p = f.metadata.get("param")
        if p is not None:
            out[f.name] = (p, f.default)
    return out


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def _show(v: Any) -> str:
    return repr(v) if isinstance(v, str) else str(v).lower() if isinstance(v, bool) else str(v)


def value_text(v: Any) -> str:
    """A parameter's value as a spec string writes it (``true``, ``shift``, ``0.5``)."""
    return _show(v).strip(chr(39))


# ------------------------------------------------------------------------------- value


@dataclass(frozen=True)
class FilterSpec:
    """A parsed, validated filter spec.

    ``name``: registry name as written (``hybrid``, ``ukf_sh``...); ``params``: every
    parameter of the filter with its value (defaults, preset values and the user's,
    validated; read-only mapping); ``label``: the spec text as the user wrote it (results
    are keyed by it); ``preset``: the application preset it was resolved in, or None;
    ``user``: the names of the parameters the user wrote; ``dim``: the tangent dimension
    dimension-dependent values were resolved for, or None.
    """

    name: str
    params: Mapping[str, Any]
    label: str
    preset: str | None = None
    user: frozenset[str] = frozenset()
    dim: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    def __hash__(self) -> int:
        return hash((self.name, tuple(sorted(self.params.items(), key=lambda kv: kv[0])),
                     self.label, self.preset, self.dim))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FilterSpec):
            return NotImplemented
        return (self.name, dict(self.params), self.label, self.preset, self.dim) == (
            other.name, dict(other.params), other.label, other.preset, other.dim)

    @property
    def base(self) -> str:
        """The registry name without the ``_sh`` wrapper suffix."""
        return self.name.removesuffix("_sh")

    @property
    def adaptive(self) -> bool:
        return self.name.endswith("_sh")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: {"name", "label", "preset", "params"} (+ "dim" when resolved)."""
        d: dict[str, Any] = {"name": self.name, "label": self.label, "preset": self.preset,
             "params": dict(self.params)}
        if self.dim is not None:
            d["dim"] = self.dim
        return d

    def text(self) -> str:
        """A spec string that parses back to these parameters."""
        args = ", ".join(f"{k}={value_text(v)}" for k, v in self.params.items())
        return f"{self.name}({args})" if args else self.name


# ----------------------------------------------------------------------------- parsing

_SPEC = re.compile(r"^\s*([a-z_][a-z0-9_]*)\s*(?:\((.*)\))?\s*$")
_NUM = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$",
                  re.IGNORECASE)


def _value(v: str) -> Any:
    v = v.strip()
    if re.fullmatch(r"[+-]?\d+", v):
        return int(v)
    if _NUM.match(v):
        return float(v)
    if v.lower() in ("none", "null"):
        return None
    if v.lower() in ("true", "false"):
        return v.lower() == "true"
    return v.strip("'\"")


def parse_text(text: str) -> tuple[str, dict[str, Any]]:
    """Syntax only: ``"ukf(alpha=0.001, kappa=0)"`` -> ("ukf", {"alpha": 0.001, "kappa": 0}).
    Raises :class:`SpecError` for malformed text or a repeated parameter."""
    if not isinstance(text, str):
        raise SpecError(f"filter spec must be a string, got {type(text).__name__}")
    m = _SPEC.match(text)
    if not m:
        raise SpecError(f"bad filter spec {text!r}: expected name or name(key=value, ...)")
    name, args = m.group(1), m.group(2)
    params: dict[str, Any] = {}
    if args and args.strip():
        for part in args.split(","):
            if "=" not in part:
                raise SpecError(f"{name}: bad parameter {part.strip()!r}: expected key=value")
            k, v = part.split("=", 1)
            k = k.strip()
            if k in params:
                raise SpecError(f"{name}: parameter {k} given twice")
            params[k] = _value(v)
    return name, params


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


def check_params(
    filt: str, table: Mapping[str, tuple[Param, Any]], given: Mapping[str, Any],
    user: frozenset[str] | set[str],
) -> dict[str, Any]:
    """Validate ``given`` against a parameter ``table`` ({name: (Param, default)}).

    Returns every parameter of the table that has an effect, defaults filled in.
    ``user`` are the keys the user wrote: unknown ones, or ones without effect (a
    ``when`` condition not met), raise :class:`SpecError`; keys that came from a preset
    and are unknown to this filter or without effect are dropped silently.
    """
    for k in given:
        if k not in table and k in user:
            raise SpecError(f"{filt}: unknown parameter {k!r} (given {k}={_show(given[k])});"
                            f" known: {', '.join(table) or 'none'}")
    out: dict[str, Any] = {}
    for k, (p, default) in table.items():
        out[k] = p.check(filt, k, given[k]) if k in given else default
    for k, (p, _) in table.items():
        for other, ok in p.when.items():
            if out.get(other) not in ok:
                if k in given and k in user:
                    allowed = ", ".join(map(str, ok))
                    raise SpecError(f"{filt}: {k} has no effect with {other}={out.get(other)}"
                                    f" (only with {other}={allowed})")
                out.pop(k, None)
                break
    return out
