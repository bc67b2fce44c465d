"""Resource estimates before long or large work: refuse what would not fit in memory,
warn on what would take hours (``uavest bench``, ``uavest track``).

The estimates are deliberately coarse upper bounds (per trial the metrics keep a few
arrays of ``steps x state`` floats per filter; the radar filter-mode bench keeps every
run's data until the end; clutter adds ``clutter_rate`` detections per scan).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from typing import Any

from ..core.spec import FilterSpec
from ..errors import InputError
from ..scenarios import typed

log = logging.getLogger("uavest")

#: Memory a command may plan to use (bytes); UAVEST_MAX_MEMORY_GB overrides.
DEFAULT_MAX_BYTES = 1e9
WARN_SECONDS = 3600.0  # warn beyond an hour

# rough microseconds per filter step (dimension <= 6), measured on the 2-core CI machine
_US_PER_STEP = {"kf": 15, "ekf": 25, "ukf": 80, "srukf": 100, "enkf": 400, "etkf": 400,
                "hybrid": 600, "hybrid_literal": 600, "hybrid_sh": 700, "pf": 800}


def max_bytes() -> float:
    v = os.environ.get("UAVEST_MAX_MEMORY_GB")
    try:
        cap = float(v) * 1e9 if v else DEFAULT_MAX_BYTES
    except ValueError:
        cap = DEFAULT_MAX_BYTES
    try:
        avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        cap = min(cap, 0.8 * avail) if avail > 0 else cap
    except (ValueError, OSError, AttributeError):
        pass
    return cap


def estimate(sc: Any, specs: Sequence[str | FilterSpec], runs: int, steps: int
             ) -> tuple[float, float]:
    """(bytes, seconds) a bench of the typed scenario ``sc`` with ``runs`` x ``steps`` and
    ``specs`` may need."""
    nf = max(1, len(specs))
    dim = 6
    lam = 0.0
    if sc.kind == "radar":
        dim = 2 * sc.ndim + 1
        lam = float(sc.radar.clutter_rate)
        ntg = max(1, len(sc.targets))
    else:
        ntg = 1
    per_step = 8.0 * (3 * dim + 4) * nf + 8.0 * (lam + ntg) * 4
    held = runs if sc.kind == "radar" else min(runs, 64)  # radar keeps every run
    mem = float(held) * steps * per_step + float(runs) * nf * 64 * 8  # + per-trial rows
    names = (s.name if isinstance(s, FilterSpec) else s.split("(")[0].strip() for s in specs)
    us = sum(_US_PER_STEP.get(n, 500) for n in names) or 500
    secs = float(runs) * steps * (us + 5.0 * (lam + ntg) * nf) * 1e-6
    return mem, secs


def check(sc: Any, specs: Sequence[str | FilterSpec], runs: int, steps: int, what: str) -> None:
    """Refuse (InputError, one line) what would not fit in memory; warn on hours (``sc``:
    the scenario, typed or its dict)."""
    mem, secs = estimate(typed(sc), specs, runs, steps)
    cap = max_bytes()
    if mem > cap:
        raise InputError(
            f"{what}: {runs:,} runs x {steps:,} steps with {len(specs)} filters would need "
            f"about {mem / 1e9:.3g} GB of memory (limit {cap / 1e9:.3g} GB; set "
            "UAVEST_MAX_MEMORY_GB to change it); use fewer --runs or --steps")
    if secs > WARN_SECONDS:
        log.warning("%s: %s runs x %s steps will take about %.1f hours", what,
                    f"{runs:,}", f"{steps:,}", secs / 3600.0)
