"""Filters from spec strings for the engine's jobs, through the presets table
(:mod:`uavest.presets`: what a filter name means in each command)."""

from __future__ import annotations

from collections.abc import Sequence

from ..core.registry import parse_filter_list
from ..core.spec import FilterSpec
from ..presets import build, describe_presets, resolve_list

__all__ = ["build_filters", "describe_presets", "parse_filter_list"]


def build_filters(
    specs: str | Sequence[str | FilterSpec], preset: str, dim: int
) -> list[tuple[FilterSpec, object]]:
    """[(fully resolved spec, unguarded filter)] for a list of specs in ``preset``, for a
    state of tangent dimension ``dim``; bad specs raise :class:`uavest.core.SpecError`
    (one line)."""
    return [(sp, build(sp)) for sp in resolve_list(specs, preset, dim)]
