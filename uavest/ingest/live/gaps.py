"""Link gaps seen by the live link's consumer: ``link_lost`` after ``gap_timeout`` s
without a vehicle message (seen while waiting, or afterwards from the receive times of
two messages), ``link_restored`` at the next message. Times in seconds (UNIX receive
time of the messages)."""

from __future__ import annotations

from ..types import LinkEvent


class GapWatch:
    """The gap state of one link's message stream (``source``: the connection string)."""

    def __init__(self, gap_timeout: float, source: str) -> None:
        self.gap_timeout = gap_timeout
        self.source = source
        self.gaps = 0
        self.in_gap = False
        self.prev_rx: float | None = None

    def idle(self, quiet_s: float) -> LinkEvent | None:
        """No message for ``quiet_s`` s: a ``link_lost`` event when that opens a gap."""
        if self.in_gap or quiet_s <= self.gap_timeout:
            return None
        self.in_gap = True
        self.gaps += 1
        return LinkEvent(0.0, "link_lost", start=self.prev_rx, count=self.gaps,
                         detail=f"no message for {self.gap_timeout:g} s", source=self.source)

    def message(self, rx: float) -> list[LinkEvent]:
        """A message received at ``rx``: the events it implies, in order (a gap the
        consumer was too busy to see while it lasted, then its end)."""
        out = []
        prev = self.prev_rx
        if prev is not None and not self.in_gap and rx - prev > self.gap_timeout:
            self.in_gap = True
            self.gaps += 1
            out.append(LinkEvent(0.0, "link_lost", start=prev, count=self.gaps,
                                 source=self.source))
        if self.in_gap:
            self.in_gap = False
            out.append(LinkEvent(0.0, "link_restored", start=prev, end=rx, count=self.gaps,
                                 detail=f"gap of {rx - (prev or rx):.2f} s",
                                 source=self.source))
        self.prev_rx = rx
        return out
