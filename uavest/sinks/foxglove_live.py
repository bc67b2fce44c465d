"""Live view: a Foxglove WebSocket server (foxglove-sdk, protocol ``foxglove.sdk.v1``) on
loopback publishing the channels of :mod:`uavest.sinks.foxglove` (the same
channels and messages as the MCAP recording) while a run goes on. Open Foxglove ->
*Open connection* -> *Foxglove WebSocket* ``ws://127.0.0.1:8765`` and import the layout
``uavest/layouts/attitude.json`` (or ``radar.json``).

Messages are built only for channels a client subscribed to, so an idle server costs
almost nothing."""

from __future__ import annotations

import time

from ..engine.records import RunInfo, ScanRecord, StepRecord
from .base import Sink
from .foxglove import DEFAULT_FRAME_RATE_HZ, FoxglovePublisher

__all__ = ["FoxgloveLiveSink"]


class FoxgloveLiveSink(Sink):
    """Serve the run live on ``ws://host:port`` (``port=0``: any free port, see
    :attr:`port`). The server starts at construction, so a client can connect before the
    run; ``wait_for_client`` s: at :meth:`open`, wait up to that long for a subscriber.
    ``frame_rate_hz`` as :class:`~uavest.sinks.mcap.McapSink`; ``linger_s``: keep serving
    that long after the run before :meth:`close` stops the server."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        name: str = "uavest",
        frame_rate_hz: float | None = DEFAULT_FRAME_RATE_HZ,
        wait_for_client: float = 0.0,
        linger_s: float = 0.0,
        spacing_m: float = 2.0,
    ) -> None:
        import foxglove

        self.ctx = foxglove.Context()
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.ctx)
        self.host = host
        self.pub = FoxglovePublisher(self.ctx, spacing_m=spacing_m, frame_rate_hz=frame_rate_hz,
                             only_subscribed=True)
        self.wait_for_client = wait_for_client
        self.linger_s = linger_s
        self.closed = False

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self.server.port)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def open(self, info: RunInfo) -> None:
        # /run/info is advertised first; wait for someone to subscribe to anything
        self.pub._channel("/run/info", "uavest.RunInfo")
        end = time.monotonic() + self.wait_for_client
        while time.monotonic() < end and not any(
                c.has_sinks() for c in self.pub.channels.values()):
            time.sleep(0.05)
        self.pub.open(info)

    def sample(self, s) -> None:
        self.pub.sample(s)

    def start(self, label, t0, x0, P0) -> None:
        self.pub.start(label, t0, x0, P0)

    def record(self, rec: StepRecord | ScanRecord) -> None:
        self.pub.record(rec)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.pub.close()
        if self.linger_s > 0:
            time.sleep(self.linger_s)
        self.server.stop()
