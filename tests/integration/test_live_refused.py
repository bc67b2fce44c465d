"""A refused TCP connection (nothing listens on the port) is said as such, not as "waiting
for a HEARTBEAT": a real loopback port with no listener."""

from __future__ import annotations

import socket

import pytest

from uavest.ingest.live import LinkTimeout, open_live


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.mark.slow
def test_refused_tcp_connection_is_reported_as_refused():
    port = _free_port()
    notes: list[str] = []
    with pytest.raises(LinkTimeout) as e:
        open_live(f"tcp:127.0.0.1:{port}", heartbeat_timeout=1.5, on_wait=notes.append)
    msg = str(e.value)
    assert "cannot connect" in msg and "refused" in msg.lower(), msg
    assert "HEARTBEAT" not in msg
    assert notes and all("cannot connect" in n for n in notes), notes


@pytest.mark.slow
def test_silent_listener_is_still_a_missing_heartbeat():
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    try:
        with pytest.raises(LinkTimeout) as e:
            open_live(f"tcp:127.0.0.1:{srv.getsockname()[1]}", heartbeat_timeout=1.5)
        assert "no HEARTBEAT" in str(e.value)
    finally:
        srv.close()
