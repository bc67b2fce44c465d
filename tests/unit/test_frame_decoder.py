"""The tlog reader's :class:`~uavest.ingest.skip.FrameDecoder` builds the same message
objects as pymavlink's ``MAVLink.decode``: every record of the project's logs (and of the
shared vtol.tlog when it is there), and hand-made frames of each kind the fast path takes
or leaves to pymavlink (MAVLink 1, a MAVLink 2 payload truncated at its zero tail, arrays
and strings, a signed frame)."""

from __future__ import annotations

import mmap
import struct

import pytest
from conftest import REPO_ROOT, shared_log
from pymavlink.dialects.v20 import ardupilotmega as mod

from uavest.ingest.skip import FrameDecoder, TlogFramer


def _state(m) -> str:
    """Everything decode sets on a message (fields, header, buffers), comparable (NaN as
    its repr)."""
    d = {k: v for k, v in vars(m).items() if k != "_header"}
    return repr((type(m).__name__, sorted(d.items()), sorted(vars(m._header).items())))


def _frames(data):
    """(start of the frame, end, msgid) of every good record of a tlog's bytes."""
    return TlogFramer(data, mod).records()


def _compare(data) -> tuple[int, int]:
    """Compare the two decoders on every record of ``data``; (records, records of the
    types the fast path takes)."""
    mav = mod.MAVLink(None)
    mav.robust_parsing = True
    dec = FrameDecoder(mod, mav)
    n = fast = 0
    for o, end, mid in _frames(data):
        want = mav.decode(bytearray(data[o:end]))
        got = dec(data, o, end, mid)
        assert _state(got) == _state(want), (type(want).__name__, o)
        n += 1
        fast += mid in dec.plan
    return n, fast


@pytest.mark.parametrize("name", ["sim_200hz.tlog", "sitl_copter.tlog"])
def test_every_record_of_the_project_logs(name):
    with open(REPO_ROOT / "logs" / name, "rb") as f, \
            mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        n, fast = _compare(mm)
    assert n > 30000 and fast > 0.9 * n  # RAW_IMU, SIMSTATE, ATTITUDE... take the fast path


def test_every_record_of_the_shared_vtol_log():
    with open(shared_log("vtol.tlog"), "rb") as f, \
            mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        n, fast = _compare(mm)
    assert n > 1000 and 0 < fast < n  # (STATUSTEXT, PARAM_VALUE: strings, through decode)


def _record(msg, v1: bool = False, key: bytes | None = None) -> bytes:
    """One tlog record (receive time, frame) of ``msg`` from system 7, component 190."""
    mav = mod.MAVLink(None, srcSystem=7, srcComponent=190)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 3
    frame = msg.pack(mav, force_mavlink1=v1)
    return struct.pack(">Q", 1_700_000_000_000_000) + bytes(frame)


def _raw_imu(zacc: int = -1000, inst: int = 0):
    return mod.MAVLink_raw_imu_message(123456, 10, -20, zacc, 1, 2, 3, 300, -40, 500, inst, 25)


@pytest.mark.parametrize("case", ["v2", "v1", "truncated", "array", "string", "signed"])
def test_hand_made_frames(case):
    msg = {
        "v2": _raw_imu(inst=2),
        "v1": _raw_imu(),
        "truncated": _raw_imu(zacc=0),  # the zero tail (id, temperature 0) cut on the wire
        "array": mod.MAVLink_hil_state_quaternion_message(
            1, [0.9, 0.1, 0.2, 0.3], 0.1, 0.2, 0.3, 473977000, 85456000, 408000, 100, -200,
            30, 500, 500, 10, 0, 0),
        "string": mod.MAVLink_param_value_message(b"INS_GYRO_FILTER", 20.0, 9, 900, 12),
        "signed": _raw_imu(),
    }[case]
    if case == "truncated":
        msg.id, msg.temperature = 0, 0
    kw = {"v1": {"v1": True}, "signed": {"key": bytes(range(32))}}.get(case, {})
    data = _record(msg, **kw)
    (o, end, mid), = _frames(data)
    if case == "truncated":
        assert data[o + 1] < mod.MAVLink_raw_imu_message.unpacker.size
    n, fast = _compare(data)
    assert n == 1
    assert fast == (case not in ("array", "string"))  # (a signed one: through decode)
    if case == "signed":
        assert data[o + 2] & 1
    got = FrameDecoder(mod, mod.MAVLink(None))(data, o, end, mid)
    assert got.get_srcSystem() == 7 and got.get_srcComponent() == 190
