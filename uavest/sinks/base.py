"""The sink contract and the collecting sink.

A sink is told when a run opens (:meth:`Sink.open`, with the run's
:class:`~uavest.engine.records.RunInfo`), receives every raw sample the source produced
(:meth:`Sink.sample`, for recorders), every estimator start (:meth:`Sink.start`), every
record (:meth:`Sink.record`), and is closed once (:meth:`Sink.close`), also when the run
stops on an error or a signal. Every method has a no-op default, so a sink implements only
what it needs.
"""

from __future__ import annotations

import logging
from collections import defaultdict

import numpy as np

from ..engine.records import RunInfo, ScanRecord, StepRecord

__all__ = ["Collector", "ResetLog", "Sink"]


class Sink:
    """Base class of sinks (all methods optional)."""

    def open(self, info: RunInfo) -> None:  # noqa: B027 - optional hook
        pass

    def sample(self, s) -> None:  # noqa: B027
        pass

    def start(self, label: str, t0: float, x0: np.ndarray, P0: np.ndarray) -> None:  # noqa: B027
        pass

    def record(self, rec: StepRecord | ScanRecord) -> None:  # noqa: B027
        pass

    def close(self) -> None:  # noqa: B027
        pass


class Collector(Sink):
    """Keeps every record in memory, per estimator label (for offline work: Monte Carlo
    trials, smoothing, tests). ``arrays(label)`` stacks a single-state estimator's
    records into ``t`` (K,), ``x`` (K, size), ``P`` (K, n, n), ``nis`` (K,)."""

    def __init__(self) -> None:
        self.records: dict[str, list] = defaultdict(list)
        self.starts: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}

    def start(self, label, t0, x0, P0) -> None:
        self.starts[label] = (t0, x0, P0)

    def record(self, rec) -> None:
        self.records[rec.estimator].append(rec)

    def arrays(self, label: str) -> dict[str, np.ndarray]:
        recs = self.records[label]
        out = {
            "t": np.array([r.t for r in recs]),
            "x": np.array([r.x for r in recs]),
            "P": np.array([r.P for r in recs]),
            "nis": np.array([np.nan if r.nis is None else r.nis for r in recs]),
            "reset": np.array([r.reset for r in recs]),
            "wall_s": np.array([r.wall_s for r in recs]),
        }
        if recs and recs[0].x_pred is not None:
            out["x_pred"] = np.array([r.x_pred for r in recs])
            out["P_pred"] = np.array([r.P_pred for r in recs])
        if recs and recs[0].C is not None:
            out["C"] = np.array([r.C for r in recs])
        return out


class ResetLog(Sink):
    """Logs every divergence reset as it happens (``logging`` INFO on ``uavest.filters``;
    the command line shows INFO with ``-v``) and counts them per estimator."""

    def __init__(self) -> None:
        self.log = logging.getLogger("uavest.filters")
        self.counts: dict[str, int] = defaultdict(int)

    def record(self, rec) -> None:
        if isinstance(rec, StepRecord) and rec.reset:
            self.counts[rec.estimator] += 1
            self.log.info("%s reset at t = %.3f s: %s", rec.estimator, rec.t, rec.reason)
