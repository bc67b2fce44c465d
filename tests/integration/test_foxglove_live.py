"""Live view: a real WebSocket client (``websockets``, subprotocol ``foxglove.sdk.v1``)
connects to FoxgloveLiveSink's server on loopback while a replay runs, sees the channels
advertised, subscribes and receives binary message data frames."""

import asyncio
import base64
import json
import struct
import threading
import time

import pytest
from conftest import shared_logs_dir

from uavest.apps.replay import ReplayConfig, replay
from uavest.report.protowire import ProtoDecoder
from uavest.sinks.base import Sink
from uavest.sinks.foxglove_live import FoxgloveLiveSink

websockets = pytest.importorskip("websockets")
VTOL = shared_logs_dir() / "vtol.tlog"
pytestmark = pytest.mark.skipif(not VTOL.exists(), reason=f"needs {VTOL} (or UAVEST_LOGS)")

WANT = ("/attitude/ekf/estimate", "/tf/ekf", "/attitude/ukf/error")


class Pace(Sink):
    def record(self, rec):
        time.sleep(0.002)


async def _client(url: str, timeout: float = 60.0, want: tuple[str, ...] = WANT,
                  many: int = 1) -> dict:
    """What a Foxglove client sees: the advertised channels, the server info, the first
    message of each topic of ``want`` (and ``/run/info``) after subscribing (``data``)
    and the first ``many`` of each (``all``: lists of (log_time, payload))."""
    got: dict = {"advertised": {}, "data": {}, "all": {}, "server_info": None,
                 "resubscribed": 0}

    def done() -> bool:
        return len(got["data"]) >= len(want) + 1 and all(
            len(got["all"].get(t, ())) >= many for t in want)
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
        assert ws.subprotocol == "foxglove.sdk.v1"
        sub_of: dict[int, str] = {}
        asked: dict[str, float] = {}  # topic -> when last subscribed
        next_sub = 1

        async def subscribe(topics):
            nonlocal next_sub
            subs = []
            for t in topics:
                sub_of[next_sub] = t
                subs.append({"id": next_sub, "channelId": got["advertised"][t]["id"]})
                asked[t] = time.monotonic()
                next_sub += 1
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

        end = time.monotonic() + timeout
        while time.monotonic() < end and not done():
            # the server can see a subscription before it has registered a channel it
            # has just advertised ("unknown channel" in its log): ask again after 1 s
            late = [t for t, w in asked.items()
                    if t not in got["data"] and time.monotonic() - w > 1.0]
            if late:
                got["resubscribed"] += len(late)
                await subscribe(late)
            try:
                msg = await asyncio.wait_for(ws.recv(), timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(msg, str):
                m = json.loads(msg)
                if m["op"] == "serverInfo":
                    got["server_info"] = m
                elif m["op"] == "advertise":
                    new = []
                    for ch in m["channels"]:
                        got["advertised"][ch["topic"]] = ch
                        if ch["topic"] in want + ("/run/info",):
                            new.append(ch["topic"])
                    if new:
                        await subscribe(new)
            else:
                op, sub, log_time = struct.unpack_from("<BIQ", msg)
                assert op == 1  # message data
                got["data"].setdefault(sub_of[sub], (log_time, bytes(msg[13:])))
                lst = got["all"].setdefault(sub_of[sub], [])
                if len(lst) < many:
                    lst.append((log_time, bytes(msg[13:])))
    return got


@pytest.mark.slow
def test_live_server_advertises_and_streams_while_a_replay_runs():
    sink = FoxgloveLiveSink("127.0.0.1", 0, wait_for_client=30.0)
    assert sink.port > 0
    result: dict = {}

    def run():
        result["doc"] = replay(VTOL, ReplayConfig(end=700.0), sinks=[sink, Pace()])

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        got = asyncio.run(_client(sink.url))
    finally:
        th.join(timeout=300)
    assert not th.is_alive()
    assert got["server_info"] is not None
    adv = got["advertised"]
    assert adv["/tf/ekf"]["schemaName"] == "foxglove.FrameTransform"
    assert adv["/tf/ekf"]["encoding"] == "protobuf"
    assert adv["/attitude/ekf/estimate"]["schemaName"] == "uavest.AttitudeEstimate"
    assert {"/imu/RAW_IMU", "/reference/SIMSTATE", "/attitude/hybrid/health"} <= set(adv)
    assert set(got["data"]) == set(WANT) | {"/run/info"}
    # uavest's per-step channels are protobuf with the FileDescriptorSet advertised
    # (base64, as the protocol carries protobuf schemas)
    est_ch = adv["/attitude/ekf/estimate"]
    assert est_ch["encoding"] == "protobuf" and est_ch["schemaEncoding"] == "protobuf"
    dec = ProtoDecoder(base64.b64decode(est_ch["schema"]))
    log_time, payload = got["data"]["/attitude/ekf/estimate"]
    m = dec.decode(payload, "uavest.AttitudeEstimate")
    assert len(m["q"]) == 4 and len(m["P_triu"]) == 21
    assert abs(m["t"] * 1e9 - log_time) < 2
    e = dec.decode(got["data"]["/attitude/ukf/error"][1], "uavest.AttitudeError")
    assert e["reference"] == "SIMSTATE" and e["nees"] >= 0.0
    info = json.loads(got["data"]["/run/info"][1])
    assert list(info["filters"]) == ["ekf", "ukf", "hybrid"]
    assert "doc" in result and sink.closed
