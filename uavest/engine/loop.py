"""The streaming engine's loop: items from a step source go to every estimator, every
record to every sink, one at a time (nothing is held but what the estimators hold)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from .records import RunInfo, Start, Step

__all__ = ["run"]


def run(
    items: Iterable[Start | Step],
    estimators: Sequence,
    sinks: Sequence = (),
    info: RunInfo | None = None,
) -> int:
    """Run ``estimators`` over ``items`` (a :class:`Start`, then :class:`Step` s, maybe
    more starts), handing every record to every sink; returns the number of steps.

    Sinks are opened first and closed last, also when the loop stops on an exception
    (e.g. KeyboardInterrupt), so output files are complete."""
    for s in sinks:
        if info is not None:
            s.open(info)
    n = 0
    try:
        for it in items:
            if isinstance(it, Step):
                for e in estimators:
                    rec = e.step(it)
                    for s in sinks:
                        s.record(rec)
                n += 1
            else:
                for e in estimators:
                    e.start(it)
                    for s in sinks:
                        s.start(e.label, it.t0, it.prior.x, it.prior.P)
    finally:
        for s in sinks:
            s.close()
    return n
