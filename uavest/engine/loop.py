"""The streaming engine's loop: items go to every estimator, every record to every sink,
one at a time (nothing is held but what the estimators hold).

:func:`run` steps estimators over an item stream (a :class:`Start`, then
:class:`Step` s). :func:`run_lanes` is the general form for a sample stream: each
:class:`Lane` is a step builder (``push(sample) -> items``, ``flush() -> items``, e.g.
:class:`~uavest.engine.attitude.AttitudeStream`) with the estimators it feeds, so one
source (a live link) drives attitude filters and trackers side by side; every sample is
shown to every sink first (recorders, scorers). A lane with ``history_s`` > 0 takes its
samples as they arrive, in any order, and applies a late one at its own time
(:mod:`uavest.engine.history`).

Both run with the heap that exists before the run frozen (:func:`frozen_heap`).
"""

from __future__ import annotations

import gc
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Protocol

from .history import LaneHistory
from .records import RunInfo, Start, Step

__all__ = ["Lane", "frozen_heap", "run", "run_lanes"]

_FROZEN = 0


@contextmanager
def frozen_heap() -> Iterator[None]:
    """Run the body with every object that exists now moved out of Python's cyclic
    garbage collector's reach (``gc.freeze``; undone at the end, nested uses count).

    A run allocates many short-lived objects; now and then the collector's oldest
    generation is collected, and that traverses the whole heap: with numpy, scipy, numba
    and pymavlink's dialects loaded about 90-100 ms per full collection (measured on a
    replay of sample.ulg). What exists before the run (modules, tables, the sources) is
    not garbage of the run, so it is frozen: a full collection then costs the run's own
    objects only."""
    global _FROZEN
    if _FROZEN == 0:
        gc.freeze()
    _FROZEN += 1
    try:
        yield
    finally:
        _FROZEN -= 1
        if _FROZEN == 0:
            gc.unfreeze()


class StepBuilder(Protocol):
    """Turns samples into engine items (e.g. :class:`~uavest.engine.attitude.AttitudeStream`)."""

    def push(self, sample: Any) -> Iterable[Start | Step]: ...

    def flush(self) -> Iterable[Start | Step]: ...


class Estimator(Protocol):
    """What the loop calls of an estimator (:mod:`uavest.engine.runner`)."""

    @property
    def label(self) -> str: ...

    def start(self, st: Start) -> None: ...

    def step(self, st: Step) -> Any: ...


class RecordSink(Protocol):
    """What the loop calls of a sink (:class:`uavest.sinks.base.Sink`, a layer above):
    ``start`` gets the label, the start time (s) and the prior's mean and covariance (or
    None)."""

    def open(self, info: RunInfo) -> None: ...

    def sample(self, s: Any) -> None: ...

    def start(self, label: str, t0: float, x0: Any, P0: Any) -> None: ...

    def record(self, rec: Any) -> None: ...

    def close(self) -> None: ...


@dataclass
class Lane:
    """A step builder and the estimators its items go to. ``history_s`` > 0: samples on
    arrival, late ones applied at their time within that many seconds of vehicle time
    (:class:`~uavest.engine.history.LaneHistory`; the builder and the estimators then
    implement its ``Rewindable`` protocol); ``history`` is that history after the run."""

    builder: StepBuilder
    estimators: Sequence[Estimator]
    history_s: float = 0.0
    history: LaneHistory | None = field(default=None, init=False)


def _dispatch(items: Iterable[Start | Step], estimators: Sequence[Estimator],
              sinks: Sequence[RecordSink], quiet_upto: float = -math.inf) -> int:
    """Step ``estimators`` with ``items``; the sinks get the records (and the start
    events, the samples a step carries) of the items after ``quiet_upto`` (s) only, the
    others being re-made by a lane's history. Returns the steps the sinks got."""
    n = 0
    for it in items:
        if isinstance(it, Step):
            loud = it.t > quiet_upto
            if loud and it.info and "samples" in it.info:  # what the builder derived
                for smp in it.info["samples"]:
                    for s in sinks:
                        s.sample(smp)
            for e in estimators:
                rec = e.step(it)
                if loud:
                    for s in sinks:
                        s.record(rec)
            n += loud
        else:
            assert isinstance(it, Start), it
            loud = it.t0 > quiet_upto
            for e in estimators:
                e.start(it)
                if loud:
                    # an augmented restart starts each estimator from its own prior
                    p0 = getattr(e, "started_from", None) if it.augment is not None else None
                    p0 = it.prior if p0 is None else p0
                    for s in sinks:
                        s.start(e.label, it.t0, getattr(p0, "x", None), getattr(p0, "P", None))
    return n


def run(
    items: Iterable[Start | Step],
    estimators: Sequence[Estimator],
    sinks: Sequence[RecordSink] = (),
    info: RunInfo | None = None,
) -> int:
    """Run ``estimators`` over ``items``, handing every record to every sink; returns the
    number of steps. Sinks are opened first and closed last, also when the loop stops on
    an exception (e.g. KeyboardInterrupt), so output files are complete."""
    for s in sinks:
        if info is not None:
            s.open(info)
    try:
        with frozen_heap():
            return _dispatch(items, estimators, sinks)
    finally:
        for s in sinks:
            s.close()


def run_lanes(
    samples: Iterable[Any],
    lanes: Sequence[Lane],
    sinks: Sequence[RecordSink] = (),
    info: RunInfo | None = None,
    late: Callable[[Any], None] | None = None,
) -> int:
    """Feed every sample to every sink and every lane's builder; step each lane's
    estimators with the items it completes. Returns the number of steps of all lanes
    (that the sinks got). A sample a lane's history skipped (late beyond it) is given
    once to ``late``."""
    for s in sinks:
        if info is not None:
            s.open(info)
    n = 0
    hist: list[tuple[Lane, LaneHistory | None]] = []
    for ln in lanes:
        h = None
        if ln.history_s > 0:
            def disp(items: Iterable[Start | Step], quiet: float, ln: Lane = ln) -> int:
                return _dispatch(items, ln.estimators, sinks, quiet)
            h = ln.history = LaneHistory(ln.builder, ln.estimators, ln.history_s, disp)
        hist.append((ln, h))
    try:
        with frozen_heap():
            for smp in samples:
                for s in sinks:
                    s.sample(smp)
                skipped = False
                for ln, h in hist:
                    if h is not None:
                        k = h.push(smp)
                        if k is None:
                            skipped = True
                        else:
                            n += k
                        continue
                    items = ln.builder.push(smp)
                    if items:
                        n += _dispatch(items, ln.estimators, sinks)
                if skipped and late is not None:
                    late(smp)
            for ln, h in hist:
                n += h.flush() if h is not None else _dispatch(ln.builder.flush(),
                                                               ln.estimators, sinks)
    finally:
        for s in sinks:
            s.close()
    return n
