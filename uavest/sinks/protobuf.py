"""uavest's own per-step channels as protobuf messages, encoded in batches without the
``protobuf`` package.

Why protobuf: at a 248 Hz filter rate the recorder writes four messages per filter step
and one per raw sample; formatting them as JSON text in Python cost the replay 60 % of
its own time (docs/recording.md). A protobuf message of fixed shape is a fixed byte
layout: tags and lengths are constants, the values little-endian float64 / int64. So a
batch of N messages is one numpy structured array over a tiled template, its value
columns assigned from stacked arrays, and one ``tobytes`` (:class:`FixedEncoder`);
variable parts (the per-update NIS list, a reset's reason) are appended per message
(protobuf allows fields in any order). Foxglove reads the messages with the schema
written into the recording (a ``FileDescriptorSet``, :data:`DESCRIPTOR_SET`), so its plot
and raw-message panels show the same field paths as the JSON channels did
(``err_deg.roll``, ``sigma3_deg.yaw``, ``nis``).

Field numbers and types are in :data:`MESSAGES` (proto3, package ``uavest``). NaN is a
valid double: a value a JSON channel would write as null (a diverged filter, no NEES
without truth) is NaN here; :func:`uavest.report.read.read_recording` gives it back as
None.
"""

from __future__ import annotations

import struct

import numpy as np

__all__ = ["DESCRIPTOR_SET", "MESSAGES", "FixedEncoder", "field_bytes", "len_field",
           "schema", "timestamp_field", "update_bytes"]

# FieldDescriptorProto.Type
_DOUBLE, _BOOL, _STRING, _MESSAGE, _SFIXED64 = 1, 8, 9, 11, 16
_OPTIONAL, _REPEATED = 1, 3
_TYPES = {"double": _DOUBLE, "bool": _BOOL, "string": _STRING, "sfixed64": _SFIXED64}

#: Message name -> fields (name, number, type). A type ``"double[]"`` is a packed repeated
#: double; another message name (``"RPY"``, ``"Update"``) a nested message; ``"Update[]"``
#: a repeated nested message. Units in the names or the field docs of docs/recording.md:
#: t s (source clock), angles deg (ZYX Euler, roll / pitch / yaw), q [w, x, y, z] body FRD
#: -> NED, gyro rad/s, accel m/s^2, field gauss, covariances rad^2 and (rad/s)^2;
#: navigation velocity m/s and position m in the local NED frame of the first GNSS fix.
MESSAGES: dict[str, tuple[tuple[str, int, str], ...]] = {
    "RPY": (("roll", 1, "double"), ("pitch", 2, "double"), ("yaw", 3, "double")),
    "Update": (("kind", 1, "string"), ("nis", 2, "double"), ("dof", 3, "sfixed64")),
    "Imu": (("t", 1, "double"), ("source", 2, "string"), ("gyro_rad_s", 3, "double[]"),
            ("accel_m_s2", 4, "double[]")),
    "Mag": (("t", 1, "double"), ("source", 2, "string"), ("field_gauss", 3, "double[]")),
    "AttitudeReference": (("t", 1, "double"), ("source", 2, "string"),
                          ("kind", 3, "string"), ("q", 4, "double[]"),
                          ("rpy_deg", 5, "RPY")),
    "AttitudeEstimate": (("t", 1, "double"), ("k", 2, "sfixed64"), ("q", 3, "double[]"),
                         ("bias_rad_s", 4, "double[]"), ("rpy_deg", 5, "RPY"),
                         ("sigma3_deg", 6, "RPY"), ("P_triu", 7, "double[]")),
    "NavigationEstimate": (("t", 1, "double"), ("k", 2, "sfixed64"),
                           ("velocity_ned_m_s", 3, "double[]"),
                           ("position_ned_m", 4, "double[]"),
                           ("sigma3_velocity_m_s", 5, "double[]"),
                           ("sigma3_position_m", 6, "double[]"),
                           ("accel_bias_m_s2", 7, "double[]")),
    "AttitudeError": (("t", 1, "double"), ("k", 2, "sfixed64"), ("reference", 3, "string"),
                      ("kind", 4, "string"), ("err_deg", 5, "RPY"), ("sigma3_deg", 6, "RPY"),
                      ("neg_sigma3_deg", 7, "RPY"), ("nees", 8, "double")),
    "FilterHealth": (("t", 1, "double"), ("k", 2, "sfixed64"), ("nis", 3, "double"),
                     ("nis_dof", 4, "sfixed64"), ("updates", 5, "Update[]"),
                     ("reset", 6, "bool"), ("reason", 7, "string"),
                     ("resets", 8, "sfixed64"), ("wall_us", 9, "double")),
}

_PACKAGE = "uavest"


def _varint(v: int) -> bytes:
    """Base-128 varint of ``v`` >= 0 (the lengths of the hot path written out)."""
    if v < 0x80:
        return bytes((v,))
    if v < 0x4000:
        return bytes((v & 0x7F | 0x80, v >> 7))
    if 0x10000000 <= v < 0x800000000:  # 5 bytes: nanoseconds of a timestamp
        return bytes((v & 0x7F | 0x80, (v >> 7) & 0x7F | 0x80, (v >> 14) & 0x7F | 0x80,
                      (v >> 21) & 0x7F | 0x80, v >> 28))
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(num: int, wire: int) -> bytes:
    return _varint(num << 3 | wire)


def len_field(num: int, payload: bytes) -> bytes:
    """A length-delimited field (a string, bytes or a nested message)."""
    return _key(num, 2) + _varint(len(payload)) + payload


_SECONDS: dict[int, bytes] = {}


def timestamp_field(num: int, ns: int) -> bytes:
    """A ``google.protobuf.Timestamp`` field (seconds, nanos; zero fields left out, as
    proto3 encoders do) of ``ns`` nanoseconds (>= 0)."""
    sec, nsec = divmod(ns, 1_000_000_000)
    head = _SECONDS.get(sec)
    if head is None:
        head = b"\x08" + _varint(sec) if sec else b""
        if len(_SECONDS) > 4096:
            _SECONDS.clear()
        _SECONDS[sec] = head
    return len_field(num, head + b"\x10" + _varint(nsec) if nsec else head)


def field_bytes(num: int, value) -> bytes:
    """One field: a str (length-delimited), a bool (varint), an int (sfixed64) or a
    float (double)."""
    if isinstance(value, str):
        return len_field(num, value.encode())
    if isinstance(value, bool):
        return _key(num, 0) + (b"\x01" if value else b"\x00")
    if isinstance(value, int):
        return _key(num, 1) + struct.pack("<q", value)
    return _key(num, 1) + struct.pack("<d", value)


_UPDATE_HEAD: dict[tuple[int, str], bytes] = {}
_UPDATE_TAIL = struct.Struct("<BdBq")


def update_bytes(num: int, kind: str, nis: float, dof: int) -> bytes:
    """A repeated ``Update`` field (number ``num``) of one measurement update."""
    head = _UPDATE_HEAD.get((num, kind))
    if head is None:
        body = field_bytes(1, str(kind))
        head = _UPDATE_HEAD[(num, kind)] = (_key(num, 2) + _varint(len(body) + _UPDATE_TAIL.size)
                                            + body)
    return head + _UPDATE_TAIL.pack(0x11, nis, 0x19, dof)


def _descriptor_set() -> bytes:
    """A ``FileDescriptorSet`` with one proto3 file of every message of MESSAGES
    (``google/protobuf/descriptor.proto``'s field numbers)."""
    msgs = b""
    for name, fields in MESSAGES.items():
        body = len_field(1, name.encode())
        for fname, num, ftype in fields:
            rep = ftype.endswith("[]")
            base = ftype[:-2] if rep else ftype
            fd = len_field(1, fname.encode()) + _key(3, 0) + _varint(num)
            fd += _key(4, 0) + _varint(_REPEATED if rep else _OPTIONAL)
            if base in _TYPES:
                fd += _key(5, 0) + _varint(_TYPES[base])
            else:
                fd += _key(5, 0) + _varint(_MESSAGE)
                fd += len_field(6, f".{_PACKAGE}.{base}".encode())
            fd += len_field(10, fname.encode())  # json_name: the field name as is
            body += len_field(2, fd)
        msgs += len_field(4, body)
    f = (len_field(1, b"uavest.proto") + len_field(2, _PACKAGE.encode()) + msgs
         + len_field(12, b"proto3"))
    return len_field(1, f)


#: The ``FileDescriptorSet`` of :data:`MESSAGES` (the schema data of every channel).
DESCRIPTOR_SET: bytes = _descriptor_set()


def schema(name: str):
    """The ``foxglove.Schema`` of ``uavest.<name>``."""
    import foxglove

    return foxglove.Schema(name=f"{_PACKAGE}.{name}", encoding="protobuf",
                           data=DESCRIPTOR_SET)


class FixedEncoder:
    """Batches of one message type with a fixed layout: the fields of ``name`` in number
    order, strings fixed per encoder (``strings``; a string field not given is left out,
    as a variable field is), packed arrays of fixed ``lengths``, nested ``RPY`` messages;
    repeated messages are left out (append them with :func:`field_bytes`).

    ``encode(n, columns)`` -> list of n messages (bytes), ``columns``: value slot -> array
    broadcastable to (n,) or (n, length): ``"t"``, ``"k"``, ``"q"`` (n, 4), ``"rpy_deg"``
    (n, 3) for a nested RPY, ...; a slot not given keeps its template value (0)."""

    def __init__(self, name: str, strings: dict[str, str] | None = None,
                 lengths: dict[str, int] | None = None) -> None:
        strings, lengths = strings or {}, lengths or {}
        self.name = name
        tpl = bytearray()
        names, formats, offsets = [], [], []
        self.rpy: dict[str, tuple[str, str, str]] = {}

        def slot(key: str, fmt: str, size: int) -> None:
            names.append(key)
            formats.append(fmt)
            offsets.append(len(tpl))
            tpl.extend(b"\x00" * size)

        for fname, num, ftype in MESSAGES[name]:
            if ftype == "double":
                tpl += _key(num, 1)
                slot(fname, "<f8", 8)
            elif ftype == "sfixed64":
                tpl += _key(num, 1)
                slot(fname, "<i8", 8)
            elif ftype == "bool":
                tpl += _key(num, 0)
                slot(fname, "u1", 1)
            elif ftype == "string":
                if fname in strings:
                    tpl += len_field(num, strings[fname].encode())
            elif ftype == "double[]":
                n = int(lengths[fname])
                tpl += _key(num, 2) + _varint(8 * n)
                slot(fname, f"({n},)<f8", 8 * n)
            elif ftype == "RPY":
                tpl += _key(num, 2) + _varint(27)
                keys = []
                for sub, snum, _ in MESSAGES["RPY"]:
                    tpl += _key(snum, 1)
                    keys.append(f"{fname}.{sub}")
                    slot(keys[-1], "<f8", 8)
                self.rpy[fname] = tuple(keys)
            # repeated messages: variable, appended by the caller
        self.size = len(tpl)
        self.template = np.frombuffer(bytes(tpl), np.uint8)
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                               "itemsize": self.size})

    def encode(self, n: int, columns: dict) -> list[bytes]:
        raw = np.tile(self.template, n)
        a = raw.view(self.dtype)
        rpy = self.rpy
        for key, v in columns.items():
            sub = rpy.get(key)
            if sub is None:
                a[key] = v
            else:
                v = np.asarray(v)
                a[sub[0]] = v[:, 0]
                a[sub[1]] = v[:, 1]
                a[sub[2]] = v[:, 2]
        buf = raw.tobytes()
        L = self.size
        return [buf[i:i + L] for i in range(0, n * L, L)]
