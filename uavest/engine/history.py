"""Samples processed on arrival, with a bounded history for the late ones.

A live link releases every sample as soon as its message is accepted (no reorder window:
:mod:`uavest.ingest.mavlink`, ``reorder_window=0``), so the streams of one vehicle arrive
interleaved a little out of time order: an aiding measurement (a velocity, a GNSS fix, a
magnetometer of another message, a detection of a sweep) can arrive after IMU samples
that are newer than it. :class:`LaneHistory` runs one :class:`~uavest.engine.loop.Lane`
over such a stream the way robot_localization's real-time loop runs its filter:

* **on arrival**: each sample goes to the lane's step builder as it comes, and the items
  it completes (an attitude step at the IMU sample that ends it, a radar scan) go to the
  estimators and their records to the sinks at once; nothing waits for newer samples;
* **late samples**: a sample at or before the builder's :attr:`~Rewindable.committed`
  time (the end of the last item it returned) for which
  :meth:`~Rewindable.order_sensitive` is true would have changed items already made. The
  lane then restores the builder and every estimator to the newest *checkpoint* taken
  before the sample's time (one after each batch of items: the builder's state and each
  estimator's, filter states being immutable, with its random generator's state), feeds
  the samples it has seen since that checkpoint again together with the late one, in time
  order (an IMU sample after the other samples of its time, as the link releases them),
  and steps the estimators with the items that gives. Every estimator then holds exactly
  what it would hold had the samples arrived in time order.
* **records never go back in time**: the re-made items up to the newest item already
  handed to the sinks go to the estimators only (a sink has seen each such step once, as
  it was made when it was made; the late sample is in every later estimate); the sinks
  see only the items that are new.
* **bounded**: checkpoints and samples older than ``horizon_s`` of vehicle time before the
  newest order-sensitive sample are dropped; a late sample older than the oldest
  checkpoint is skipped and counted (:attr:`HistoryStats.late`; the live app adds it to
  the link's ``late`` count per source).

Samples for which ``order_sensitive`` is false are used as they arrive, in any order
(the builders document why that is sound for each kind, e.g. a reference used only for
scoring, an ADS-B report carried to the scan time with its own velocity).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..ingest.types import arrival_order
from .records import Start, Step

__all__ = ["HistoryStats", "LaneHistory", "Rewindable", "restore_vars", "snapshot_vars"]


class Rewindable(Protocol):
    """What :class:`LaneHistory` needs of a step builder (and, without the first two, of
    an estimator: ``snapshot`` / ``restore``)."""

    @property
    def committed(self) -> float:
        """Vehicle time (s) up to which the items already returned are final: an
        order-sensitive sample at or before it would have changed them."""
        ...

    def order_sensitive(self, s: Any) -> bool:
        """True if ``s`` changes items depending on when it comes (an IMU or aiding
        sample the builder uses); False for samples used as they arrive."""
        ...

    def snapshot(self) -> Any:
        """Everything :meth:`restore` needs to come back to this moment (may be restored
        more than once)."""
        ...

    def restore(self, snap: Any) -> None: ...


# ----------------------------------------------------------------- snapshots of objects


class _Nested:
    """A field holding an object with its own ``snapshot`` / ``restore``."""

    __slots__ = ("obj", "snap")

    def __init__(self, obj: Any) -> None:
        self.obj = obj
        self.snap = obj.snapshot()


class _Rng:
    """A field holding a numpy Generator: the same object, its bit generator's state."""

    __slots__ = ("rng", "state")

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.state = rng.bit_generator.state


class _Appended:
    """An append-only list: the same list, its length."""

    __slots__ = ("lst", "n")

    def __init__(self, lst: list[Any]) -> None:
        self.lst = lst
        self.n = len(lst)


_LEAF = (int, float, str, bytes, bool, complex, type(None), np.ndarray, np.generic,
         frozenset, range)


_OWN = object()  # a leaf rule's "not mine": the value is copied as a container or kept


def _copy(v: Any, leaf: Callable[[Any], Any]) -> Any:
    """``v`` with its containers (list, dict, tuple, deque, set) and mutable dataclass
    instances copied all the way down, every other value through ``leaf`` (which returns
    ``_OWN`` for a value it does not handle: kept as it is)."""
    t = type(v)
    if t in _LEAF:
        return v
    if t is list:
        return [_copy(x, leaf) for x in v]
    if t is dict:
        return {k: _copy(x, leaf) for k, x in v.items()}
    if t is tuple:
        return tuple(_copy(x, leaf) for x in v)
    if t is deque:
        return deque((_copy(x, leaf) for x in v), v.maxlen)
    if t is set:
        return set(v)
    out = leaf(v)
    if out is not _OWN:
        return out
    if dataclasses.is_dataclass(v) and not isinstance(v, type) and \
            not type(v).__dataclass_params__.frozen:  # type: ignore[attr-defined]
        c = copy.copy(v)
        for f in dataclasses.fields(v):
            setattr(c, f.name, _copy(getattr(v, f.name), leaf))
        return c
    return v


def _freeze_leaf(v: Any) -> Any:
    if isinstance(v, np.random.Generator):
        return _Rng(v)
    if hasattr(v, "snapshot") and hasattr(v, "restore"):
        return _Nested(v)
    return _OWN


def _freeze(v: Any) -> Any:
    """A copy of ``v`` that later changes to ``v`` cannot reach: containers (list, dict,
    deque, set, tuple) copied all the way down, a mutable dataclass instance copied with
    its fields, a numpy Generator as its state, an object with ``snapshot`` as its
    snapshot. Anything else (numbers, strings, numpy arrays, frozen dataclasses such as
    the samples, models) is shared: it is never changed in place."""
    return _copy(v, _freeze_leaf)


def _thaw_leaf(v: Any) -> Any:
    t = type(v)
    if t is _Nested:
        v.obj.restore(v.snap)
        return v.obj
    if t is _Rng:
        v.rng.bit_generator.state = v.state
        return v.rng
    if t is _Appended:
        del v.lst[v.n:]
        return v.lst
    return _OWN


def _thaw(v: Any) -> Any:
    """The value to put back from :func:`_freeze`'s copy, copied again (a snapshot can
    be restored more than once)."""
    return _copy(v, _thaw_leaf)


def snapshot_vars(obj: Any, skip: Iterable[str] = (), appended: Iterable[str] = ()
                  ) -> dict[str, Any]:
    """A snapshot of ``obj``'s attributes for :func:`restore_vars`: each copied as
    :func:`_freeze` says, except those in ``skip`` (shared objects the owner never
    replaces: options, the source's parameters) and those in ``appended`` (lists only ever
    appended to, kept as their length: their cost does not grow with the run)."""
    skip = set(skip)
    app = set(appended)
    out: dict[str, Any] = {}
    for k, v in vars(obj).items():
        if k in skip:
            continue
        out[k] = _Appended(v) if k in app else _freeze(v)
    return out


def restore_vars(obj: Any, snap: dict[str, Any]) -> None:
    """Put ``obj``'s attributes back as :func:`snapshot_vars` saw them (the snapshot
    stays usable for another restore)."""
    for k, v in snap.items():
        setattr(obj, k, _thaw(v))


# ----------------------------------------------------------------- the lane's history


@dataclass
class HistoryStats:
    """What a lane's history did: ``rewinds`` (late samples applied at their time),
    ``restepped`` (items given to the estimators again by them), ``refed`` (samples fed
    to the builder again), ``late`` (late samples older than the history: skipped),
    ``deepest_s`` (the farthest rewind, s of vehicle time before the newest sample),
    ``seconds`` (wall time of the rewinds, restoring and re-stepping)."""

    rewinds: int = 0
    restepped: int = 0
    refed: int = 0
    late: int = 0
    deepest_s: float = 0.0
    seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


#: Samples the log keeps at most: beyond, its oldest checkpoint goes (a late sample older
#: than the next one is then skipped and counted).
MAX_LOG = 100_000


@dataclass
class _Checkpoint:
    seq: int  # samples of the log fed before it
    t_fed: float  # newest time of the order-sensitive samples fed before it (s)
    builder: Any
    estimators: list[Any]


def _item_t(it: Start | Step) -> float:
    return it.t0 if isinstance(it, Start) else it.t


def _order(e: tuple[float, int, Any]) -> tuple[float, bool, int]:
    """Time order of the log's entries (t, seq, sample): :func:`arrival_order`, then
    arrival."""
    return (*arrival_order(e[2]), e[1])


Dispatch = Callable[[Iterable[Start | Step], float], int]


class LaneHistory:
    """One lane's builder and estimators run on arrival with a history of ``horizon_s``
    s of vehicle time (module docstring). ``dispatch(items, quiet_upto)`` steps the
    estimators with ``items`` and hands the records of those after ``quiet_upto`` (s) to
    the sinks, returning how many steps it handed; :meth:`push` returns that count, or
    None when the sample was late beyond the history (skipped)."""

    def __init__(self, builder: Any, estimators: Sequence[Any], horizon_s: float,
                 dispatch: Dispatch) -> None:
        self.builder = builder
        self.estimators = list(estimators)
        self.horizon = float(horizon_s)
        self.dispatch = dispatch
        self.log: deque[tuple[float, int, Any]] = deque()
        self.ckpts: deque[_Checkpoint] = deque()
        self.seq = 0
        self.t_fed = -math.inf  # newest order-sensitive sample fed (s)
        self.t_out = -math.inf  # newest item handed to the sinks (s)
        self.quiet = -math.inf  # during a rewind: items up to this time are re-made
        self.t_ck = -math.inf  # the builder's committed time at the last checkpoint
        self.stats = HistoryStats()
        # the start: a sample that comes after a builder's first items but belongs before
        # them (e.g. in an attitude stream's alignment window) goes back to here
        self._checkpoint()

    def push(self, s: Any) -> int | None:
        """Feed one sample; a late one is applied at its time (or skipped: None)."""
        b = self.builder
        sens = b.order_sensitive(s)
        if sens and s.t <= b.committed:
            return self._late(s)
        return self._feed(s, sens)

    def _feed(self, s: Any, sens: bool) -> int:
        self.log.append((s.t, self.seq, s))
        self.seq += 1
        if len(self.log) > MAX_LOG:  # no checkpoint for that long (a builder that holds
            self.ckpts.popleft()  # its input, e.g. an attitude stream without an IMU)
            self._trim()
        if sens and s.t > self.t_fed:
            self.t_fed = s.t
        b = self.builder
        items = b.push(s)
        n = self._emit(items) if items else 0
        if items or (sens and b.committed != self.t_ck):  # (or steps closed without any)
            self._checkpoint()
        return n

    def flush(self) -> int:
        """The end of the stream: the builder's last items."""
        return self._emit(self.builder.flush())

    def _emit(self, items: Iterable[Start | Step]) -> int:
        items = list(items)
        n = self.dispatch(items, self.quiet)
        for it in items:
            t = _item_t(it)
            if t <= self.quiet:
                self.stats.restepped += isinstance(it, Step)
            elif t > self.t_out:
                self.t_out = t
        return n

    def _checkpoint(self) -> None:
        self.t_ck = self.builder.committed
        self.ckpts.append(_Checkpoint(self.seq, self.t_fed, self.builder.snapshot(),
                                      [e.snapshot() for e in self.estimators]))
        self._trim()

    def _trim(self) -> None:
        lim = self.t_fed - self.horizon
        ck = self.ckpts
        while len(ck) > 1 and ck[1].t_fed < lim:  # the next one serves every sample >= lim
            ck.popleft()
        s0 = ck[0].seq if ck else self.seq
        log = self.log
        while log and log[0][1] < s0:
            log.popleft()

    def _late(self, s: Any) -> int | None:
        ck = next((c for c in reversed(self.ckpts) if c.t_fed < s.t
                   or c.seq == 0), None)  # (the start serves any time)
        if ck is None:
            self.stats.late += 1
            return None
        w0 = time.perf_counter()
        st = self.stats
        st.rewinds += 1
        st.deepest_s = max(st.deepest_s, self.t_fed - s.t)
        self.builder.restore(ck.builder)
        for e, snap in zip(self.estimators, ck.estimators, strict=True):
            e.restore(snap)
        again = [e for e in self.log if e[1] >= ck.seq]
        again.append((s.t, self.seq, s))
        again.sort(key=_order)
        while self.log and self.log[-1][1] >= ck.seq:
            self.log.pop()
        while self.ckpts[-1] is not ck:
            self.ckpts.pop()
        self.t_fed = ck.t_fed
        self.t_ck = self.builder.committed
        st.refed += len(again)
        quiet, self.quiet = self.quiet, max(self.quiet, self.t_out)
        n = 0
        b = self.builder
        try:
            for _, _, x in again:
                n += self._feed(x, b.order_sensitive(x))
        finally:
            self.quiet = quiet
        st.seconds += time.perf_counter() - w0
        return n
