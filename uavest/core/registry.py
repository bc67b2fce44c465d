"""Filters by name: spec text -> validated :class:`FilterSpec` -> filter.

Names: kf, ekf, ukf, ckf (cubature), srukf, enkf, etkf, hybrid (``update_mode`` shift |
local), hybrid_literal, pf. A ``_sh`` suffix wraps the filter in the Sage-Husa
adaptive-noise estimator (e.g. ``ukf_sh``, ``hybrid_sh(b=0.97)``).

Adding a filter: write its class (a frozen dataclass inheriting
:class:`uavest.core.contract.FilterBase` or ``EnsembleFilter``, parameters declared with
``field(metadata=param(...))``) in one file and add one line to :data:`REGISTRY`.

New API::

    spec = parse_spec("hybrid(n_cloud=20)")       # FilterSpec, validated, all params
    specs = parse_filter_list("ekf,ukf,hybrid")   # refuses duplicates and empty lists
    f = build(spec)                               # unguarded filter

Application presets (what ``hybrid`` means in replay / bench / track) live in
:mod:`uavest.presets`, not here. ``make_filter``, ``make_filter_in_context``,
``parse_filter_spec`` and ``split_filter_list`` are kept as thin wrappers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from .adaptive import SageHusa
from .contract import Filter
from .ensemble import ETKF, EnKF
from .hybrid import HybridLiteral, HybridLocal, HybridShift
from .kalman import EKF, KF
from .particle import PF
from .spec import (
    FilterSpec,
    Param,
    SpecError,
    check_params,
    declared_params,
    parse_text,
    split_filter_list,
)
from .unscented import CKF, SRUKF, UKF


@dataclass(frozen=True)
class Modes:
    """A registry name whose strategy class is chosen by one parameter (``key``); each
    class declares only the parameters its strategy uses. The first mode is the
    default."""

    key: str
    classes: Mapping[str, type]

    @property
    def default(self) -> str:
        return next(iter(self.classes))


REGISTRY: dict[str, type | Modes] = {
    "kf": KF,
    "ekf": EKF,
    "ukf": UKF,
    "ckf": CKF,
    "srukf": SRUKF,
    "enkf": EnKF,
    "etkf": ETKF,
    "hybrid": Modes("update_mode", {"shift": HybridShift, "local": HybridLocal}),
    "hybrid_literal": HybridLiteral,
    "pf": PF,
}
FILTER_NAMES = tuple(REGISTRY) + ("<name>_sh",)
_SH = declared_params(SageHusa)


def _known() -> str:
    return ", ".join(FILTER_NAMES)


def filter_class(name: str, given: Mapping[str, Any] | None = None
                 ) -> tuple[type, dict[str, Any]]:
    """(class, {mode key: mode}) a registry name (``_sh`` allowed) resolves to, the mode
    read from ``given`` (validated). Raises :class:`SpecError` for unknown names."""
    base = name.removesuffix("_sh")
    entry = REGISTRY.get(base)
    if entry is None:
        raise SpecError(f"unknown filter {base!r}; known: {_known()}")
    if isinstance(entry, Modes):
        mode = (given or {}).get(entry.key, entry.default)
        p = Param("choice", choices=tuple(entry.classes))
        mode = p.check(name, entry.key, mode)
        return entry.classes[mode], {entry.key: mode}
    return entry, {}


def param_table(name: str, given: Mapping[str, Any] | None = None) -> dict[str, tuple[Param, Any]]:
    """{parameter: (Param, default)} of a registry name (with its mode, and the
    Sage-Husa parameters for ``_sh`` names)."""
    cls, _ = filter_class(name, given)
    table: dict[str, tuple[Param, Any]] = {}
    entry = REGISTRY[name.removesuffix("_sh")]
    if isinstance(entry, Modes):
        table[entry.key] = (Param("choice", choices=tuple(entry.classes)), entry.default)
    table.update(declared_params(cls))
    if name.endswith("_sh"):
        table.update(_SH)
    return table


def parse_spec(
    spec: str | FilterSpec,
    defaults: Mapping[str, Any] | None = None,
    *,
    preset: str | None = None,
    dim: int | None = None,
) -> FilterSpec:
    """Parse and validate a spec; ``defaults`` (e.g. a preset's values) apply unless the
    spec writes the parameter. A :class:`FilterSpec` passed in is re-validated with its
    user-written parameters (``spec.user``) winning over ``defaults``, the rest
    re-resolved."""
    if isinstance(spec, FilterSpec):
        name, label, user = spec.name, spec.label, frozenset(spec.user)
        written = {k: spec.params[k] for k in user if k in spec.params}
    else:
        name, written = parse_text(spec)
        label, user = spec.strip(), frozenset(written)
    given = {**(defaults or {}), **written}
    cls, mode = filter_class(name, given)  # unknown name / bad mode first
    _check_mode_params(name, cls, mode, user)
    params = check_params(name, param_table(name, given), given, user)
    return FilterSpec(name, params, label, preset, user, dim)


def _check_mode_params(name: str, cls: type, mode: dict[str, Any], user: frozenset[str]) -> None:
    """A written parameter that belongs to another mode of the same name: say so."""
    entry = REGISTRY[name.removesuffix("_sh")]
    if not isinstance(entry, Modes):
        return
    mine = set(declared_params(cls)) | {entry.key} | (set(_SH) if name.endswith("_sh") else set())
    for k in sorted(user - mine):
        others = [m for m, c in entry.classes.items() if k in declared_params(c)]
        if others:
            (key, m), = mode.items()
            raise SpecError(
                f"{name}: {k} has no effect with {key}={m} (only with {key}="
                f"{', '.join(others)}; parameters of {key}={m}: "
                f"{', '.join(sorted(mine - {entry.key}))})")


def parse_filter_list(
    text: str | Sequence[str],
    defaults: Mapping[str, Any] | None = None,
) -> list[FilterSpec]:
    """Specs of a ``--filters`` value ('a,b(x=1,y=2),c') or a list of spec strings.
    Refuses an empty list and duplicates (the same label twice, or two labels that
    resolve to the same filter and parameters)."""
    items = split_filter_list(text) if isinstance(text, str) else [str(t) for t in text]
    if not any(items):
        raise SpecError("the filter list is empty")
    if not all(items):
        raise SpecError(f"the filter list {text!r} has an empty entry")
    specs = [parse_spec(t, defaults) for t in items]
    seen: dict[tuple[str, tuple[tuple[str, Any], ...]], str] = {}
    for s in specs:
        key = (s.name, tuple(sorted(s.params.items())))
        if s.label in seen.values() or key in seen:
            other = seen.get(key, s.label)
            what = s.label if other == s.label else f"{other} and {s.label}"
            raise SpecError(f"the filter list names {what} more than once")
        seen[key] = s.label
    return specs


def build(spec: FilterSpec | str) -> Filter:
    """The (unguarded) filter of a spec; callers wrap it in :class:`Guarded`."""
    if not isinstance(spec, FilterSpec):
        spec = parse_spec(spec)
    cls, mode = filter_class(spec.name, spec.params)
    kw = {k: v for k, v in spec.params.items() if k not in mode}
    sh = {k: kw.pop(k) for k in list(kw) if spec.adaptive and k in _SH}
    f = cls(**kw)
    return SageHusa(f, **sh) if spec.adaptive else f


# ------------------------------------------------------------------- compatibility layer


def parse_filter_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """Syntax only: ``"ukf(alpha=0.001, kappa=0)"`` -> ("ukf", {"alpha": 0.001, "kappa": 0})."""
    return parse_text(spec)


def make_filter(spec: str, **defaults: Any) -> Filter:
    """Build a filter from a spec string; ``defaults`` apply unless the spec overrides
    (defaults a filter does not have, or that have no effect, are ignored)."""
    return build(parse_spec(spec, defaults))


def make_filter_in_context(spec: str, hybrid_defaults: dict[str, Any]) -> Filter:
    """``make_filter`` with an application's defaults for the ``hybrid`` family (plain and
    ``_sh``); parameters written in the spec still win, other filters are unaffected.
    Prefer :func:`uavest.presets.resolve` / :func:`uavest.presets.build`."""
    base = parse_text(spec)[0].removesuffix("_sh")
    return make_filter(spec, **(dict(hybrid_defaults) if base == "hybrid" else {}))


__all__ = [
    "FILTER_NAMES", "REGISTRY", "FilterSpec", "Modes", "SpecError", "build", "filter_class",
    "make_filter", "make_filter_in_context", "param_table", "parse_filter_list",
    "parse_filter_spec", "parse_spec", "split_filter_list",
]
