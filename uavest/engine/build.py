"""Filters from spec strings for the engine's applications, through the presets table."""

from __future__ import annotations

from ..core.registry import make_filter_in_context, split_filter_list

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
    return [(_Spec(s, preset), make_filter_in_context(s, _PRESETS[preset])) for s in specs]
