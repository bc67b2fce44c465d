"""Reading a uavest recording back with the ``mcap`` package (independently of the
recorder): channels with their schemas, message counts, the JSON channels and uavest's own
protobuf channels decoded, the well-known protobuf channels decodable on demand, MCAP
metadata records.

A complete file and a file torn by a killed recorder are read the same way: a
sequential scan of the records (``mcap.stream_reader.StreamReader``) that decompresses
every chunk and stops at the first incomplete record, so every message of every closed
chunk is recovered; ``Recording.truncated`` tells whether the file ended early (no
footer)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from .protowire import ProtoDecoder, _varint

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
    _own_raw: dict = field(default_factory=dict, repr=False)
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
    for t, msgs in rec._own_raw.items():
        rec.json[t] = decode_own(rec._own[t], rec.schemas[t][0], msgs)
    rec._own_raw.clear()
    return rec


def decode_own(dec: ProtoDecoder, type_name: str, msgs: list[bytes]) -> list[dict]:
    """Messages of one of uavest's own protobuf channels as dicts (NaN as None), in order.

    The recorder writes them with a fixed byte layout (:mod:`uavest.sinks.protobuf`), so
    the messages of one length usually share it: the layout is read off the first one
    (the offsets of its scalar and packed-double fields), every message of that length
    whose other bytes (tags, lengths, strings) equal the first's is decoded by numpy in
    one go, and the rest (a health message with its per-update list, a reset's reason)
    by :class:`ProtoDecoder`. The same dicts either way (test)."""
    out: list = [None] * len(msgs)
    groups: dict[int, list[int]] = {}
    for i, m in enumerate(msgs):
        groups.setdefault(len(m), []).append(i)
    for L, idx in groups.items():
        lay = _layout(dec, type_name, msgs[idx[0]], 0, ()) if len(idx) >= 8 and L else None
        if lay is None:
            for i in idx:
                out[i] = _nulls(dec.decode(msgs[i], type_name))
            continue
        slots, consts = lay
        buf = np.frombuffer(b"".join(msgs[i] for i in idx), np.uint8).reshape(len(idx), L)
        mask = np.ones(L, bool)
        for _, off, kind, count in slots:
            mask[off:off + (1 if kind == "u1" else 8 * max(count, 1))] = False
        same = (buf[:, mask] == buf[0, mask]).all(axis=1).tolist()
        cols = []
        for path, off, kind, count in slots:
            width = 1 if kind == "u1" else 8 * max(count, 1)
            v = np.ascontiguousarray(buf[:, off:off + width]).view(kind)
            if kind == "u1":
                col = v[:, 0].astype(bool).tolist()
            else:
                col = _none_where_bad(v[:, 0] if count == 0 else v)
            cols.append((path, col))
        for r, i in enumerate(idx):
            if not same[r]:
                out[i] = _nulls(dec.decode(msgs[i], type_name))
                continue
            d: dict = {}
            for path, col in cols:
                if len(path) == 1:
                    d[path[0]] = col[r]
                else:
                    d.setdefault(path[0], {})[path[1]] = col[r]
            for path, val in consts:
                if len(path) == 1:
                    d[path[0]] = val
                else:
                    d.setdefault(path[0], {})[path[1]] = val
            out[i] = d
    return out


def _none_where_bad(v: np.ndarray) -> list:
    """``v.tolist()`` with None for NaN / inf (1-D or 2-D)."""
    lst = v.tolist()
    if v.dtype.kind == "f":
        bad = ~np.isfinite(v)
        if bad.any():
            if v.ndim == 1:
                for i in np.flatnonzero(bad).tolist():
                    lst[i] = None
            else:
                for i, j in zip(*np.nonzero(bad), strict=True):
                    lst[int(i)][int(j)] = None
    return lst


def _layout(dec: ProtoDecoder, type_name: str, m: bytes, base: int, prefix: tuple):
    """(slots, constants) of message ``m``: slots (path, byte offset, numpy kind, count:
    0 for a scalar, n for a packed double array) of its double / sfixed64 / bool fields,
    constants (path, str) of its strings; None when ``m`` has a field this cannot place
    at a fixed offset (a repeated message, a varint other than a bool)."""
    spec = dec.types[type_name]
    slots: list = []
    consts: list = []
    i, n = 0, len(m)
    while i < n:
        key, j = _varint(m, i)
        num, wt = key >> 3, key & 7
        if num not in spec:
            return None
        name, ftype, label, sub = spec[num]
        path = prefix + (name,)
        if wt == 1 and ftype in (1, 16) and label != 3:
            slots.append((path, base + j, "<f8" if ftype == 1 else "<i8", 0))
            i = j + 8
        elif wt == 0 and ftype == 8 and m[j] in (0, 1):
            slots.append((path, base + j, "u1", 0))
            i = j + 1
        elif wt == 2:
            ln, k = _varint(m, j)
            body = m[k:k + ln]
            if ftype == 9:
                consts.append((path, body.decode()))
            elif ftype == 11 and label != 3 and not prefix:
                r = _layout(dec, sub, body, base + k, path)
                if r is None:
                    return None
                slots += r[0]
                consts += r[1]
            elif ftype == 1 and label == 3 and ln % 8 == 0:
                slots.append((path, base + k, "<f8", ln // 8))
            else:
                return None
            i = k + ln
        else:
            return None
    return slots, consts



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
        elif ch.topic in rec._own:  # decoded in bulk at the end (decode_own)
            rec._own_raw.setdefault(t, []).append(bytes(r.data))
        else:
            rec.raw.setdefault(t, []).append((r.log_time, bytes(r.data)))
    elif isinstance(r, Metadata):
        rec.metadata[r.name] = dict(r.metadata)
