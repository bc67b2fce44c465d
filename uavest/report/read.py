"""Reading a uavest recording back with the ``mcap`` package (independently of the
recorder): channels with their schemas, message counts, JSON channels decoded, the
well-known protobuf channels decodable on demand, MCAP metadata records.

A complete file and a file torn by a killed recorder are read the same way: a
sequential scan of the records (``mcap.stream_reader.StreamReader``) that decompresses
every chunk and stops at the first incomplete record, so every message of every closed
chunk is recovered; ``Recording.truncated`` tells whether the file ended early (no
footer)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from .protowire import ProtoDecoder

__all__ = ["Recording", "read_recording"]


@dataclass
class Recording:
    """A recording read back.

    ``schemas``: topic -> (schema name, schema encoding, message encoding); ``counts``:
    topic -> messages; ``json``: topic -> decoded messages of JSON channels and of
    uavest's own protobuf channels (in file order; NaN and infinities as None); ``raw``:
    topic -> [(log_time ns, bytes)] of the other channels; ``metadata``: record name ->
    dict; ``chunks``: chunks read; ``truncated``: the file has no footer (writer
    killed)."""

    path: Path
    schemas: dict[str, tuple[str, str, str]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    json: dict[str, list[dict]] = field(default_factory=dict)
    raw: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    log_times: dict[str, list[int]] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    schema_data: dict[str, bytes] = field(default_factory=dict)
    chunks: int = 0
    truncated: bool = False
    error: str = ""
    _own: dict = field(default_factory=dict, repr=False)
    _decoders: dict = field(default_factory=dict, repr=False)

    def topics(self, prefix: str = "", suffix: str = "") -> list[str]:
        return [t for t in self.counts if t.startswith(prefix) and t.endswith(suffix)]

    def decode(self, topic: str) -> list[dict]:
        """The messages of a protobuf channel as dicts (:class:`ProtoDecoder`)."""
        name, enc, _ = self.schemas[topic]
        if enc != "protobuf":
            raise ValueError(f"{topic} is not a protobuf channel ({enc})")
        dec = ProtoDecoder(self.schema_data[topic])
        return [dec.decode(b, name) for _, b in self.raw.get(topic, [])]


def read_recording(path: str | Path, topics: set[str] | None = None) -> Recording:
    """Read ``path`` (complete or torn); ``topics``: keep only those messages (counts
    and schemas of every channel are kept)."""
    rec = Recording(Path(path))
    schemas: dict[int, Schema] = {}
    chans: dict[int, Channel] = {}
    with open(path, "rb") as f:
        reader = StreamReader(f, skip_magic=False, emit_chunks=True)
        try:
            for r in reader.records:
                if isinstance(r, Chunk):
                    rec.chunks += 1
                    _chunk(rec, r, schemas, chans, topics)
                else:
                    _one(rec, r, schemas, chans, topics)
                if isinstance(r, Footer):
                    break
            else:
                rec.truncated = True
        except Exception as e:  # the torn tail of a killed recording
            rec.truncated = True
            rec.error = f"{type(e).__name__}: {e}"
    return rec


def _nulls(v):
    """NaN -> None in a decoded message (lists and nested dicts too)."""
    if type(v) is float:
        return None if v != v or v in (_INF, -_INF) else v
    if type(v) is dict:
        return {k: _nulls(x) for k, x in v.items()}
    if type(v) is list:
        return [_nulls(x) for x in v]
    return v


_INF = float("inf")


def _chunk(rec, chunk, schemas, chans, topics) -> None:
    for r in breakup_chunk(chunk):
        _one(rec, r, schemas, chans, topics)


def _one(rec: Recording, r, schemas, chans, topics) -> None:
    if isinstance(r, Schema):
        schemas[r.id] = r
    elif isinstance(r, Channel):
        if r.id in chans:
            return
        chans[r.id] = r
        s = schemas.get(r.schema_id)
        rec.schemas[r.topic] = (s.name if s else "", s.encoding if s else "",
                                r.message_encoding)
        if s is not None:
            rec.schema_data[r.topic] = s.data
            if s.encoding == "protobuf" and s.name.startswith("uavest."):
                # uavest's own protobuf channels (the per-step ones) are decoded like the
                # JSON ones: dicts by field name, NaN as None (JSON's null)
                dec = rec._decoders.get(s.id)
                if dec is None:
                    dec = rec._decoders[s.id] = ProtoDecoder(s.data)
                rec._own[r.topic] = dec
        rec.counts.setdefault(r.topic, 0)
    elif isinstance(r, Message):
        ch = chans.get(r.channel_id)
        if ch is None:
            return
        t = ch.topic
        rec.counts[t] += 1
        if topics is not None and t not in topics:
            return
        rec.log_times.setdefault(t, []).append(r.log_time)
        if ch.message_encoding == "json":
            rec.json.setdefault(t, []).append(json.loads(r.data))
        elif ch.topic in rec._own:
            rec.json.setdefault(t, []).append(_nulls(rec._own[t].decode(
                r.data, rec.schemas[t][0])))
        else:
            rec.raw.setdefault(t, []).append((r.log_time, bytes(r.data)))
    elif isinstance(r, Metadata):
        rec.metadata[r.name] = dict(r.metadata)
