"""Filters from resolved specs for the engine's jobs.

The engine builds what it is given: :class:`~uavest.core.spec.FilterSpec`\\ s already
resolved for the job's state (what a filter name means in a command is the
application's decision, :mod:`uavest.presets`; the CLI resolves ``--filters`` once
against its command's preset and passes the specs down)."""

from __future__ import annotations

from collections.abc import Sequence

from ..core.contract import Filter
from ..core.registry import build
from ..core.spec import FilterSpec

__all__ = ["build_filters"]


def build_filters(specs: Sequence[FilterSpec]) -> list[tuple[FilterSpec, Filter]]:
    """[(spec, unguarded filter)] for specs resolved by
    :func:`uavest.presets.resolve_list` (a spec string is refused with ``TypeError``:
    resolving it is the caller's, against the command's preset)."""
    out = []
    for sp in specs:
        if not isinstance(sp, FilterSpec):
            raise TypeError(f"build_filters takes resolved FilterSpecs, got {sp!r} "
                            "(resolve spec text with uavest.presets.resolve_list)")
        out.append((sp, build(sp)))
    return out
