"""Raw GNSS over a real loopback link from the built-in simulator, which stamps GPS_RAW_INT
with UNIX time as ArduPilot does: every fix is mapped onto the vehicle clock (counted
``retimed``), none is ``late``, and the session's tlog replays to the same fixes."""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest

from uavest.ingest import open_live, open_source
from uavest.ingest.types import BaroSample, GnssSample, ImuSample, LinkEvent
from uavest.scenarios import load_typed
from uavest.sim import Simulator


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b, equal_nan=True)
    if isinstance(a, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return a == b


@pytest.mark.slow
def test_unix_stamped_gps_raw_int_is_retimed_not_late_and_replays_the_same(tmp_path):
    port = _port()
    tl = tmp_path / "live.tlog"
    sim = Simulator(load_typed("sim_default"), seed=3, imu_rate=100.0)
    stop = threading.Event()
    th = threading.Thread(target=sim.run, daemon=True, kwargs=dict(
        conn=f"udpout:127.0.0.1:{port}", speed=4.0, stop_event=stop, wait_gcs=True))
    th.start()
    live = []
    try:
        with open_live(f"udpin:127.0.0.1:{port}", heartbeat_timeout=10, tlog=tl,
                       read_declination=False) as link:
            t0 = time.monotonic()
            for s in link:
                live.append(s)
                if time.monotonic() - t0 > 6.0:
                    break
            st, sysid, window = link.stats, link.vehicle_sysid, link.reorder_window
    finally:
        stop.set()
        th.join(10)
    live = [x for x in live if not isinstance(x, LinkEvent)]
    gnss = [x for x in live if isinstance(x, GnssSample)]
    imu_t = np.array([x.t for x in live if isinstance(x, ImuSample)])
    assert len(gnss) >= 60  # 5 Hz for >= 12 s of simulated time (speed 4)
    # every fix arrived UNIX-stamped and was mapped, none dropped as late
    assert st.retimed >= len(gnss) and st.retimed <= st.messages["GPS_RAW_INT"]
    assert st.late == 0 and st.time_reset == 0
    # (a loaded machine may delay an rx-timed SIMSTATE: only the GNSS must be clean)
    assert not [k for k in st.rejected if k.endswith(":GPS_RAW_INT")], st.rejected
    t = np.array([x.t for x in gnss])
    assert np.all(np.diff(t) > 0) and imu_t[0] - 0.2 <= t[0] and t[-1] <= imu_t[-1] + 0.02
    # once SYSTEM_TIME gave the UNIX - boot offset: the simulator's fix times, every 0.2 s
    # (to the 1 ms of SYSTEM_TIME's time_boot_ms)
    late_t = t[t > 1.5]
    assert np.allclose(late_t, np.round(late_t / 0.2) * 0.2, atol=1.5e-3)
    g = gnss[-1]
    assert g.source == "GPS_RAW_INT" and g.fix_type == 3
    assert np.allclose([g.h_acc, g.v_acc, g.s_acc, g.hdop, g.vdop], [0.8, 1.5, 0.15, 0.7, 1.1])
    assert math.isnan(g.vel_ned[2]) and np.all(np.isfinite(g.vel_ned[:2]))
    # the barometer is requested by default: SCALED_PRESSURE hPa -> Pa
    baro = [x for x in live if isinstance(x, BaroSample)]
    assert len(baro) >= 100 and all(8.0e4 < x.pressure < 1.05e5 for x in baro)
    # the live session's tlog replayed with the link's window: the same fixes
    replay = [x for x in open_source(tl, sysid=sysid, reorder_window=window)
              if isinstance(x, GnssSample)]
    assert len(replay) >= len(gnss)
    for a, b in zip(gnss, replay[:len(gnss)], strict=True):
        assert all(_same(getattr(a, f), getattr(b, f)) for f in a.__slots__), (a, b)
