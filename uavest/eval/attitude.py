"""Scoring attitude estimates against a reference: Euler-angle RMSE and NEES.

Errors are taken between ZYX Euler angles (roll, pitch, yaw; see
:mod:`uavest.geometry.rotation`) as wrapped differences in degrees (yaw modulo 360, so 359
vs 1 is a 2 degree error). The reference is interpolated (slerp) at the estimate's times;
estimate times outside the reference's span are not scored.

NEES is computed on the attitude part only (3 degrees of freedom, the reference has no
gyro bias): ``e = Log(q_est^-1 q_ref)`` (body-frame error, the filter's tangent
convention) and ``nees = e^T P[:3, :3]^-1 e``; a consistent filter averages 3.
"""

from __future__ import annotations

from bisect import bisect_right

import numpy as np

from ..geometry.rotation import (
    quat_conj,
    quat_log,
    quat_mul,
    quat_to_euler,
    slerp_one,
    wrap_pi,
)

Array = np.ndarray

__all__ = [
    "AUTOPILOT_SOURCES",
    "AttitudeScorer",
    "euler_errors_deg",
    "nees_attitude",
    "rmse_deg",
    "choose_reference",
    "reference_problem",
    "select_reference",
]

#: Preference order among autopilot estimates (first present wins).
AUTOPILOT_SOURCES = ("ATTITUDE_QUATERNION", "ATTITUDE", "ATT", "vehicle_attitude")
TRUTH_SOURCES = ("SIMSTATE", "SIM_STATE", "SIM", "HIL_STATE_QUATERNION")


MIN_REF_SAMPLES = 10  # a reference with fewer samples cannot score a run
MIN_REF_RATE_HZ = 0.2  # ... nor one slower than this (or faster than MAX_REF_RATE_HZ)
MAX_REF_RATE_HZ = 20_000.0
MIN_REF_COVERAGE = 0.5  # fraction of the scored window the reference must span


def _span(r) -> tuple[int, float, float]:
    """(samples, first time, last time) of a reference (RefSeries or the scorer's track)."""
    n = len(r)
    t0 = getattr(r, "t_first", None)
    t1 = getattr(r, "t_last", None)
    if t0 is None or t1 is None:
        t = np.asarray(r.t, dtype=float)
        t0, t1 = (float(t[0]), float(t[-1])) if t.size else (np.nan, np.nan)
    return n, float(t0), float(t1)


def reference_problem(r, window: tuple[float, float] | None = None) -> str | None:
    """Why reference ``r`` cannot score a run over ``window`` (s, the first and last
    step), or None if it can: at least :data:`MIN_REF_SAMPLES` samples, a rate between
    :data:`MIN_REF_RATE_HZ` and :data:`MAX_REF_RATE_HZ`, and (with a window) spanning at
    least :data:`MIN_REF_COVERAGE` of it."""
    n, t0, t1 = _span(r)
    if n < MIN_REF_SAMPLES:
        return f"{n} usable sample{'s' if n != 1 else ''} (needs >= {MIN_REF_SAMPLES})"
    span = t1 - t0
    rate = (n - 1) / span if span > 0 else float("inf")
    if not (MIN_REF_RATE_HZ <= rate <= MAX_REF_RATE_HZ):
        return f"implausible rate {rate:.3g} Hz ({n} samples over {span:.3g} s)"
    if window is not None:
        w0, w1 = window
        if w1 > w0:
            cover = max(0.0, min(t1, w1) - max(t0, w0)) / (w1 - w0)
            if cover < MIN_REF_COVERAGE:
                return (f"covers {100 * cover:.0f} % of the scored window "
                        f"{w0:.1f}-{w1:.1f} s (needs >= {100 * MIN_REF_COVERAGE:.0f} %)")
    return None


def choose_reference(
    refs: dict, window: tuple[float, float] | None = None
) -> tuple[str | None, str | None, dict[str, str]]:
    """(reference source, autopilot source, {rejected source: reason}).

    Preference: truth (``kind == "truth"``), then the autopilot's estimate, then AHRS2;
    the first candidate that qualifies (:func:`reference_problem`) is the reference, the
    ones before it that did not are returned with the reason. The autopilot source is the
    preferred autopilot estimate that qualifies (None if none).
    """
    truth = [k for k in TRUTH_SOURCES if k in refs and refs[k].kind == "truth"]
    truth += [k for k, v in refs.items() if v.kind == "truth" and k not in truth]
    auto = [k for k in AUTOPILOT_SOURCES if k in refs]
    auto += [k for k, v in refs.items() if v.kind == "autopilot" and k not in auto]
    other = [k for k, v in refs.items() if v.kind == "ahrs2"]
    rejected: dict[str, str] = {}
    chosen = None
    for k in truth + auto + other:
        why = reference_problem(refs[k], window)
        if why is None:
            chosen = k
            break
        rejected[k] = why
    ap = next((k for k in auto if reference_problem(refs[k], window) is None), None)
    return chosen, ap, rejected


def select_reference(
    refs: dict, window: tuple[float, float] | None = None
) -> tuple[str | None, str | None]:
    """(reference source, autopilot source) from ``LogData.references`` (or the scorer's
    references): :func:`choose_reference` without the reasons. Either may be None."""
    ref, ap, _ = choose_reference(refs, window)
    return ref, ap


def euler_errors_deg(q_est: Array, q_ref: Array) -> Array:
    """(N, 3) wrapped (estimate - reference) roll, pitch, yaw errors in degrees."""
    d = wrap_pi(quat_to_euler(q_est) - quat_to_euler(q_ref))
    return np.rad2deg(d)


def rmse_deg(q_est: Array, q_ref: Array, mask: Array | None = None) -> dict[str, float]:
    """Roll, pitch, yaw RMSE (degrees) of ``q_est`` against ``q_ref`` over ``mask``."""
    e = euler_errors_deg(q_est, q_ref)
    if mask is not None:
        e = e[mask]
    if e.shape[0] == 0:
        nan = float("nan")
        return {"roll_rmse_deg": nan, "pitch_rmse_deg": nan, "yaw_rmse_deg": nan, "n": 0}
    r = np.sqrt(np.mean(e * e, axis=0))
    return {
        "roll_rmse_deg": float(r[0]),
        "pitch_rmse_deg": float(r[1]),
        "yaw_rmse_deg": float(r[2]),
        "n": int(e.shape[0]),
    }


def nees_attitude(q_est: Array, P: Array, q_true: Array) -> Array:
    """Per-step attitude NEES (3 dof): ``e^T P[:3,:3]^-1 e``, e = Log(q_est^-1 q_true)."""
    e = quat_log(quat_mul(quat_conj(q_est), q_true))
    Pa = P[:, :3, :3]
    sol = np.linalg.solve(Pa, e[..., None])[..., 0]
    return np.einsum("ij,ij->i", e, sol)


_WAIT = object()  # a reference has not reached that time yet


class _RefTrack:
    """What the scorer keeps of one reference source: its kind, its sample count, and its
    samples from just before the oldest step still waiting (times ``t``, quaternions
    ``q``)."""

    __slots__ = ("kind", "n", "t", "q", "t_first", "t_last")

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.n = 0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.t: list[float] = []
        self.q: list[Array] = []

    def __len__(self) -> int:
        return self.n

    def at(self, t: float, final: bool = False):
        """The reference at ``t`` (slerp), None outside its span, ``_WAIT`` if it may
        still reach ``t`` (never when ``final``)."""
        ts = self.t
        if not ts or ts[-1] < t:
            return None if final else _WAIT
        if t < ts[0]:
            return None
        if len(ts) == 1:
            return self.q[0]
        i = min(bisect_right(ts, t) - 1, len(ts) - 2)
        s = min(max((t - ts[i]) / (ts[i + 1] - ts[i]), 0.0), 1.0)
        return np.array(slerp_one(self.q[i], self.q[i + 1], s))

    def trim(self, t: float) -> None:
        """Forget samples not needed for steps at or after ``t``."""
        i = bisect_right(self.t, t) - 1
        if i > 0:
            del self.t[:i], self.q[:i]


class AttitudeScorer:
    """Streaming :func:`rmse_deg` / :func:`nees_attitude` of estimators against every
    reference source at once, with memory bounded by the references' lag.

    Feed, in any interleaving, each estimator's estimate per step (:meth:`add_estimate`,
    steps in time order) and every reference sample (:meth:`add_reference`, each source in
    time order). A step is scored against a reference once a reference sample at or after
    it has arrived (slerp between the two samples around it, as
    :func:`~uavest.geometry.rotation.quat_slerp_interp`); steps outside a reference's span
    are not scored against it. :meth:`scores` then gives per-estimator rows against any
    reference, and rows for the other references scored against it. Equal, up to
    rounding, to the batch functions over whole arrays; at most ``max_pending`` steps wait
    for a late reference (older ones are scored without it, counted in ``unscored``).

    With ``settle_s`` (s, > 0) each estimator is also scored over its steps ``settle_s``
    or more after its own first step (:meth:`scores`' ``settled`` block: a start in
    flight converges first), as :class:`~uavest.eval.navigation.NavScorer` does."""

    def __init__(self, max_pending: int = 50_000, settle_s: float | None = None) -> None:
        self.refs: dict[str, _RefTrack] = {}
        self.pending: list = []  # [t, {label: (q, P3)}, {ref: q or None}, score refs]
        self.head = 0  # index of the first unfinished pending entry
        self.max_pending = max_pending
        self.acc: dict[tuple[str, str], list] = {}
        self.unscored = 0
        self.t_new: float | None = None
        self.t_first: float | None = None  # first step time (the scored window's start)
        self._done: list = []
        self.settle_s = settle_s if settle_s is not None and settle_s > 0 else None
        self.first: dict[str, float] = {}  # each estimator's first step time (s)
        self.acc_settled: dict[tuple[str, str], list] = {}

    def add_estimate(self, t: float, label: str, q: Array, P: Array) -> None:
        """One estimator's attitude ``q`` (4,) and tangent covariance ``P`` at step
        time ``t``; estimators of the same step share ``t``."""
        p = self.pending
        if self.t_first is None:
            self.t_first = t
        self.first.setdefault(label, t)
        if len(p) > self.head and p[-1][0] == t:
            p[-1][1][label] = (q, P[:3, :3])
            self.t_new = t
            return
        # the step's first entry may already be finished (every reference had reached t
        # when the first estimator's estimate came): this entry then carries only the
        # estimators, and the references are not scored against each other a second time
        first = self.t_new != t
        self.t_new = t
        e = [t, {label: (q, P[:3, :3])}, {}, first]
        p.append(e)
        for name, r in self.refs.items():
            v = r.at(t)
            if v is not _WAIT:
                e[2][name] = v
        self._advance()
        if len(p) - self.head > self.max_pending:
            self._finalise_one(force=True)

    def add_reference(self, name: str, kind: str, t: float, q: Array) -> None:
        r = self.refs.get(name)
        if r is None:
            r = self.refs[name] = _RefTrack(kind)
        if r.t and t <= r.t[-1]:
            return  # not after the previous sample: dropped, as read_log de-duplicates
        r.t.append(t)
        r.q.append(q)
        r.n += 1
        if r.t_first is None:
            r.t_first = t
        r.t_last = t
        for e in self.pending[self.head:]:
            if name in e[2]:
                continue
            v = r.at(e[0])
            if v is _WAIT:
                break
            e[2][name] = v
        self._advance()
        if self.head < len(self.pending):
            r.trim(self.pending[self.head][0])
        elif self.t_new is not None:  # later steps come at or after the newest one seen
            r.trim(self.t_new)

    def _advance(self) -> None:
        while self.head < len(self.pending) and self._ready(self.pending[self.head]):
            self._finalise_one()

    def _ready(self, e) -> bool:
        return all(name in e[2] for name in self.refs)

    def _finalise_one(self, force: bool = False) -> None:
        e = self.pending[self.head]
        if force and not self._ready(e):
            self.unscored += 1
        self.head += 1
        self._done.append(e)
        if len(self._done) >= 256:
            self._flush()
        if self.head > 4096:  # drop finished entries
            del self.pending[: self.head]
            self.head = 0
    def _flush(self) -> None:
        done, self._done = self._done, []
        if not done:
            return
        refs = list(self.refs)
        labels = sorted({lab for e in done for lab in e[1]})
        for rname in refs:
            rows = [i for i, e in enumerate(done) if e[2].get(rname) is not None]
            if not rows:
                continue
            qr = np.array([done[i][2][rname] for i in rows])
            cands = [(lab, 1) for lab in labels] + [(o, 2) for o in refs if o != rname]
            for name, where in cands:
                sel = [(j, done[i][where].get(name)) for j, i in enumerate(rows)
                       if where == 1 or done[i][3]]
                sel = [(j, v) for j, v in sel if v is not None]
                if not sel:
                    continue
                idx = np.array([j for j, _ in sel])
                if where == 1:
                    q = np.array([v[0] for _, v in sel])
                    P3 = np.array([v[1] for _, v in sel])
                else:
                    q, P3 = np.array([v for _, v in sel]), None
                err = euler_errors_deg(q, qr[idx])
                ne = None
                if P3 is not None:
                    P = np.zeros((len(idx), 6, 6))
                    P[:, :3, :3] = P3
                    ne = nees_attitude(q, P, qr[idx])
                _accumulate(self.acc, (name, rname), err, ne)
                if where == 1 and self.settle_s is not None:
                    t = np.array([done[rows[j]][0] for j in idx])
                    late = t >= self.first[name] + self.settle_s
                    if late.any():
                        _accumulate(self.acc_settled, (name, rname), err[late],
                                    None if ne is None else ne[late])

    @property
    def window(self) -> tuple[float, float] | None:
        """(first, last) step time scored, or None before any step."""
        return None if self.t_first is None else (self.t_first, self.t_new)

    def finish(self) -> None:
        """Score what is still waiting (no later reference sample will come)."""
        while self.head < len(self.pending):
            e = self.pending[self.head]
            for name, r in self.refs.items():
                if name not in e[2]:
                    e[2][name] = r.at(e[0], final=True)
            self._finalise_one()
        self._flush()

    def scores(self, name: str, ref: str, truth: bool) -> dict:
        """Roll/pitch/yaw RMSE (deg), count ``n`` and, against truth, ``nees_mean``, of
        estimator or reference ``name`` against reference ``ref``; with ``settle_s``, an
        estimator's ``settled`` block (the same keys and ``after_s``) when it has steps
        that late."""
        d = _row(self.acc.get((name, ref)), truth)
        late = self.acc_settled.get((name, ref))
        if late is not None and late[1]:
            d["settled"] = {**_row(late, truth), "after_s": float(self.settle_s or 0.0)}
        return d


def _accumulate(acc: dict, key: tuple[str, str], err: Array, ne: Array | None) -> None:
    """Add the Euler errors ``err`` (N, 3) deg and the NEES ``ne`` (N,) to ``acc[key]``
    (sum of squares, count, NEES sum, NEES count)."""
    a = acc.setdefault(key, [np.zeros(3), 0, 0.0, 0])
    a[0] += np.sum(err * err, axis=0)
    a[1] += err.shape[0]
    if ne is not None:
        a[2] += float(np.sum(ne))
        a[3] += ne.shape[0]


def _row(a: list | None, truth: bool) -> dict:
    """The scores of one accumulator (:func:`_accumulate`)."""
    if a is None or a[1] == 0:
        nan = float("nan")
        return {"roll_rmse_deg": nan, "pitch_rmse_deg": nan, "yaw_rmse_deg": nan, "n": 0}
    r = np.sqrt(a[0] / a[1])
    d = {"roll_rmse_deg": float(r[0]), "pitch_rmse_deg": float(r[1]),
         "yaw_rmse_deg": float(r[2]), "n": int(a[1])}
    if truth and a[3]:
        d["nees_mean"] = a[2] / a[3]
    return d
