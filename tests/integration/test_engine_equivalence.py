"""The streaming engine's replay equals the batch replay it replaced (commit 05bb455,
``uavest.pipeline.replay``), step by step, on the shared logs.

The batch replay's output is committed as golden files (``tests/golden/replay_*.npz``,
written by ``tests/golden/make_golden.py``; see tests/golden/README.md), so the test needs
no git history. Each filter gets the old seeding (``default_rng([0, crc32(label)])``) so
that the hybrid's random draws are the same too. Tolerances: step times and the initial
state to 1e-12 s / 1e-12, every state row (quaternion, gyro bias in rad/s) to 1e-9
absolute. Skips with the reason when the shared logs are absent."""

from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_log

from uavest.apps.replay import ReplayConfig, replay
from uavest.sinks.base import Collector

GOLDEN = Path(__file__).resolve().parents[1] / "golden"
FILTERS = ("ekf", "ukf", "hybrid")


def _golden(log: str) -> dict[str, np.ndarray]:
    path = GOLDEN / f"replay_{log.replace('.', '_')}.npz"
    with np.load(path) as z:
        ref = {k: z[k] for k in z.files}
    meta = json.loads(str(ref.pop("meta")))
    assert meta["log"] == log and tuple(meta["filters"]) == FILTERS, meta
    return ref


@pytest.mark.slow
@pytest.mark.parametrize("log", ["vtol.tlog", "sample.ulg"])
def test_streaming_replay_equals_batch_replay(log):
    path = shared_log(log)
    ref = _golden(log)
    coll = Collector()
    replay(path, ReplayConfig(filters=FILTERS), sinks=[coll],
           rng_for=lambda label: np.random.default_rng([0, zlib.crc32(label.encode())]))
    for label in FILTERS:
        a = coll.arrays(label)
        t0, x0, _ = coll.starts[label]
        assert t0 == ref["t"][0]
        np.testing.assert_allclose(x0, ref[label][0], rtol=0, atol=1e-12)
        assert a["t"].shape == ref["t"][1:].shape, label
        np.testing.assert_allclose(a["t"], ref["t"][1:], rtol=0, atol=1e-12)
        np.testing.assert_allclose(a["x"], ref[label][1:], rtol=0, atol=1e-9, err_msg=label)


def test_golden_files_are_the_generators_output():
    """The committed files are what make_golden.py writes: one per log, every filter, the
    state rows unit quaternions (a truncated or hand-edited file fails here, without the
    logs)."""
    for log in ("vtol.tlog", "sample.ulg"):
        ref = _golden(log)
        n = len(ref["t"])
        assert n > 100 and np.all(np.diff(ref["t"]) > 0), log
        for label in FILTERS:
            assert ref[label].shape == (n, 7), (log, label)
            np.testing.assert_allclose(np.linalg.norm(ref[label][:, :4], axis=1), 1, atol=1e-9)
