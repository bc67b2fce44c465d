"""The streaming engine's replay equals the batch replay it replaced (commit 05bb455,
``uavest.pipeline.replay``), step by step, on the shared logs.

The old code is taken from the repository's own history (``git archive``) and run in a
subprocess; each filter gets the old seeding (``default_rng([seed, crc32(label)])``) so
that the hybrid's random draws are the same too. Skips with a reason when git history or
the shared logs are absent."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import tarfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_logs_dir

from uavest.apps.replay import ReplayConfig, replay
from uavest.sinks.base import Collector

ROOT = Path(__file__).resolve().parents[2]
LOGS = shared_logs_dir()
OLD = "05bb455"
FILTERS = ("ekf", "ukf", "hybrid")

_SCRIPT = r"""
import sys, numpy as np
from dataclasses import replace
from uavest.ingest import read_log
from uavest.models.attitude import declination_from_params, noise_for_source
from uavest.pipeline.replay import build_steps, run_filters, velocity_acceleration
log, out = sys.argv[1], sys.argv[2]
data = read_log(log)
noise = noise_for_source(data.imu.source)
decl = declination_from_params(data.params) or 0.0
mag = data.mag
steps = build_steps(data.imu.t, data.imu.gyro, data.imu.accel, mag.t, mag.field, None, "auto")
for name, pos in data.positions.items():
    if len(pos) >= 2 and np.isfinite(pos.vel_ned).all(axis=1).sum() >= 2:
        steps = replace(steps, accel_ned=velocity_acceleration(pos.t, pos.vel_ned, steps.t[1:]))
        break
runs, _ = run_filters(steps, %r, noise, decl, 0, False, True)
np.savez(out, t=steps.t, **{r.label: r.x for r in runs})
"""


def _old_code(tmp: Path) -> Path:
    try:
        tar = subprocess.run(["git", "-C", str(ROOT), "archive", OLD, "uavest"],
                             capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        pytest.skip(f"git history with commit {OLD} not available ({e})")
    dest = tmp / "old"
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(dest, filter="data")
    return dest


@pytest.mark.slow
@pytest.mark.parametrize("log", ["vtol.tlog", "sample.ulg"])
def test_streaming_replay_equals_batch_replay(log, tmp_path):
    path = LOGS / log
    if not path.is_file():
        pytest.skip(f"shared log {path} not present (tests read ../shared/logs)")
    old = _old_code(tmp_path)
    out = tmp_path / "old.npz"
    env = dict(os.environ, PYTHONPATH=str(old))
    subprocess.run([sys.executable, "-c", _SCRIPT % (FILTERS,), str(path), str(out)],
                   env=env, check=True, cwd=tmp_path)
    ref = np.load(out)
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
