"""The one line that says which filters reset, how often, and the first one's time and
reason (a replay's reliability warning, a live run's summary)."""

from __future__ import annotations

from uavest.apps.replay import resets_line


def test_the_line_names_each_filter_that_reset_with_its_first_reason():
    why = {"ekf": [[29.4, "gnss_vel rejected for 5.0 s"], [40.0, "later"]]}
    line = resets_line({"ekf": 2, "ukf": 0, "hybrid": 1}, why)
    assert line == ("filter resets: ekf 2 (first at t=29.4 s: gnss_vel rejected for 5.0 s), "
                    "hybrid 1")
    assert resets_line({"ekf": 0, "ukf": 0}, {}) is None
