"""The channels of a generic vector-state run (``/truth/state``, ``/measurement/z``,
``/state/<label>/estimate``, ``.../health``, ``.../error``): x and P in the system's own
units and coordinates, JSON."""

from __future__ import annotations

import math

import numpy as np

from ...engine.records import StateSample, StepRecord
from .attitude import AttitudeChannels
from .channels import ChannelSet, Scene
from .encode import _floats

Array = np.ndarray

__all__ = ["StateChannels"]


class StateChannels:
    """Truth, measurements and estimates of generic vector states; the health channel is
    the attitude estimators' (:meth:`.attitude.AttitudeChannels.health`)."""

    def __init__(self, chans: ChannelSet, scene: Scene, attitude: AttitudeChannels) -> None:
        self.chans = chans
        self.scene = scene
        self.attitude = attitude
        # the latest truth (t, x) and the largest state size
        self.state_truth: tuple[float, Array] | None = None
        self.state_dim = 0

    def sample(self, s: StateSample) -> None:
        """Truth and measurement of a generic vector-state step (``/truth/state``,
        ``/measurement/z``); the truth is kept for the error of the step's records."""
        self.scene.kind = "state"
        if s.x is not None:
            x = np.asarray(s.x, float).ravel()
            self.state_truth = (float(s.t), x)
            self.chans.json("/truth/state", "uavest.StateTruth", s.t,
                       {"t": s.t, "k": int(s.k), "x": _floats(x)})
        if s.z is not None:
            self.chans.json("/measurement/z", "uavest.Measurement", s.t,
                       {"t": s.t, "k": int(s.k), "z": _floats(s.z)})

    def record(self, rec: StepRecord) -> None:
        """A generic vector-state step: ``/state/<label>/estimate``, ``.../health`` and,
        when the truth of the same step was seen, ``.../error`` (estimate - truth, the
        filter's own +-3 sigma, NEES with dof n). The state is a plain vector (x and P in
        the same coordinates); a state whose covariance is of another size has no error
        channel."""
        lab, t = rec.estimator, rec.t
        self.scene.label(lab)
        x = np.asarray(rec.x, float).ravel()
        P = np.asarray(rec.P, float).reshape(x.size, -1) if np.size(rec.P) else \
            np.zeros((x.size, 0))
        self.state_dim = max(self.state_dim, int(x.size))
        d = np.diagonal(P) if P.shape[0] == P.shape[1] else np.full(x.size, np.nan)
        with np.errstate(invalid="ignore"):
            s3 = 3.0 * np.sqrt(d)
        s3l = _floats(s3)
        self.chans.json(f"/state/{lab}/estimate", "uavest.StateEstimate", t, {
            "t": t, "k": int(rec.k), "n": int(x.size), "x": _floats(x), "sigma3": s3l,
            "P": _floats(P)})
        self.attitude.health(f"/state/{lab}/health", rec)
        tr = self.state_truth
        if tr is not None and tr[0] == t and tr[1].size == x.size == P.shape[0] == P.shape[1]:
            e = x - tr[1]
            try:
                ne = float(e @ np.linalg.solve(P, e))
            except np.linalg.LinAlgError:
                ne = math.nan
            self.chans.json(f"/state/{lab}/error", "uavest.StateError", t, {
                "t": t, "k": int(rec.k), "err": _floats(e), "sigma3": s3l,
                "neg_sigma3": _floats(-s3), "nees": ne if math.isfinite(ne) else None,
                "dof": int(x.size)})
