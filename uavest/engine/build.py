"""Filters from spec strings for the engine's applications, through the presets table."""

from __future__ import annotations

from ..core.registry import make_filter, make_filter_in_context, split_filter_list

__all__ = ["build_filters"]

_PRESETS = {  # replaced by uavest.presets
    "attitude": {"n_cloud": 16, "tau": 0.9},
    "radar": {"update_mode": "local", "n_cloud": 64},
    "bench": {},
}


class _Spec:
    def __init__(self, label: str, preset: str) -> None:
        self.label = label
        self.preset = preset

    def as_dict(self) -> dict:
        return {"label": self.label, "preset": self.preset}


def build_filters(specs, preset: str, dim: int) -> list:
    """[(spec, filter)] for spec strings (or one comma-separated string)."""
    if isinstance(specs, str):
        specs = split_filter_list(specs)
    out = []
    for s in specs:
        extra = {}
        if preset == "bench" and s.split("(")[0].strip().removesuffix("_sh") in ("enkf", "etkf"):
            from ..core.hybrid import Hybrid

            extra = {"members": Hybrid().members(dim)}
        f = make_filter_in_context(s, _PRESETS[preset]) if not extra else make_filter(s, **extra)
        out.append((_Spec(s, preset), f))
    return out


def parse_filter_list(text: str) -> list[str]:
    """Spec strings from a ``--filters`` value; empty lists, duplicates and bad specs are
    refused with one line."""
    specs = split_filter_list(text)
    if not specs:
        raise ValueError("--filters is empty: give at least one filter, e.g. ekf,ukf,hybrid")
    dup = sorted({s for s in specs if specs.count(s) > 1})
    if dup:
        raise ValueError(f"--filters lists {', '.join(dup)} more than once")
    for s in specs:
        make_filter(s)
    return specs


def describe_presets() -> str:
    """What ``hybrid`` resolves to in each command."""
    lines = ["presets (what 'hybrid' means per command; spec parameters still win):"]
    for name, d in _PRESETS.items():
        args = ", ".join(f"{k}={v}" for k, v in d.items()) or "core defaults"
        lines.append(f"  {name:9s} hybrid({args})")
    return "\n".join(lines)
