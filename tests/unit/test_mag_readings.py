"""New and held magnetometer readings (uavest.engine.nav_aiding.NewReadings), the one rule
of the navigation stream's aiding and the replay's delay probe: MAVLink's IMU messages
repeat the last compass value between its updates (held), but a vehicle at rest with a
noise-free magnetometer (the ArduCopter SITL's) reads the same field for minutes, and those
are readings: before the rule had a time limit, logs/sitl_copter.tlog's navigation EKF
took no magnetometer update in its first 40 s on the ground."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.engine.nav_aiding import MAG_HOLD_MAX_S, AidQueues, NewReadings
from uavest.ingest.types import MagSample


def test_a_repeat_within_the_hold_time_is_held_after_it_a_reading():
    r = NewReadings()
    f = np.array([0.2, 0.0, 0.4])
    assert r.new(0.0, f)
    assert not r.new(0.02, f.copy()) and not r.new(MAG_HOLD_MAX_S - 0.01, f)
    assert r.new(MAG_HOLD_MAX_S + 0.01, f)  # the same field read again
    assert not r.new(MAG_HOLD_MAX_S + 0.03, f)
    assert r.new(MAG_HOLD_MAX_S + 0.05, f + 1e-6)  # a changed value is always new


@pytest.mark.parametrize("rate_hz", [50.0, 200.0])
def test_a_constant_field_at_rest_keeps_aiding(rate_hz):
    """20 s of one unchanging field (a vehicle at rest, a noise-free sensor) queue one
    aid per hold time; a field that changes at 10 Hz (ArduPilot's compass in a faster
    IMU message) queues each change once."""
    q = AidQueues()
    n = int(20 * rate_hz)
    for k in range(n):
        q.add_mag(MagSample(k / rate_hz, np.array([0.2, 0.0, 0.4]), "RAW_IMU"), 0.0)
    assert len(q.queues["mag"]) == pytest.approx(20 / MAG_HOLD_MAX_S, abs=2)
    q = AidQueues()
    for k in range(n):
        t = k / rate_hz
        q.add_mag(MagSample(t, np.array([0.2, 0.01 * int(t * 10), 0.4]), "RAW_IMU"), 0.0)
    assert len(q.queues["mag"]) == 200


def test_the_streams_float_checks_are_numpys():
    """finite3 (IMU and magnetometer samples) and NewReadings' equality on Python floats
    give numpy's answers: NaN, infinities, -0.0 against 0.0, a held field."""
    import numpy as np

    from uavest.engine.nav_aiding import NewReadings, finite3

    nan, inf = float("nan"), float("inf")
    vecs = [np.array(v) for v in ([0.1, -2.0, 9.8], [nan, 0, 0], [0, inf, 0], [0, 0, -inf],
                                   [0.0, -0.0, 0.0], [1e308, -1e308, 5e-324])]
    for a in vecs:
        for b in vecs:
            assert finite3(a, b) == bool(np.isfinite(a).all() and np.isfinite(b).all())
            assert finite3(a.tolist(), tuple(b)) == finite3(a, b)  # (lists, numpy scalars)
    for a in vecs:
        for b in vecs:
            r = NewReadings()
            assert r.new(0.0, a)
            assert r.new(0.1, b) == (not np.array_equal(a, b)), (a, b)
