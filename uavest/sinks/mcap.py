"""MCAP recording sink: every channel of :mod:`uavest.sinks.foxglove`, written with
foxglove-sdk's MCAP writer (Foxglove's well-known protobuf schemas, so the app's 3-D, plot,
map and log panels work with no set-up; uavest's per-step quantities and raw samples as
protobuf messages of its own schema, :mod:`uavest.sinks.protobuf`, encoded in batches; the
rest as JSON with titled JSON schemas). Read recordings back with the ``mcap`` package
(:mod:`uavest.report.read`).

Durability: chunks (lz4) close when they reach ``chunk_size`` bytes (uncompressed) or
when ``flush_s`` seconds of wall time have passed since the last close, whichever comes
first (checked every 8th sample or record), so a recorder killed mid-run (SIGKILL, power
loss) loses at most about ``flush_s`` s of data: everything in the closed chunks stays
readable without the summary and footer (:func:`uavest.report.read.read_recording` falls
back to a sequential record scan that stops at the torn tail).

Metadata records (MCAP ``Metadata``, written at :meth:`McapSink.open`): ``run`` (command,
source, seed), ``filters`` (label -> resolved parameters as JSON), ``config`` (the run's
configuration as JSON), ``versions`` (package versions), ``recording`` (frames, units,
uavest channel-set version).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..engine.records import RunInfo
from .base import Sink
from .foxglove import DEFAULT_FRAME_RATE_HZ, FoxglovePublisher
from .foxglove.encode import _jsonable

__all__ = ["CHANNEL_SET_VERSION", "McapSink"]

#: Version of the channel set / message fields (``recording`` metadata).
CHANNEL_SET_VERSION = "2"


class McapSink(Sink):
    """Record a run to ``path`` (.mcap), plus ``<stem>.layout.json`` beside it.

    ``frame_rate_hz``: limit of the 3-D channels (``/tf/*``, ``/attitude/*/pose``) per
    estimator and per reference in Hz of data time (default
    :data:`~uavest.sinks.foxglove.DEFAULT_FRAME_RATE_HZ` = 15 Hz: the bodies in
    the 3-D view move at that rate; None or 0: every step). The per-step channels always
    carry every step.
    ``chunk_size``: target uncompressed chunk size in bytes; ``flush_s``: close the open
    chunk at least this often (s of wall time); ``compression``: ``"lz4"`` (default: the
    recorder's CPU 9-15 % lower than with zstd level 1, files about 20 % larger; both are
    MCAP's standard compressions, read by Foxglove and the ``mcap`` reader), ``"zstd"`` or
    None; ``compression_level``: zstd level (1: about a quarter cheaper than the library's
    default, and no larger; 0 = the library's default); ``compression_threads``: 0
    (default) compresses on the calling thread, no pool competing with the replay for a
    small machine's cores; ``spacing_m``: display offset
    between the bodies in the 3-D view (m); ``layout``: write the Foxglove layout beside
    the recording; ``overwrite``: replace an existing file; ``batch``: records and samples
    the publisher encodes together (the per-step channels are protobuf, encoded in
    batches: :mod:`uavest.sinks.protobuf`; every batch is written before a chunk closes,
    so ``flush_s`` still bounds what a killed recorder loses)."""

    def __init__(
        self,
        path: str | Path,
        frame_rate_hz: float | None = DEFAULT_FRAME_RATE_HZ,
        *,
        chunk_size: int = 256 * 1024,
        flush_s: float = 1.0,
        compression: str | None = "lz4",
        compression_level: int = 1,
        spacing_m: float = 2.0,
        layout: bool = True,
        overwrite: bool = True,
        batch: int = 4096,
        compression_threads: int = 0,
    ) -> None:
        self.path = Path(path)
        self.frame_rate_hz = frame_rate_hz
        self.chunk_size = int(chunk_size)
        self.flush_s = float(flush_s)
        self.compression = compression
        self.compression_level = int(compression_level)
        self.spacing_m = spacing_m
        self.write_layout = layout
        self.overwrite = overwrite
        self.batch = int(batch)
        self.compression_threads = int(compression_threads)
        self.writer = None
        self.pub: FoxglovePublisher | None = None
        self._last_flush = 0.0
        self.closed = False
        self.flushes = 0

    @property
    def layout_path(self) -> Path:
        """``<dir>/<stem>.layout.json`` beside the recording."""
        return self.path.with_name(self.path.stem + ".layout.json")

    def _ensure(self) -> FoxglovePublisher:
        if self.pub is None:
            import foxglove
            from foxglove.mcap import MCAPCompression, MCAPWriteOptions

            comp = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4,
                    None: None}[self.compression]
            self.path.parent.mkdir(parents=True, exist_ok=True)
            ctx = foxglove.Context()
            self.writer = foxglove.open_mcap(
                str(self.path), allow_overwrite=self.overwrite, context=ctx,
                writer_options=MCAPWriteOptions(
                    compression=comp, chunk_size=self.chunk_size, profile="",
                    compression_level=self.compression_level,
                    compression_threads=self.compression_threads))
            self.pub = FoxglovePublisher(ctx, spacing_m=self.spacing_m,
                                 frame_rate_hz=self.frame_rate_hz, batch=self.batch)
            self._last_flush = time.monotonic()
        return self.pub

    def _tick(self) -> None:
        now = time.monotonic()
        if now - self._last_flush >= self.flush_s:
            self.pub.flush()  # what the publisher holds goes into the chunk it closes
            self.writer.flush()
            self.flushes += 1
            self._last_flush = now

    # -- Sink -----------------------------------------------------------------------------
    def open(self, info: RunInfo) -> None:
        pub = self._ensure()
        d = _jsonable(info.as_dict())
        w = self.writer
        w.write_metadata("run", {"command": str(d["command"]), "source": str(d["source"]),
                                 "seed": str(d["seed"])})
        w.write_metadata("filters", {k: json.dumps(v, sort_keys=True)
                                     for k, v in d["filters"].items()})
        w.write_metadata("config", {k: json.dumps(v, sort_keys=True)
                                    for k, v in d["config"].items()})
        w.write_metadata("versions", {k: str(v) for k, v in d["versions"].items()})
        w.write_metadata("recording", {
            "channel_set_version": CHANNEL_SET_VERSION,
            "frames": "world = ENU; body_<name> = FLU; data NED/FRD converted with "
                      "q_enu_flu = q_ned2enu * q_ned_frd * q_frd2flu",
            "log_time": "data time t (s, source clock) in ns",
            "writer": "foxglove-sdk open_mcap", "chunk_size": str(self.chunk_size),
            "flush_s": str(self.flush_s)})
        pub.open(info)
        self.writer.flush()  # the head of the file is durable at once
        self._last_flush = time.monotonic()

    def sample(self, s) -> None:
        """A sample or a record into the publisher's queue (its sample() / record() do the
        same; one call level less on the hot path, which runs cold between the filters'
        steps)."""
        pub = self.pub or self._ensure()
        q = pub._queue
        q.append(s)
        n = len(q)
        if n >= pub.batch:
            pub.flush()
        elif not n & 7:  # the clock read every 8th call (tens of ms at most)
            self._tick()

    def start(self, label, t0, x0, P0) -> None:
        self._ensure().start(label, t0, x0, P0)

    record = sample  # records and samples share the queue, in order

    def close(self) -> None:
        if self.closed or self.pub is None:
            self.closed = True
            return
        self.closed = True
        self.pub.close()
        self.writer.close()
        if self.write_layout:
            from ..layouts import layout_text

            pub = self.pub
            follow = pub.ref_frames.get(pub.best_ref) if pub.best_ref else None
            kind = pub.kind or "attitude"
            att = [lab for lab in pub.labels if lab not in pub.track_labels]
            if follow is None and att and kind.startswith("attitude"):
                follow = f"body_{att[0]}"
            self.layout_path.write_text(layout_text(
                pub.track_labels if kind == "radar" else att, kind, follow,
                max(pub.state_dim, 1), pub.track_labels))

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic so far."""
        return dict(self.pub.counts) if self.pub else {}
