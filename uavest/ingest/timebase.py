"""Vehicle-clock handling: 32-bit wrap, reboots (resets), jumps, per-stream order.

See docs/ingest.md "Timestamps".  All times are seconds.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

from .types import IngestStats

WRAP_MS32 = 2**32 * 1e-3  # s, period of a uint32 millisecond counter (~49.7 days)
RESET_JUMP = 2.0  # s, backwards jump (vs. newest time of the system) that may be a reboot
FORWARD_JUMP_NO_RX = 2.0  # s, forward jump held for confirmation when no receive time
# (one corrupted DataFlash TimeUS must not move the clock: a real gap is confirmed by the
# next messages)
FORWARD_JUMP_RX = 10.0  # s, forward jump beyond the receive-time elapsed
CONFIRM_SPAN = 60.0  # s, largest step between held messages that still confirm each other
CONFIRM = 3  # consecutive consistent messages needed to accept a reset/jump
JITTER = 1.0  # s, allowed disorder between message types of one system


@dataclass
class _Pending:
    raw: float
    rx: float | None
    payload: object


@dataclass
class VehicleClock:
    """The clock of one system (MAVLink sysid, or the single DataFlash/ULog writer).

    ``push(raw, rx, payload)`` takes a raw vehicle time (s since boot as read),
    the log receive time (s, or None) and an opaque payload and returns the list
    of ``(t, payload)`` that are now accepted, with ``t`` on a monotonic clock
    (raw + offset; offset grows at each detected reboot).  Suspicious jumps are
    held until ``CONFIRM`` consistent messages confirm them; otherwise the held
    payloads are returned by ``take_rejected()`` for counting.
    """

    stats: IngestStats
    offset: float = 0.0
    max_raw: float | None = None
    rx_at_max: float | None = None
    last_out: float | None = None
    last_out_rx: float | None = None
    _ms_last: float | None = None
    _ms_wraps: int = 0
    _pending: list[_Pending] = field(default_factory=list)
    _pending_kind: str = ""
    _rejected: list[tuple[str, object]] = field(default_factory=list)

    def unwrap_ms32(self, t: float) -> float:
        """Unwrap a time derived from a uint32 ms counter (s)."""
        if self._ms_last is not None and t < self._ms_last - WRAP_MS32 / 2:
            self._ms_wraps += 1
            self.stats.time_wrap += 1
        self._ms_last = t
        return t + self._ms_wraps * WRAP_MS32

    def map_rx(self, rx: float | None) -> float | None:
        """Vehicle time for a message without a time field, from its receive time.

        = latest accepted vehicle time of this system + receive time elapsed since
        that message was received (0 if no receive times).  None if nothing seen yet.
        """
        if self.last_out is None:
            return None
        if rx is None or self.last_out_rx is None:
            return self.last_out
        return self.last_out + max(0.0, rx - self.last_out_rx)

    def take_rejected(self) -> list[tuple[str, object]]:
        r, self._rejected = self._rejected, []
        return r

    def _accept(self, raw: float, rx: float | None) -> float:
        if self.max_raw is None or raw > self.max_raw:
            self.max_raw, self.rx_at_max = raw, rx
        t = raw + self.offset
        if self.last_out is None or t >= self.last_out:
            self.last_out, self.last_out_rx = t, rx
        return t

    def _reject_pending(self) -> None:
        kind = "time_backwards" if self._pending_kind == "back" else "out_of_range"
        self._rejected.extend((kind, p.payload) for p in self._pending)
        self._pending = []

    def _confirm_pending(self) -> list[tuple[float, object]]:
        pend, self._pending = self._pending, []
        if self._pending_kind == "back":
            self.stats.time_reset += 1
            first = pend[0]
            gap = 1e-3
            if first.rx is not None and self.rx_at_max is not None:
                gap = max(gap, first.rx - self.rx_at_max)
            new_base = min(p.raw for p in pend)
            self.offset = (self.max_raw + self.offset) + gap - new_base
            self.max_raw = None
        return [(self._accept(p.raw, p.rx), p.payload) for p in pend]

    def push(self, raw: float, rx: float | None, payload: object) -> list[tuple[float, object]]:
        if self.max_raw is None:
            return [(self._accept(raw, rx), payload)]
        back = raw < self.max_raw - RESET_JUMP
        if rx is not None and self.rx_at_max is not None:
            fwd = raw > self.max_raw + max(0.0, rx - self.rx_at_max) + FORWARD_JUMP_RX
        else:
            fwd = raw > self.max_raw + FORWARD_JUMP_NO_RX
        if not (back or fwd):
            if self._pending:
                self._reject_pending()
            return [(self._accept(raw, rx), payload)]
        kind = "back" if back else "fwd"
        if self._pending:
            last = self._pending[-1].raw
            lo = min(p.raw for p in self._pending)
            if kind == self._pending_kind and lo - JITTER <= raw <= last + CONFIRM_SPAN:
                self._pending.append(_Pending(raw, rx, payload))
                if len(self._pending) >= CONFIRM and max(p.raw for p in self._pending) > lo:
                    return self._confirm_pending()
                return []
            self._reject_pending()
        self._pending_kind = kind
        self._pending.append(_Pending(raw, rx, payload))
        return []

    def flush(self) -> list[tuple[float, object]]:
        """At end of input: confirm a held jump seen >= 2 times with progress, else reject."""
        if not self._pending:
            return []
        if len(self._pending) >= 2 and max(p.raw for p in self._pending) > self._pending[0].raw:
            return self._confirm_pending()
        self._reject_pending()
        return []


MAX_STREAMS = 4096  # streams remembered by StreamGate (ADS-B ICAO addresses are streams)
MAX_SAME_TIME = 256  # contents remembered at one time of a multi-item stream (detections)


@dataclass
class StreamGate:
    """Per-stream monotonicity: drop duplicates and samples going backwards.

    At most :data:`MAX_STREAMS` streams are remembered (least recently used forgotten), so
    a flood of made-up ADS-B addresses cannot grow memory without bound.
    """

    stats: IngestStats
    last: OrderedDict = field(default_factory=OrderedDict)  # key -> (t, content)

    def _remember(self, key: tuple, value) -> None:
        self.last[key] = value
        self.last.move_to_end(key)
        if len(self.last) > MAX_STREAMS:
            self.last.popitem(last=False)

    def admit_repeat(
        self, key: tuple, t: float, content: tuple, source: str, count: bool = True,
        slack: float = 1.5,
    ) -> bool:
        """Like :meth:`admit` for reports re-sent with a coarse age (ADS-B ``tslc``, whole s).

        The same content within ``slack`` s of the last admitted time is a ``duplicate``
        (a re-sent report whose age rounding moved its time); otherwise as :meth:`admit`.
        """
        prev = self.last.get(key)
        if prev is not None and abs(t - prev[0]) < slack and _same(content, prev[1]):
            if count:
                self.stats.bad("duplicate", source)
            return False
        return self.admit(key, t, content, source, count)

    def admit_multi(
        self, key: tuple, t: float, content: tuple, source: str, count: bool = True
    ) -> bool:
        """Like :meth:`admit` for streams with several items at one time (a scan's detections).

        An item at the stream's last time is admitted unless its content was already seen at
        that time (then ``duplicate``); an older time is ``time_backwards``.
        """
        prev = self.last.get(key)
        if prev is not None:
            t0, seen = prev
            if t < t0:
                if count:
                    self.stats.bad("time_backwards", source)
                return False
            if t == t0:
                if any(_same(content, c) for c in seen):
                    if count:
                        self.stats.bad("duplicate", source)
                    return False
                if len(seen) < MAX_SAME_TIME:
                    seen.append(content)
                self.last.move_to_end(key)
                return True
        self._remember(key, (t, [content]))
        return True

    def admit(self, key: tuple, t: float, content: tuple, source: str, count: bool = True) -> bool:
        """True if ``t`` (s) is newer than the last admitted time of stream ``key``.

        Otherwise counts a duplicate (same time and content) or time_backwards,
        unless ``count`` is False (secondary item of a message already counted).
        """
        prev = self.last.get(key)
        if prev is not None and t <= prev[0]:
            if not count:
                return False
            if t == prev[0] and _same(content, prev[1]):
                self.stats.bad("duplicate", source)
            else:
                self.stats.bad("time_backwards", source)
            return False
        self._remember(key, (t, content))
        return True


def _same(a: tuple, b: tuple) -> bool:
    import numpy as np

    if len(a) != len(b):
        return False
    for x, y in zip(a, b, strict=True):
        if x is None or y is None:
            if x is not y:
                return False
        elif not np.array_equal(x, y):
            return False
    return True


UNIX_US_MIN = 1e15  # us, a time_usec at least this large is UNIX time (~2001), not boot time
RETIME_TOL = 1.0  # s, largest |UNIX-mapped time - arrival time| that trusts the UNIX time


def retime_unix(t_unix: float, rx: float | None, clock: VehicleClock,
                unix_offset: float | None, floor: float = -float("inf")) -> float | None:
    """Vehicle time (s) of a message stamped with a receiver's UNIX time ``t_unix`` (s),
    such as ArduPilot's GPS_RAW_INT (``time_usec`` = GNSS epoch time), without moving
    ``clock`` (a UNIX stamp never confirms a reboot or a jump).

    * With the system's UNIX - boot offset (s, from SYSTEM_TIME) the UNIX time mapped
      onto the boot clock, ``t_unix - unix_offset``, when it lies within
      :data:`RETIME_TOL` of the arrival (else the receiver's and the autopilot's clocks
      disagree, e.g. by the leap seconds, and the arrival is used);
    * otherwise the arrival: ``clock.map_rx(rx)`` (newest vehicle time of the system +
      receive time elapsed since it);
    * never before ``floor`` (s: the newest time already released in order by the reader,
      so a fix older than a short reorder window is stamped at its edge instead of being
      dropped as ``late``; -inf when the reader releases on arrival, where the engine's
      history applies a late fix at its own time).

    None when the system has no vehicle time yet and no offset.
    """
    t_arr = clock.map_rx(rx) if clock.last_out is not None else None
    t = None
    if unix_offset is not None:
        t_fix = t_unix - unix_offset
        if t_arr is None or abs(t_fix - t_arr) <= RETIME_TOL:
            t = t_fix
    if t is None:
        t = t_arr
    if t is None:
        return None
    return max(t, floor)


RX_TOL = 1.0  # s, receive-time step beyond which a message's receive time is examined
RX_LOOKAHEAD = 4  # messages after it that decide whether a receive-time step is real


class RxFilter:
    """Receive times (a tlog's 8-byte record times) checked against their neighbours.

    A receive time more than :data:`RX_TOL` s away from the previous good one is a real
    step (a link gap, a concatenated log) when the next :data:`RX_LOOKAHEAD` messages
    agree with it, and an **outlier** (one corrupted record time: one flipped bit of the
    top byte moves it by centuries) when they agree with the previous one instead: it is
    then replaced by the previous good receive time and counted ``time_outlier`` (the
    message itself is kept; its vehicle time is not affected). Non-finite or negative
    receive times are outliers too. ``filter(pairs)`` wraps an iterator of
    ``(message, rx)``; it delays messages by at most :data:`RX_LOOKAHEAD` messages.
    """

    def __init__(self, stats: IngestStats) -> None:
        self.stats = stats
        self.prev: float | None = None

    def _decide(self, rx: float | None, nxt: list[float]) -> float | None:
        if rx is None:
            return None
        bad = not (rx >= 0.0 and rx < 1e11)  # NaN, negative, beyond the year 5000
        if not bad and self.prev is not None and abs(rx - self.prev) > RX_TOL:
            agree_self = sum(abs(x - rx) <= RX_TOL for x in nxt)
            agree_prev = sum(abs(x - self.prev) <= RX_TOL for x in nxt)
            bad = agree_prev > agree_self
        if bad:
            self.stats.bad("time_outlier", "rx")
            return self.prev
        self.prev = rx
        return rx

    def filter(self, pairs):
        from collections import deque

        buf: deque = deque()
        for msg, rx in pairs:
            buf.append((msg, rx))
            if len(buf) > RX_LOOKAHEAD:
                m, r = buf.popleft()
                nxt = [x for _, x in buf if x is not None]
                yield m, self._decide(r, nxt)
        while buf:
            m, r = buf.popleft()
            nxt = [x for _, x in buf if x is not None]
            yield m, self._decide(r, nxt)
