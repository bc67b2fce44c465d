"""Estimators the engine runs: :class:`FilterRunner` (any filter of the core, guarded) and
:class:`TrackerRunner` (the multi-target tracker). :meth:`FilterRunner.step` is the one
predict/update loop of the package: replay, live runs, Monte Carlo trials, radar
filter-mode trials and the speed benchmark all step filters through it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..core.guard import Guarded
from .records import ScanRecord, Start, Step, StepRecord, TrackEstimate, Update

Array = np.ndarray

__all__ = ["WARMUP_STEPS", "FilterRunner", "TrackerRunner"]

#: Steps of each filter left out of :attr:`FilterRunner.timed_seconds`: one-time costs
#: (numba compilation, caches filled on first use) land in the first steps and were
#: charged to whichever filter ran first (``ekf`` alone 3359 us/step, listed second 733).
WARMUP_STEPS = 5


class FilterRunner:
    """Runs one filter over steps and makes a :class:`StepRecord` per step.

    ``filter`` is a core filter (wrapped in :class:`Guarded` unless ``guard`` is False or
    it is one already); ``rng`` its own generator (see :mod:`uavest.seeding`).
    ``record_prediction``: also record the prediction's mean/covariance before the
    updates; ``smooth``: also record what RTS smoothing needs, through the filter
    contract's ``rts_terms`` (the prediction to pair with the cross-covariance C, and C;
    wall time of that is not counted in ``wall_s``)."""

    def __init__(
        self,
        label: str,
        filter: Any,
        rng: np.random.Generator,
        *,
        guard: bool | Guarded = True,
        record_prediction: bool = False,
        smooth: bool = False,
    ) -> None:
        self.label = label
        if isinstance(guard, Guarded):
            self.filter = guard
        elif guard and not isinstance(filter, Guarded):
            self.filter = Guarded(filter)
        else:
            self.filter = filter
        self.rng = rng
        self.record_prediction = record_prediction
        self.smooth = smooth
        self.state: Any = None  # the filter's state (its own type), None before start
        self.space: Any = None
        self.smooth_seconds = 0.0
        self.seconds = 0.0  # wall time of all steps (without smoothing's share)
        self.steps = 0
        self.timed_seconds = 0.0  # wall time of the steps after the first WARMUP_STEPS
        self.timed_steps = 0
        self._last: Any = None
        #: (step time s, why) of every step whose record says the filter reset
        self.reset_log: list[tuple[float, str]] = []

    def start(self, st: Start) -> None:
        self.space = st.space
        prior, resets = st.prior, None
        if self.state is not None:  # a restart: the guard's reset count carries on
            resets = getattr(self.state, "resets", None)
            if st.augment is not None:
                prior = st.augment(self.filter.estimate(self.state))
            kx, kp = st.keep_x, st.keep_P
            if st.keep_tail:
                n, nx, nP = st.keep_tail, len(prior.x), len(prior.P)
                kx, kp = tuple(range(nx - n, nx)), tuple(range(nP - n, nP))
            if kx:
                old = self.filter.estimate(self.state)
                x, P = np.array(prior.x, float), np.array(prior.P, float)
                ix, ip = np.array(kx), np.array(kp)
                x[ix] = old.x[ix]
                Pk = old.P[np.ix_(ip, ip)]
                P[ip, :] = 0.0
                P[:, ip] = 0.0
                P[np.ix_(ip, ip)] = Pk
                prior = type(prior)(x, P)
        self.state = self.filter.init(prior, st.space, self.rng)
        if resets:
            from dataclasses import replace

            self.state = replace(self.state, resets=resets)
        self._last = prior  # the previous step's estimate (smoothing pairs with it)
        self.started_from = prior  # what the sinks are told it started from

    def step(self, st: Step) -> StepRecord:
        f, rng = self.filter, self.rng
        c0 = time.perf_counter()
        s0 = self.state
        s = f.predict(s0, st.transition, st.t, st.dt, st.u, rng)
        x_pred = P_pred = C = None
        if self.record_prediction or self.smooth:
            gp = f.estimate(s)
            x_pred, P_pred = gp.x, gp.P
        if self.smooth:
            c1 = time.perf_counter()
            gp, C = f.rts_terms(s0, s, st.transition, st.t, st.dt, st.u, prev=self._last)
            x_pred, P_pred = gp.x, gp.P
            dt_s = time.perf_counter() - c1
            self.smooth_seconds += dt_s
            c0 += dt_s
        ups: list[Update] = []
        for i, (z, m) in enumerate(st.updates):
            s, inn = self.update(s, z, m, st, i)
            if inn is not None:
                ups.append(Update(type(m).__name__, inn.nu, inn.S, float(inn.nis)))
        g = f.estimate(s)
        self.state = s
        self._last = g
        wall = time.perf_counter() - c0
        self.seconds += wall
        self.steps += 1
        if self.steps > WARMUP_STEPS:
            self.timed_seconds += wall
            self.timed_steps += 1
        return self._finish(StepRecord(
            self.label, st.k, st.t, g.x, g.P, tuple(ups), bool(getattr(s, "reset", False)),
            getattr(s, "reason", ""), int(getattr(s, "resets", 0)), wall, x_pred, P_pred, C,
        ))

    def _finish(self, rec: StepRecord) -> StepRecord:
        """The step's record, its reset (if any) logged in :attr:`reset_log`."""
        if rec.reset:
            self.reset_log.append((float(rec.t), rec.reason))
        return rec

    def update(self, s: Any, z: Array, m: Any, st: Step, i: int) -> tuple[Any, Any]:
        """(state, innovation or None) after the ``i``-th update ``(z, m)`` of step
        ``st``; subclasses gate or count it here (:class:`~uavest.engine.navigation.NavRunner`)."""
        return self.filter.update(s, z, m, self.rng)

    @property
    def resets(self) -> int:
        return int(getattr(self.state, "resets", 0))

    def snapshot(self) -> tuple[Any, ...]:
        """This moment of the run, for :meth:`restore` (a lane's history,
        :mod:`uavest.engine.history`): the filter's state (immutable), the previous
        estimate, the generator's state and the step counters."""
        return (self.state, self.space, self._last, self.rng.bit_generator.state,
                self.steps, self.seconds, self.timed_steps, self.timed_seconds,
                self.smooth_seconds, len(self.reset_log))

    def restore(self, snap: tuple[Any, ...]) -> None:
        (self.state, self.space, self._last, st, self.steps, self.seconds,
         self.timed_steps, self.timed_seconds, self.smooth_seconds, nlog) = snap
        self.rng.bit_generator.state = st
        del self.reset_log[nlog:]

    @property
    def us_per_step(self) -> float:
        """Mean wall time of one predict+update in microseconds, without the first
        :data:`WARMUP_STEPS` steps (all of them when there are no more)."""
        if self.timed_steps:
            return 1e6 * self.timed_seconds / self.timed_steps
        return 1e6 * self.seconds / max(self.steps, 1)


class TrackerRunner:
    """Runs a multi-target :class:`uavest.tracking.tracker.Tracker` over scans: a step's
    single update is ``(Z (N, m) detections, radar model at the scan's pose)``."""

    def __init__(self, label: str, make_tracker: Callable[[], Any]) -> None:
        self.label = label
        self.make_tracker = make_tracker
        # a Tracker (uavest.tracking, a sibling layer the engine does not import)
        self.tracker: Any = None

    def start(self, st: Start) -> None:
        self.tracker = self.make_tracker()

    def snapshot(self) -> tuple[Any, Any]:
        """This moment of the run, for :meth:`restore` (the tracker's own snapshot)."""
        tr = self.tracker
        return tr, (None if tr is None else tr.snapshot())

    def restore(self, snap: tuple[Any, Any]) -> None:
        self.tracker, s = snap
        if self.tracker is not None:
            self.tracker.restore(s)

    def step(self, st: Step) -> ScanRecord:
        ((Z, model),) = st.updates
        tr = self.tracker
        c0 = time.perf_counter()
        before = {t.id for t in tr.tracks}
        tr.step(st.k, st.t, st.dt, Z, model)
        wall = time.perf_counter() - c0
        tracks = []
        resets = 0
        for t in tr.tracks:
            _, gp, ge, hit, conf = t.history[-1]
            born = t.born == st.k
            tracks.append(TrackEstimate(t.id, ge.x, ge.P, conf, hit, None if born else gp.x))
            resets += int(getattr(t.state, "resets", 0))
        deleted = tuple(sorted(before - {t.id for t in tr.tracks}))
        return ScanRecord(self.label, st.k, st.t, tuple(tracks), deleted, resets, wall)
