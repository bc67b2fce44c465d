"""A small schema-driven protobuf decoder (no ``protobuf`` package needed): decodes the
messages of an MCAP channel with a ``protobuf`` schema (a ``FileDescriptorSet``, as
foxglove-sdk writes for its well-known schemas) into dicts keyed by field name.

Supports what the well-known schemas use: scalars (varint, zigzag, fixed 32/64, double,
float), strings, bytes, nested messages, enums (as ints), repeated fields (packed or
not). Unknown fields are skipped; absent fields are absent from the dict (proto3
defaults are not filled in)."""

from __future__ import annotations

import struct

from ..errors import InputError

__all__ = ["ProtoDecoder"]

_VARINT, _I64, _LEN, _I32 = 0, 1, 2, 5


def _varint(b: bytes, i: int) -> tuple[int, int]:
    r = s = 0
    while True:
        c = b[i]
        i += 1
        r |= (c & 0x7F) << s
        if c < 0x80:
            return r, i
        s += 7


def _fields(b: bytes):
    """(field number, wire type, value) of every field of a serialised message."""
    i, n = 0, len(b)
    while i < n:
        key, i = _varint(b, i)
        num, wt = key >> 3, key & 7
        if wt == _VARINT:
            v, i = _varint(b, i)
        elif wt == _I64:
            v, i = b[i:i + 8], i + 8
        elif wt == _LEN:
            ln, i = _varint(b, i)
            v, i = b[i:i + ln], i + ln
        elif wt == _I32:
            v, i = b[i:i + 4], i + 4
        else:
            raise InputError(f"unsupported wire type {wt}")
        yield num, wt, v


def _signed(v: int, bits: int) -> int:
    return v - (1 << bits) if v >= 1 << (bits - 1) else v


class ProtoDecoder:
    """Decoder for the message types of one ``FileDescriptorSet`` (``schema.data``)."""

    def __init__(self, descriptor_set: bytes) -> None:
        self.types: dict[str, dict[int, tuple[str, int, int, str]]] = {}
        for num, _, fd in _fields(descriptor_set):
            if num != 1:
                continue
            pkg, msgs = "", []
            for n2, _, v in _fields(fd):
                if n2 == 2:
                    pkg = v.decode()
                elif n2 == 4:
                    msgs.append(v)
            for m in msgs:
                self._add(pkg, m)

    def _add(self, scope: str, desc: bytes) -> None:
        name, fields, nested = "", {}, []
        for n, _, v in _fields(desc):
            if n == 1:
                name = v.decode()
            elif n == 2:
                f = {k: x for k, _, x in _fields(v)}
                fields[f[3]] = (f[1].decode(), f.get(5, 0), f.get(4, 1),
                                f.get(6, b"").decode().lstrip("."))
            elif n == 3:
                nested.append(v)
        full = f"{scope}.{name}" if scope else name
        self.types[full] = fields
        for m in nested:
            self._add(full, m)

    def decode(self, data: bytes, type_name: str) -> dict:
        """The message ``data`` of type ``type_name`` (e.g. ``foxglove.FrameTransform``)."""
        spec = self.types[type_name]
        out: dict = {}
        for num, wt, v in _fields(data):
            if num not in spec:
                continue
            name, ftype, label, tname = spec[num]
            if wt == _LEN and ftype not in (9, 11, 12):  # packed repeated scalars
                vals, j = [], 0
                while j < len(v):
                    if ftype in (1, 6, 16):
                        vals.append(self._scalar(ftype, _I64, v[j:j + 8]))
                        j += 8
                    elif ftype in (2, 7, 15):
                        vals.append(self._scalar(ftype, _I32, v[j:j + 4]))
                        j += 4
                    else:
                        x, j = _varint(v, j)
                        vals.append(self._scalar(ftype, _VARINT, x))
                out.setdefault(name, []).extend(vals)
                continue
            if ftype == 11:
                val = self.decode(v, tname)
            elif ftype == 9:
                val = v.decode()
            elif ftype == 12:
                val = bytes(v)
            else:
                val = self._scalar(ftype, wt, v)
            if label == 3:
                out.setdefault(name, []).append(val)
            else:
                out[name] = val
        return out

    @staticmethod
    def _scalar(ftype: int, wt: int, v):
        if ftype == 1:
            return struct.unpack("<d", v)[0]
        if ftype == 2:
            return struct.unpack("<f", v)[0]
        if ftype in (6, 16):
            return struct.unpack("<Q" if ftype == 6 else "<q", v)[0]
        if ftype in (7, 15):
            return struct.unpack("<I" if ftype == 7 else "<i", v)[0]
        if ftype == 8:
            return bool(v)
        if ftype in (3, 5):
            return _signed(v, 64)
        if ftype in (17, 18):
            return (v >> 1) ^ -(v & 1)
        return v  # uint32, uint64, enum
