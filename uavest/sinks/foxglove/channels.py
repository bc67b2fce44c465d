"""The channels of one ``foxglove.Context`` (made on first use, counted per topic) and
what every domain shares: :class:`Scene` (what kind of run this is, the estimator labels).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import foxglove
from foxglove import channels as fch
from foxglove.messages import Log, LogLevel

from .. import protobuf as pb
from .encode import _clean, _ns, _ts
from .schemas import SCHEMAS

__all__ = ["ChannelSet", "Scene"]


@dataclass
class Scene:
    """What the run has shown so far: ``kind`` (``"attitude"`` | ``"radar"`` |
    ``"attitude+radar"`` | ``"state"``, None before the first sample or record), the
    estimator labels in order of appearance, and the run's info (``/run/info``)."""

    kind: str | None = None
    labels: list[str] = field(default_factory=list)
    info: dict | None = None

    def label(self, lab: str) -> None:
        """Note estimator ``lab`` (once, in order)."""
        if lab not in self.labels:
            self.labels.append(lab)


class ChannelSet:
    """The channels on ``context`` by topic, made on first use from a schema name
    (``wk:<Foxglove message>`` protobuf encoded here, ``pb:<uavest message>``,
    ``uavest.<JSON schema>``, or a Foxglove SDK channel name), and the messages logged per
    topic (:attr:`counts`). ``only_subscribed``: :meth:`want` gives None for a channel
    nobody listens to (the live view)."""

    def __init__(self, context, only_subscribed: bool) -> None:
        self.ctx = context
        self.only_subscribed = only_subscribed
        self.channels: dict[str, Any] = {}
        self.counts: dict[str, int] = {}

    def channel(self, topic: str, schema: str):
        ch = self.channels.get(topic)
        if ch is None:
            if schema.startswith("wk:"):  # a well-known schema, messages encoded here
                ch = foxglove.Channel(topic, schema=getattr(foxglove.messages, schema[3:])
                                      .get_schema(), message_encoding="protobuf",
                                      context=self.ctx)
            elif schema.startswith("pb:"):
                ch = foxglove.Channel(topic, schema=pb.schema(schema[3:]),
                                      message_encoding="protobuf", context=self.ctx)
            elif schema.startswith("uavest."):
                ch = foxglove.Channel(topic, schema=SCHEMAS[schema], context=self.ctx)
            else:
                ch = getattr(fch, schema + "Channel")(topic, context=self.ctx)
            self.channels[topic] = ch
        return ch

    def want(self, topic: str, schema: str):
        ch = self.channel(topic, schema)
        if self.only_subscribed and not ch.has_sinks():
            return None
        return ch

    def json(self, topic: str, schema: str, t: float, msg: dict) -> None:
        ch = self.want(topic, schema)
        if ch is not None:
            try:
                data = json.dumps(msg, allow_nan=False)
            except ValueError:  # a NaN/inf somewhere (a diverged filter): write null
                data = json.dumps(_clean(msg), allow_nan=False)
            ch.log(data.encode(), log_time=_ns(t))
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def text(self, topic: str, schema: str, t: float, text: str) -> None:
        """Log JSON text made by the caller (the hot path)."""
        ch = self.want(topic, schema)
        if ch is not None:
            ch.log(text.encode(), log_time=_ns(t))
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def pb(self, topic: str, schema: str, t: float, build) -> None:
        ch = self.want(topic, schema)
        if ch is not None:
            ch.log(build(), log_time=_ns(t))
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def log(self, ch, topic: str, data: bytes, ns: int) -> None:
        """Log JSON bytes on a channel made by :meth:`channel` (the wrapper's checks
        skipped: ``foxglove.Channel.base.log``)."""
        ch.base.log(data, ns)
        c = self.counts
        c[topic] = c.get(topic, 0) + 1

    def log_many(self, ch, topic: str, msgs: list[bytes], ns: list[int]) -> None:
        log = ch.base.log
        for m, t in zip(msgs, ns, strict=True):
            log(m, t)
        c = self.counts
        c[topic] = c.get(topic, 0) + len(msgs)

    def log_event(self, t: float, level: str, name: str, message: str) -> None:
        """An event on ``/log`` (foxglove.Log): level ``info``/``warning``/``error``."""

        lvl = {"info": LogLevel.Info, "warning": LogLevel.Warning,
               "error": LogLevel.Error}[level]
        self.pb("/log", "Log", t, lambda: Log(
            timestamp=_ts(t), level=lvl, message=message, name=name, file="uavest", line=0))
