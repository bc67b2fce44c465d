"""Batched gating (issue 13) gives the tracks the per-track loop gave: same ids, births,
deletions, confirmations and states (to 1e-9) on seeded multi-target runs with clutter.
The per-track ``_gate`` it replaced is kept here verbatim as the reference."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.core import make_filter
from uavest.core.guard import Guarded, nis_gate
from uavest.core.linalg import chol
from uavest.models.motion import NearlyConstantVelocity
from uavest.models.radar import RadarMeasurement
from uavest.tracking.tracker import (
    Tracker,
    TrackerConfig,
    predicted_measurement,
    predicted_measurements,
)


class _LoopGuard(Guarded):
    """The guard without its batched forms: one state at a time, as before."""

    def predict_many(self, states, model, t, dt, u=None, rng=None):
        return [self.predict(s, model, t, dt, u, rng) for s in states]

    def update_many(self, states, zs, model, rng=None):
        return [self.update(s, z, model, rng) for s, z in zip(states, zs, strict=True)]


class LoopTracker(Tracker):
    """The tracker with the pre-change gating (one unscented transform per track) and
    predicts / updates one track at a time."""

    def __init__(self, filt, motion, cfg, rng):
        super().__init__(filt, motion, cfg, rng)
        self.filter = _LoopGuard(filt, strikes=10**9)

    def _gate(self, tracks, Z, meas):
        T, N = len(tracks), len(Z)
        d2 = np.full((T, N), np.inf)
        cost = np.full((T, N), np.inf)
        g = nis_gate(meas.dim, self.cfg.gate_prob)
        for i, tr in enumerate(tracks):
            zhat, S = predicted_measurement(tr.pred, meas)
            L = chol(S)
            nu = meas.residual(Z, zhat)
            u = np.linalg.solve(L, nu.T)
            di = np.einsum("ij,ij->j", u, u)
            ok = di <= g
            d2[i, ok] = di[ok]
            cost[i, ok] = di[ok] + 2.0 * np.log(np.diag(L)).sum()
        return d2, cost


def _scans(n_targets: int, n_scans: int, seed: int, radar, motion, clutter: int = 10):
    rng = np.random.default_rng(seed)
    ang = rng.uniform(-np.pi, np.pi, n_targets)
    rad = rng.uniform(2000.0, 12000.0, n_targets)
    X = np.stack([rad * np.cos(ang), rad * np.sin(ang), rng.normal(0, 30, n_targets),
                  rng.normal(0, 30, n_targets)], axis=1)
    lo, hi = radar.measurement_box(15000.0)
    out = []
    for _ in range(n_scans):
        X = motion.f(X, 0.0, 1.0) + rng.normal(0, 0.5, X.shape)
        det = rng.random(n_targets) < 0.9
        Z = np.vstack([radar.sample(X[det], rng), lo + (hi - lo) * rng.random((clutter, 2))])
        out.append(Z[rng.permutation(len(Z))])
    return out


def _run(cls, spec, cfg, scans, radar, motion):
    tk = cls(make_filter(spec), motion, cfg, np.random.default_rng(3))
    for k, Z in enumerate(scans):
        tk.step(k + 1, float(k + 1), 1.0, Z, radar)
    return tk


@pytest.mark.parametrize("spec", ["ukf", "ekf", "hybrid(update_mode=local, n_cloud=4)"])
@pytest.mark.parametrize("association", ["gnn", "jpda"])
def test_batched_gating_gives_the_same_tracks(spec, association):
    motion = NearlyConstantVelocity(2, 0.5)
    radar = RadarMeasurement(2, sigma_range=10.0, sigma_az=np.deg2rad(1.0))
    scans = _scans(12, 25, 11, radar, motion)
    cfg = TrackerConfig(association=association, pd=0.9, clutter_density=1e-4)
    new = _run(Tracker, spec, cfg, scans, radar, motion)
    old = _run(LoopTracker, spec, cfg, scans, radar, motion)
    assert len(new.all_tracks) == len(old.all_tracks) > 12  # clutter starts tracks too
    for a, b in zip(new.all_tracks, old.all_tracks, strict=True):
        assert (a.id, a.born, a.status, a.confirmed_at, a.deleted_at, a.hits) == (
            b.id, b.born, b.status, b.confirmed_at, b.deleted_at, b.hits)
        assert len(a.history) == len(b.history)
        for ha, hb in zip(a.history, b.history, strict=True):
            assert ha[0] == hb[0] and ha[3:] == hb[3:]
            np.testing.assert_allclose(ha[2].x, hb[2].x, rtol=0, atol=1e-9)
            np.testing.assert_allclose(ha[2].P, hb[2].P, rtol=1e-9, atol=1e-9)
    assert sum(t.status == "confirmed" for t in new.tracks) >= 8


def test_predicted_measurements_equal_the_per_track_transform():
    rng = np.random.default_rng(0)
    from uavest.core.gaussian import Gaussian

    radar = RadarMeasurement(3, sigma_range=5.0, sigma_rr=1.0)
    gs = []
    for _ in range(7):
        A = rng.standard_normal((6, 6))
        gs.append(Gaussian(rng.normal(0, 3000, 6) * [1, 1, 0.1, 0.01, 0.01, 0.01],
                           A @ A.T + np.eye(6)))
    gs[0] = Gaussian(np.array([-5000.0, 1.0, 10, 0, 0, 0]), 1e4 * np.eye(6))  # near +-pi
    zhat, S = predicted_measurements(gs, radar)
    for i, g in enumerate(gs):
        z1, S1 = predicted_measurement(g, radar)
        np.testing.assert_allclose(zhat[i], z1, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(S[i], S1, rtol=1e-10, atol=1e-10)
