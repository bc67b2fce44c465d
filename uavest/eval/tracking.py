"""Tracking metrics: RMSE, NEES and its chi-square band, GOSPA, track quality.

Conventions (documented in docs/tracking.md):

* **Time-averaged RMSE**: per step k, RMSE_k = sqrt(mean over runs |e_k|^2); reported
  value = mean over k of RMSE_k. The PCRLB is averaged the same way (per-step
  sqrt(trace of the position block of J_k^-1), then mean over k).
* **NEES**: per step, the run-averaged e^T P^-1 e; reported value = mean over steps.
  Its 95% band for R runs of an n-dim state: chi2.ppf([0.025, 0.975], R n) / R.
* **GOSPA** (Rahmathullah, Garcia-Fernandez, Svensson 2017) with alpha = 2, order p,
  cut-off c: d = (min_assignment sum d(x, y)^p + c^p / 2 (#missed + #false))^(1/p).
* **Track quality** from the per-step GOSPA assignment of confirmed tracks to truths
  (pairs closer than c):
  - *track break*: a truth that had an assigned track becomes unassigned while it still
    exists (track lost / fragmented);
  - *ID swap* (counted per swap event, not per truth): a truth's assigned track id
    changes from a to b (ignoring unassigned gaps) and track b had earlier been assigned
    to another truth (tracks exchanged targets). Two tracks exchanged between two truths
    (truth i: a -> b and truth j: b -> a, at the same scan or not) are **one** swap; a
    one-sided take-over (truth j does not get a back) is one swap too. A change to a
    track never assigned before counts as a *re-acquisition* (not a swap);
  - *false track*: a confirmed track assigned to some truth in fewer than half of the
    steps it was confirmed;
  - *time to confirm*: first step with an assigned confirmed track minus the truth's
    first step, times dt (s), averaged over truths that got a track.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .metrics import nees, nees_band  # noqa: F401  (re-exported for tracking callers)

Array = np.ndarray


def gospa(
    X: Array, Y: Array, c: float = 100.0, p: float = 2.0
) -> tuple[float, list[tuple[int, int]], float, int, int]:
    """GOSPA (alpha = 2) between truths ``X`` (m, d) and estimates ``Y`` (n, d).

    Returns (gospa, pairs [(i_truth, j_est)] with distance < c, localisation part,
    #missed, #false)."""
    m, n = len(X), len(Y)
    if m == 0 and n == 0:
        return 0.0, [], 0.0, 0, 0
    if m == 0 or n == 0:
        return float((c**p / 2 * (m + n)) ** (1 / p)), [], 0.0, m, n
    D = np.linalg.norm(X[:, None, :] - Y[None, :, :], axis=2)
    C = np.minimum(D, c) ** p
    from scipy.optimize import linear_sum_assignment  # lazily: start-up time

    ri, ci = linear_sum_assignment(C)
    pairs = [(int(i), int(j)) for i, j in zip(ri, ci, strict=True) if D[i, j] < c]
    loc = float(sum(D[i, j] ** p for i, j in pairs))
    missed = m - len(pairs)
    false = n - len(pairs)
    val = (loc + c**p / 2 * (missed + false)) ** (1 / p)
    return float(val), pairs, loc, missed, false


@dataclass
class QualityReport:
    """Track quality of one run (see module docstring for definitions)."""

    gospa: float = 0.0
    track_breaks: int = 0
    id_swaps: int = 0
    false_tracks: int = 0
    #: distinct tracks confirmed at some time in the run (cumulative: a target whose track
    #: broke and was confirmed again counts twice; reported as ``tracks_confirmed_total``)
    confirmed_tracks: int = 0
    time_to_confirm: float | None = None
    assigned: dict = field(default_factory=dict)  # truth id -> list of (step, track id)


def track_quality(
    truth_steps: list[dict[int, Array]],
    track_steps: list[dict[int, Array]],
    c: float = 100.0,
    p: float = 2.0,
    dt: float = 1.0,
) -> QualityReport:
    """Quality metrics from per-step {truth id: position} and {confirmed track id:
    position} dictionaries (same length, one entry per scan)."""
    rep = QualityReport()
    g_sum = 0.0
    prev: dict[int, int | None] = {}
    last: dict[int, int] = {}
    pending: dict[tuple[int, int], int] = {}  # (old, new track) of a counted swap -> truth
    track_truths: dict[int, set[int]] = {}
    track_conf_steps: dict[int, int] = {}
    track_hit_steps: dict[int, int] = {}
    first_truth: dict[int, int] = {}
    first_assigned: dict[int, int] = {}
    for k, (tr, tk) in enumerate(zip(truth_steps, track_steps, strict=True)):
        tids, kids = list(tr), list(tk)
        X = np.array([tr[i] for i in tids]) if tids else np.zeros((0, 1))
        Y = np.array([tk[j] for j in kids]) if kids else np.zeros((0, 1))
        g, pairs, _, _, _ = gospa(X, Y, c, p)
        g_sum += g
        amap = {tids[i]: kids[j] for i, j in pairs}
        for j in kids:
            track_conf_steps[j] = track_conf_steps.get(j, 0) + 1
        for tid in tids:
            first_truth.setdefault(tid, k)
            a = amap.get(tid)
            if a is None:
                if prev.get(tid) is not None:
                    rep.track_breaks += 1
            else:
                track_hit_steps[a] = track_hit_steps.get(a, 0) + 1
                first_assigned.setdefault(tid, k)
                rep.assigned.setdefault(tid, []).append((k, a))
                if tid in last and last[tid] != a:
                    if any(o != tid for o in track_truths.get(a, ())):
                        # the other half of an exchange already counted (b -> a by
                        # another truth) completes that swap; otherwise a new swap
                        other = pending.get((a, last[tid]))
                        if other is not None and other != tid:
                            del pending[(a, last[tid])]
                        else:
                            rep.id_swaps += 1
                            pending[(last[tid], a)] = tid
                last[tid] = a
                track_truths.setdefault(a, set()).add(tid)
            prev[tid] = a
        for tid in list(prev):
            if tid not in tr:
                prev[tid] = None  # truth ended: not a break
    rep.gospa = g_sum / max(len(truth_steps), 1)
    rep.confirmed_tracks = len(track_conf_steps)
    rep.false_tracks = sum(
        1 for j, n in track_conf_steps.items() if track_hit_steps.get(j, 0) < 0.5 * n
    )
    ttc = [(first_assigned[t] - first_truth[t]) * dt for t in first_assigned]
    rep.time_to_confirm = float(np.mean(ttc)) if ttc else None
    return rep
