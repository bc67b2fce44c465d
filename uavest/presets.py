"""Application presets: what a filter name means in each command, in one table.

The core's filters have one set of defaults (``uavest.core``). Applications tuned some of
them; a *preset* names such a tuning so that users can see it (``uavest list`` prints
:func:`describe_presets`) and results can record it (:meth:`FilterSpec.as_dict`):

``bench``
    ``uavest bench`` on the Monte Carlo systems (UNGM, nonlinear 2-D, linear CV): the
    core defaults; EnKF/ETKF get the member count M = (2n+1)(N+1) of the hybrid, so the
    ensemble sizes match (:func:`resolve_list`: the hybrid listed in the same run;
    :func:`resolve` alone: the preset's own hybrid).
``attitude``
    ``uavest replay`` (attitude from IMU, n = 6): ``hybrid`` with n_cloud = 16 (M = 221)
    and tau = 0.9 (90 % of each measurement by the EnKF shift, 10 % by the confidence
    weights); docs/attitude.md gives the sweep they were chosen by.
``radar``
    ``uavest track`` and the radar scenarios of ``uavest bench``: ``hybrid`` with the
    local-gain (Gaussian-mixture) update and n_cloud = 64 (M = 585 in 4-D). The local
    update keeps the information of a 10 m range that the single EnKF shift loses
    against a wide prior (docs/tracking.md gives the measurements).
    Write ``hybrid(update_mode=shift, n_cloud=32)`` for the core default.

A preset's values apply to the registry name and its ``_sh`` variant; parameters the
user writes in the spec always win; preset values that have no effect in the mode the
user chose (e.g. ``tau`` with ``update_mode=local``) are dropped.

API::

    spec = resolve("hybrid(tau=0.5)", "attitude", dim=6)   # FilterSpec, all params
    specs = resolve_list("ekf,enkf,hybrid(n_cloud=8)", "bench", dim=1)
    f = build(spec)                                        # unguarded filter
    print(describe_presets())
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .core.contract import Filter
from .core.hybrid import default_gamma
from .core.registry import build as _build
from .core.registry import filter_class, parse_spec
from .core.spec import FilterSpec, SpecError, split_filter_list, value_text

#: A dimension-dependent preset value: f(dim, preset name) -> value.
PerDim = Callable[[int, str], Any]


def _hybrid_members(dim: int, preset: str) -> int:
    """M = (2n+1)(N+1) of the preset's own ``hybrid`` at tangent dimension ``dim``."""
    return _build(resolve("hybrid", preset, dim)).members(dim)


@dataclass(frozen=True)
class Preset:
    """One application's filter tuning: ``params`` {registry name: {parameter: value or
    PerDim}}, ``used_by`` the commands that use it, ``match_members``: EnKF/ETKF without
    a written ``members`` take the member count of the hybrid in the same list."""

    name: str
    used_by: str
    params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    match_members: bool = False


PRESETS: dict[str, Preset] = {
    "bench": Preset(
        "bench", "uavest bench (Monte Carlo systems)",
        {"enkf": {"members": _hybrid_members}, "etkf": {"members": _hybrid_members}},
        match_members=True,
    ),
    "attitude": Preset("attitude", "uavest replay / run / demo with the attitude model",
                       {"hybrid": {"n_cloud": 16, "tau": 0.9}}),
    # the attitude preset's hybrid, re-spread after each shift: the navigation state's
    # position, velocity and biases are long-memory states that an ensemble's gain
    # otherwise shrinks (docs/filters.md, "Long memory")
    # and the unscented filters' sigma points at 0.1 of the Van der Merwe spread: with
    # alpha 1 they lie sqrt(n) = 3.9-4.2 std out on the 15-18-dim state, +-60 deg of yaw
    # at the start's 15 deg std, and the UKF aligned in flight far slower than the EKF
    # (docs/navigation.md, "The UKF's sigma-point spread")
    "nav": Preset("nav", "uavest replay / run / demo with the navigation model",
                  {"hybrid": {"n_cloud": 16, "tau": 0.9, "reinflate": True},
                   "ukf": {"alpha": 0.1}, "srukf": {"alpha": 0.1}}),
    "radar": Preset(
        "radar", "uavest track, uavest bench (radar scenarios)",
        {"hybrid": {"update_mode": "local", "n_cloud": 64}},
    ),
}


def preset(name: str) -> Preset:
    """The preset called ``name`` (:class:`SpecError` listing the known ones)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise SpecError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}") from None


def _defaults(p: Preset, name: str, dim: int | None) -> dict[str, Any]:
    out = {}
    for k, v in p.params.get(name.removesuffix("_sh"), {}).items():
        if callable(v):
            if dim is None:
                raise SpecError(f"preset {p.name}: {name} {k} depends on the state "
                                "dimension; resolve it with dim=")
            v = v(dim, p.name)
        out[k] = v
    return out


def _with_dim(spec: FilterSpec, dim: int | None) -> FilterSpec:
    """Fill dimension-dependent defaults (``gamma=None`` -> its value at ``dim``)."""
    if dim is None or "gamma" not in spec.params or spec.params["gamma"] is not None:
        return spec
    params = dict(spec.params)
    params["gamma"] = default_gamma(dim)
    return FilterSpec(spec.name, params, spec.label, spec.preset, spec.user, dim)


def resolve(spec: str | FilterSpec, preset_name: str, dim: int | None = None) -> FilterSpec:
    """The fully resolved :class:`FilterSpec` of ``spec`` in a preset: core defaults,
    then the preset's values, then the parameters the user wrote. With ``dim`` (the
    state's tangent dimension) dimension-dependent values are resolved too (member
    counts, ``gamma``); a preset value that needs ``dim`` raises :class:`SpecError`
    without it."""
    p = preset(preset_name)
    if isinstance(spec, FilterSpec) and dim is not None and (spec.preset, spec.dim) == (
            p.name, dim):
        return spec  # resolved here before (the CLI's): not again
    name = spec.name if isinstance(spec, FilterSpec) else None
    if name is None:
        from .core.spec import parse_text

        name = parse_text(spec)[0]
    filter_class(name)  # unknown names first, with the list of known ones
    out = parse_spec(spec, _defaults(p, name, dim), preset=p.name, dim=dim)
    return _with_dim(out, dim)


def resolve_list(
    text: str | Sequence[str | FilterSpec], preset_name: str, dim: int | None = None,
    *, distinct: bool = True,
) -> list[FilterSpec]:
    """:func:`resolve` for every spec of a list ('a,b(x=1),c' or a sequence), refusing
    an empty list and duplicates. In a preset with ``match_members`` and exactly one
    hybrid-family entry in the list, EnKF/ETKF that do not write ``members`` get that
    hybrid's member count (so the run compares equal ensemble sizes). A list of specs
    already resolved in this preset at this ``dim`` (this function's result) is returned
    as it is.

    ``distinct=False`` lets two labels that resolve to the same filter through: each
    label draws from its own random stream (``filter:<label>``), which is how a benchmark
    shows one filter's stream-to-stream spread on the same truths
    (``benchmarks/radar_bound.py``). The same label twice is refused either way; the
    command line keeps ``distinct=True`` (two names of one filter are a user's slip)."""
    p = preset(preset_name)
    items = split_filter_list(text) if isinstance(text, str) else list(text)
    if items and dim is not None and all(
            isinstance(i, FilterSpec) and i.preset == p.name and i.dim == dim for i in items):
        return items  # a list this function resolved (the CLI's) is not resolved again
    texts = [i if isinstance(i, str) else i.label for i in items]
    # empty list / empty entry / the same label twice; whether two different labels are
    # the same filter is decided below, in this preset (not with the core's defaults:
    # under the attitude preset "hybrid" and "hybrid(tau=0.3)" are different filters)
    if not any(texts):
        raise SpecError("the filter list is empty")
    if not all(texts):
        raise SpecError(f"the filter list {text!r} has an empty entry")
    specs = [resolve(i, preset_name, dim) for i in items]
    if p.match_members and dim is not None:
        hybrids = [s for s in specs if s.base == "hybrid"]
        if len(hybrids) == 1:
            M = _build(hybrids[0]).members(dim)
            specs = [
                parse_spec(s, {"members": M}, preset=p.name, dim=dim)
                if s.base in ("enkf", "etkf") and "members" not in s.user else s
                for s in specs
            ]
    seen: dict[tuple, str] = {}
    for s in specs:
        key = (s.name, tuple(sorted(s.params.items())))
        if s.label in seen.values():
            raise SpecError(f"the filter list names {s.label} more than once")
        if key in seen and distinct:
            raise SpecError(f"the filter list names {seen[key]} and {s.label}, which resolve "
                            f"to the same filter in preset {p.name}")
        seen[key] = s.label
    return specs


def build(spec: FilterSpec | str, preset_name: str | None = None, dim: int | None = None
          ) -> Filter:
    """The unguarded filter of a spec (resolved in ``preset_name`` first if given);
    callers wrap it in :class:`uavest.core.Guarded`."""
    if preset_name is not None:
        spec = resolve(spec, preset_name, dim)
    return _build(spec)


def spec_labels(specs: Sequence[str | FilterSpec]) -> list[str]:
    """The specs as the user wrote them (a resolved spec's ``label``), e.g. for a
    configuration record."""
    return [s.label if isinstance(s, FilterSpec) else s for s in specs]


def _changed(spec: FilterSpec) -> str:
    """``name(k=v, ...)`` with the mode and the values that differ from the core's
    defaults in that mode."""
    mode = {k: v for k, v in spec.params.items() if k == "update_mode"}
    core = parse_spec(spec.name, mode)
    keep = [k for k, v in spec.params.items()
            if k == "update_mode" or core.params.get(k, object()) != v]
    return f"{spec.name}(" + ", ".join(f"{k}={value_text(spec.params[k])}" for k in keep) + ")"


def describe_presets(names: Sequence[str] = ("hybrid", "enkf", "etkf", "ukf", "srukf")
                     ) -> str:
    """What ``hybrid`` (and any other filter a preset changes) resolves to in each
    preset, as the values that differ from the core defaults (for ``uavest list``)."""
    lines = ["presets (what a filter name means in each command; spec parameters win):"]
    for p in PRESETS.values():
        lines.append(f"  {p.name:9s} used by {p.used_by}")
        for n in names:
            if n != "hybrid" and n not in p.params:
                continue
            if any(callable(v) for v in p.params.get(n, {}).values()):
                keys = ", ".join(k for k, v in p.params[n].items() if callable(v))
                what = (f"{n}({keys} = (2n+1)(n_cloud+1) of the hybrid in the same run, "
                        f"else of {_changed(resolve('hybrid', p.name))})")
            else:
                what = _changed(resolve(n, p.name))
            if what.count("=") == 1 and "update_mode" in what or what.endswith("()"):
                what += "  (core defaults)"
            lines.append(f"    {n:7s} -> {what}")
    return "\n".join(lines)


__all__ = ["PRESETS", "Preset", "build", "describe_presets", "preset", "resolve",
           "resolve_list", "spec_labels"]
