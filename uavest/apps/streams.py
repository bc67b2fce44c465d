"""Achieved rate of every stream the live estimator asked the vehicle for.

After the stream requests (``SET_MESSAGE_INTERVAL``, fallback ``REQUEST_DATA_STREAM``) the
vehicle may serve a stream at the rate asked, slower, or not at all (a vehicle without
ADS-B traffic, an autopilot that has no OBSTACLE_DISTANCE_3D source, PX4 and SIMSTATE).
:func:`achieved_rates` compares, per requested stream, the requested rate with the rate
measured by the link over its rate window (the link's receive times, 5 s), and
:meth:`StreamRate.line` says it on one line; ``uavest run`` prints one line per stream
once the window has passed (or at the end of a shorter run) and its JSON records them
(``link.streams``).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["StreamRate", "achieved_rates", "mean_rates"]

#: Below this fraction of the requested rate a stream is ``low``.
MIN_FRACTION = 0.8


@dataclass(frozen=True)
class StreamRate:
    """One requested stream: ``requested_hz``, ``achieved_hz`` (measured over
    ``window_s`` s of receive time), ``method`` of the request, ``ack`` (the
    COMMAND_ACK's MAV_RESULT, None without an answer) and ``status``: ``ok`` (at least
    :data:`MIN_FRACTION` of the request), ``low`` or ``missing`` (none received)."""

    name: str
    requested_hz: float
    achieved_hz: float
    method: str
    ack: int | None
    window_s: float
    status: str

    def line(self) -> str:
        """The one-line report: ``missing: X (requested N Hz, none received; method)``
        or ``stream X: N Hz requested, M Hz achieved[, low] (method)``."""
        if self.status == "missing":
            return (f"missing: {self.name} (requested {self.requested_hz:g} Hz, none "
                    f"received; {self.method})")
        low = ", low" if self.status == "low" else ""
        return (f"stream {self.name}: {self.requested_hz:g} Hz requested, "
                f"{self.achieved_hz:.1f} Hz achieved{low} ({self.method})")

    def as_dict(self) -> dict:
        return {"requested_hz": self.requested_hz, "achieved_hz": self.achieved_hz,
                "method": self.method, "ack": self.ack, "window_s": self.window_s,
                "status": self.status}


def achieved_rates(stream_status: dict, rates: dict[str, float], window_s: float,
                   min_fraction: float = MIN_FRACTION) -> list[StreamRate]:
    """Per requested stream (``stream_status``: name -> the link's ``StreamStatus``, in
    request order) its achieved rate from ``rates`` (name -> Hz measured by the link)."""
    out = []
    for name, st in stream_status.items():
        hz = float(rates.get(name, 0.0))
        req = float(st.requested_hz)
        status = "missing" if hz <= 0.0 else "low" if hz < min_fraction * req else "ok"
        out.append(StreamRate(name, req, hz, str(st.method), st.ack, float(window_s), status))
    return out


def mean_rates(counts: dict[str, int], names, duration_s: float) -> dict[str, float]:
    """Mean Hz over the whole run of each of ``names`` from the messages counted
    (``counts``: name -> messages the link accepted), over ``duration_s`` s."""
    d = max(float(duration_s), 1e-9)
    return {n: counts.get(n, 0) / d for n in names}
