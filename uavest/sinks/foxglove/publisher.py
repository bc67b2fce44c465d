"""The channels uavest publishes to Foxglove (MCAP recordings and the live WebSocket view),
and the one place that turns samples and records into their messages.

:class:`FoxglovePublisher` owns a ``foxglove.Context``; the MCAP sink opens a writer on it, the
live sink a WebSocket server, so both carry exactly the same channels and messages. See
``docs/recording.md`` for the channel list.

The channels per domain: :mod:`.frames` (NED/FRD -> ENU/FLU, ``/tf``, poses, markers,
the vehicle position), :mod:`.attitude` (raw samples, references, estimates, health,
errors), :mod:`.state` (generic vector states), :mod:`.radar` (scans, true targets,
tracks), on the channels of :mod:`.channels`, with the JSON schemas of :mod:`.schemas`.

Frames. Our data are NED (navigation) / FRD (body); Foxglove's 3-D panel is ENU / FLU
(x east, y north, z up; body x forward, y left, z up); see :mod:`.frames`.

Times. ``log_time`` of every message is the data time ``t`` (s, the source's clock: vehicle
time since boot for logs) in nanoseconds; JSON messages also carry ``t`` in seconds.

uavest's per-step attitude channels and raw samples are protobuf messages of its own schema
(:mod:`uavest.sinks.protobuf`); its other channels are JSON with a JSON schema with a
``title`` (``uavest.*``), NaN written as null.
"""

from __future__ import annotations

from typing import Any

from ...engine.records import RunInfo, ScanRecord, StepRecord
from .attitude import AttitudeChannels
from .channels import ChannelSet, Scene
from .encode import _clean, _jsonable
from .frames import Frames
from .radar import RadarChannels
from .state import StateChannels

__all__ = ["FoxglovePublisher"]


class FoxglovePublisher:
    """Turns samples and records into Foxglove messages on channels of one context.

    ``spacing_m``: the 3-D view puts filter i's body frame ``spacing_m * (i + 1)`` m east
    of the vehicle position (references at the position itself), so the bodies stand side
    by side instead of on top of each other (a display offset only: ``PoseInFrame`` and
    the per-step channels carry the true position). ``frame_rate_hz``: limit of the 3-D
    channels (``/tf/*``, ``/attitude/*/pose``) per estimator in data time (None: every
    step); the per-step channels always carry every step. ``history``: points of a track's
    history line. ``only_subscribed``: skip building messages for channels nobody
    listens to (the live view). ``batch``: :meth:`sample` and :meth:`record` queue their
    argument; every ``batch`` calls (1: at once, the live view) :meth:`flush` handles the
    queue in order and encodes the per-step attitude channels and the raw samples
    (protobuf, :mod:`uavest.sinks.protobuf`) vectorised over it; the recorder also
    flushes before it closes a chunk, so nothing waits longer than a chunk."""

    def __init__(self, context, *, spacing_m: float = 2.0, frame_rate_hz: float | None = None,
                 history: int = 60, only_subscribed: bool = False, batch: int = 1) -> None:
        self.ctx = context
        self.batch = max(int(batch), 1)
        self._queue: list = []  # samples and records not yet handled, in order
        self._kinds: dict[type, int] = {}  # queued item type -> 0 sample, 1 raw, 2 record
        self.spacing = float(spacing_m)
        self.history = int(history)
        self.only_subscribed = only_subscribed
        self.chans = ChannelSet(context, only_subscribed)
        self.scene = Scene()
        self.frames = Frames(self.chans, self.scene, 1.0 / frame_rate_hz if frame_rate_hz
                             else 0.0)
        self.attitude = AttitudeChannels(self.chans, self.scene, self.frames, self.spacing)
        self.state = StateChannels(self.chans, self.scene, self.attitude)
        self.radar = RadarChannels(self.chans, self.scene, self.history)

    # -- what the sinks read --------------------------------------------------------------
    @property
    def channels(self) -> dict[str, Any]:
        """The channels made so far, by topic."""
        return self.chans.channels

    @property
    def counts(self) -> dict[str, int]:
        """Messages logged per topic."""
        return self.chans.counts

    @property
    def kind(self) -> str | None:
        """``"attitude"`` | ``"radar"`` | ``"attitude+radar"`` | ``"state"`` (None: nothing
        seen yet)."""
        return self.scene.kind

    @property
    def labels(self) -> list[str]:
        """Estimator and tracker labels in order of appearance."""
        return self.scene.labels

    @property
    def info(self) -> dict | None:
        return self.scene.info

    @property
    def track_labels(self) -> list[str]:
        return self.radar.track_labels

    @property
    def ref_frames(self) -> dict[str, str]:
        """Reference source -> its body frame."""
        return self.attitude.ref_frames

    @property
    def best_ref(self) -> str | None:
        """The reference the errors are computed against (truth first)."""
        return self.attitude.best_ref

    @property
    def state_dim(self) -> int:
        return self.state.state_dim

    def _channel(self, topic: str, schema: str):
        return self.chans.channel(topic, schema)

    def log_event(self, t: float, level: str, name: str, message: str) -> None:
        """An event on ``/log`` (foxglove.Log): level ``info``/``warning``/``error``."""
        self.chans.log_event(t, level, name, message)

    # -- run ------------------------------------------------------------------------------
    def open(self, info: RunInfo) -> None:
        self.scene.info = _clean(_jsonable(info.as_dict()))
        self.chans.json("/run/info", "uavest.RunInfo", 0.0, self.scene.info)

    def start(self, label: str, t0: float, x0, P0) -> None:
        self.flush()  # (the start event after what came before it on /log)
        self.scene.label(label)
        self.log_event(t0, "info", label, f"start {label} at t = {t0:.3f} s")

    # -- samples and records --------------------------------------------------------------
    def sample(self, s) -> None:
        """Queue a sample or a record (handled with the batch, in order)."""
        q = self._queue
        q.append(s)
        if len(q) >= self.batch:
            self.flush()

    record = sample  # records and samples share the queue

    def _sample(self, s) -> None:
        """A queued sample other than IMU / magnetometer (:meth:`flush` puts those in their
        buffers itself)."""
        name = type(s).__name__
        if name == "AttitudeRef":
            self.attitude.reference(s)
        elif name == "PositionSample":
            self.frames.position(s)
        elif name == "RadarScanSample" or (hasattr(s, "Z") and hasattr(s, "model")):
            self.radar.scan_sample(s)
        elif name == "StateSample":
            self.state.sample(s)
        elif name == "NavAnchor":
            self.chans.json("/navigation/anchor", "uavest.NavAnchor", s.t, {
                "t": s.t, "lat_lon_alt": [s.lat, s.lon, s.alt], "source": s.source,
                "reason": s.reason, "geodesy": s.geodesy})

    def _record(self, rec: StepRecord | ScanRecord) -> None:
        if type(rec) is not StepRecord:
            if isinstance(rec, ScanRecord):
                self.radar.scan(rec)
                return
        if self.scene.kind == "state":
            self.state.record(rec)
            return
        self.attitude.record(rec)

    def flush(self) -> None:
        """Encode and log everything buffered: raw samples first (the references the
        errors need), then each estimator's estimates and health, then the errors of the
        steps the chosen reference has reached."""
        q = self._queue
        if q:
            # the queued calls in order, in one loop (each sink call of the run only
            # appends: cheap between the filters' steps, which evict the recorder's
            # working set from the caches)
            self._queue = []
            sample, record = self._sample, self._record
            kinds, raw = self._kinds, self.attitude.raw
            for it in q:
                tp = type(it)
                k = kinds.get(tp)
                if k is None:
                    k = kinds[tp] = (2 if tp is StepRecord or issubclass(tp, ScanRecord) else
                                     1 if tp.__name__ in ("ImuSample", "MagSample") else 0)
                if k == 1:  # a raw sample: into its buffer (the hot case, inline)
                    b = raw.get((tp, it.source))
                    if b is None:
                        b = self.attitude.raw_buffer(it)
                    b.append(it)
                elif k == 2:
                    record(it)
                else:
                    sample(it)
        self.frames.flush()
        self.attitude.flush_samples()
        self.attitude.flush_lanes()
        self.attitude.drain(final=False)

    def close(self) -> None:
        self.flush()
        self.attitude.drain(final=True)
