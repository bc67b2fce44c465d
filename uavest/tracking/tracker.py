"""Multi-target tracker: gating, GNN association, M-of-N initiation, deletion, stable IDs.

Every track runs the same filter (any core filter: ``ekf``, ``ukf``, ``hybrid``...). To
compare filters side by side on the same detections, run one :class:`Tracker` per filter
on the same scans (:func:`uavest.experiments.radar.run_tracker_side_by_side`).

Per scan (time t, detections Z (N, m), radar model at the scan's sensor pose):

1. **Predict** every live track to t.
2. **Gate** (Mahalanobis): for each track the predicted measurement zhat and innovation
   covariance S = Cov(h(x)) + R are computed by the unscented transform of the track's
   Gaussian estimate (the same for every filter, so gating does not favour one);
   detection j is in the gate of track i if d2_ij = nu^T S^-1 nu <= chi2.ppf(gate_prob, m)
   (computed as ``scipy.special.chdtri(m, 1 - gate_prob)``) with nu the angle-wrapped
   residual.
3. **Associate** (``association``):
   ``"gnn"`` (default): global nearest neighbour, scipy's ``linear_sum_assignment`` on
   the cost d2_ij + ln det S_i (negative log-likelihood), out-of-gate pairs forbidden.
   Confirmed tracks are assigned first, tentative tracks then get the remaining
   detections.
   ``"jpda"``: joint probabilistic data association for the confirmed tracks. Tracks that
   share gated detections form a cluster; every joint event of a cluster (each track
   takes at most one of its gated detections, each detection at most one track) has the
   weight prod over assigned pairs of Pd N(nu_ij; 0, S_i) / lambda times prod over
   unassigned tracks of (1 - Pd Pg), lambda the clutter density per unit measurement
   volume and Pg = ``gate_prob``; the association probabilities beta_ij are the
   normalised sums over the events (exact enumeration; clusters of more than
   ``jpda_max_cluster`` tracks fall back to per-track PDA). Tentative tracks use GNN on
   the detections outside every confirmed gate.
4. **Update** assigned tracks with the filter; unassigned tracks coast (predict only).
   Under JPDA a confirmed track is updated with each gated detection separately and the
   hypotheses (plus "none", the prediction) are mixed with weights beta by the filter's
   own ``mix`` (the filter contract, :mod:`uavest.core.contract`): a Gaussian state by
   moment matching, an ensemble state by pooling the members with weights beta_j w_j
   and drawing M of them (systematic), so any filter works unchanged.
5. **Initiate**: each detection left over and outside every confirmed track's gate starts
   a tentative track by *single-point initiation*: position and covariance from the
   converted measurement (:meth:`RadarMeasurement.to_cartesian`), velocity 0 with std
   ``init_vel_std`` per axis (turn rate 0 with std ``init_omega_std`` for CT).
6. **Confirm / delete** (the documented rule):
   - a tentative track is *confirmed* as soon as it has ``confirm_m`` hits within its
     first ``confirm_n`` scans (the initiating detection counts as a hit); it is deleted
     as soon as that has become impossible;
   - a confirmed track is *deleted* after ``delete_misses`` consecutive scans without a
     detection (it coasts meanwhile), or when its position std sqrt(tr P_pos) exceeds
     ``max_pos_std``.

Track IDs are assigned at initiation (increasing integers) and never reused.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from ..core.gaussian import Gaussian
from ..core.guard import Guarded, nis_gate
from ..core.linalg import bind_lapack, chol
from ..core.unscented import sigma_weights
from ..errors import InputError
from ..models.radar import RADAR_KERNELS, RadarMeasurement

Array = np.ndarray


@dataclass(frozen=True)
class TrackerConfig:
    """Tracker parameters (a scenario's ``[tracker]`` table, :meth:`from_tables`)."""

    gate_prob: float = 0.999
    confirm_m: int = 4
    confirm_n: int = 5
    delete_misses: int = 5
    init_vel_std: float = 100.0  # m/s per axis
    init_omega_std: float = 0.1  # rad/s (CT only)
    max_pos_std: float = 5000.0  # m
    association: str = "gnn"  # gnn | jpda
    pd: float = 0.9  # detection probability assumed by JPDA
    clutter_density: float = 1e-6  # false alarms per scan per unit measurement volume (JPDA)
    jpda_max_cluster: int = 8  # larger clusters: per-track PDA instead of enumeration

    def __post_init__(self) -> None:
        if self.association not in ("gnn", "jpda"):
            raise InputError(f"tracker.association must be gnn or jpda, not {self.association!r}")

    @staticmethod
    def from_tables(tracker: Any, radar: Any, clutter_volume: float | None = None
                    ) -> TrackerConfig:
        """From a typed scenario's ``[tracker]`` table; JPDA's ``pd`` and
        ``clutter_density`` (None there: not set) default to the ``[radar]`` table's ``pd``
        and ``clutter_rate / clutter_volume`` (the measurement-space volume clutter is
        drawn in)."""
        kw = {f.name: getattr(tracker, f.name) for f in fields(TrackerConfig)
              if hasattr(tracker, f.name)}
        if kw.get("pd") is None:
            kw["pd"] = float(radar.pd)
        if kw.get("clutter_density") is None:
            kw.pop("clutter_density", None)
            if clutter_volume:
                kw["clutter_density"] = max(float(radar.clutter_rate) / clutter_volume,
                                            1e-12)
        return TrackerConfig(**kw)


@dataclass
class Track:
    """One track. ``history`` rows: (scan k, predicted Gaussian, posterior Gaussian,
    detected: bool, confirmed: bool)."""

    id: int
    state: object
    born: int
    status: str = "tentative"  # tentative | confirmed | deleted
    hits: int = 1
    scans: int = 1
    misses: int = 0
    confirmed_at: int | None = None
    deleted_at: int | None = None
    history: list = field(default_factory=list)
    est: Gaussian | None = None
    pred: Gaussian | None = None


def predicted_measurement(g: Gaussian, meas: RadarMeasurement) -> tuple[Array, Array]:
    """(zhat, S) of a Gaussian through the radar by the unscented transform (the core's
    Van der Merwe points, alpha=1, beta=2, kappa=0), S including R."""
    _, Wm, Wc, U = sigma_weights(g.P.shape[0], 1.0, 2.0, 0.0, "merwe")
    X = g.x + U @ chol(g.P).T
    Z = meas.h(X)
    zhat = meas.mean(Z, Wm)
    E = meas.residual(Z, zhat)
    S = (E.T * Wc) @ E + meas.R
    return zhat, 0.5 * (S + S.T)


def predicted_measurements(gs: list[Gaussian], meas: RadarMeasurement
                           ) -> tuple[Array, Array]:
    """:func:`predicted_measurement` of every Gaussian of ``gs`` at once: (zhat (T, m),
    S (T, m, m)). One batched Cholesky of the covariances, one call of ``meas.h`` on all
    T (2n+1) sigma points; the azimuth mean is circular as in
    :meth:`RadarMeasurement.mean`. Measurement models without the radar's layout go
    through :func:`predicted_measurement` one Gaussian at a time."""
    if not isinstance(meas, RadarMeasurement):
        out = [predicted_measurement(g, meas) for g in gs]
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])
    x = np.stack([g.x for g in gs])
    P = np.stack([g.P for g in gs])
    T, n = x.shape
    _, Wm, Wc, U = sigma_weights(n, 1.0, 2.0, 0.0, "merwe")
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        L = np.stack([chol(Pi) for Pi in P])
    X = x[:, None, :] + U @ L.transpose(0, 2, 1)  # (T, 2n+1, n)
    Z = meas.h(X.reshape(-1, n)).reshape(T, U.shape[0], -1)
    zhat = np.einsum("j,tjm->tm", Wm, Z)
    az = meas._az
    zhat[:, az] = np.arctan2(np.sin(Z[:, :, az]) @ Wm, np.cos(Z[:, :, az]) @ Wm)
    E = meas.residual(Z, zhat[:, None, :])
    S = np.einsum("tjm,j,tjk->tmk", E, Wc, E) + meas.R
    return zhat, 0.5 * (S + S.transpose(0, 2, 1))


def jpda_betas(lik: Array, miss: Array, max_cluster: int = 8) -> Array:
    """JPDA association probabilities.

    Args:
      lik: (T, N) likelihood ratios Pd N(nu_ij; 0, S_i) / lambda, 0 outside the gate.
      miss: (T,) weight of "track i detected nothing", 1 - Pd Pg.
      max_cluster: clusters with more tracks use per-track PDA (no joint enumeration).

    Returns beta (T, N + 1): beta[i, j] = P(detection j is track i's), beta[i, N] =
    P(none is); rows sum to 1.
    """
    T, N = lik.shape
    beta = np.zeros((T, N + 1))
    gated = lik > 0
    # clusters: connected components of tracks linked through shared gated detections
    label = list(range(T))

    def root(i: int) -> int:
        while label[i] != i:
            label[i] = label[label[i]]
            i = label[i]
        return i

    for j in range(N):
        ts = np.flatnonzero(gated[:, j])
        for a in ts[1:]:
            label[root(int(a))] = root(int(ts[0]))
    clusters: dict[int, list[int]] = {}
    for i in range(T):
        clusters.setdefault(root(i), []).append(i)
    for tracks in clusters.values():
        if len(tracks) == 1 or len(tracks) > max_cluster:
            for i in tracks:
                row = np.append(lik[i], miss[i])
                beta[i] = row / row.sum()
            continue
        acc = _joint_events(tracks, gated, lik, miss)
        beta[tracks] = acc / acc.sum(axis=1, keepdims=True)
    return beta


def _joint_events(tracks: list[int], gated: Array, lik: Array, miss: Array) -> Array:
    """Sum of joint-event weights per (track of the cluster, detection or none): (T_c, N+1).
    Depth-first over the cluster's tracks; a detection is used by at most one track."""
    N = gated.shape[1]
    options = [np.flatnonzero(gated[i]) for i in tracks]
    acc = np.zeros((len(tracks), N + 1))
    pick = [N] * len(tracks)

    def enum(k: int, used: frozenset, w: float) -> None:
        if k == len(tracks):
            acc[np.arange(len(tracks)), pick] += w
            return
        i = tracks[k]
        pick[k] = N
        enum(k + 1, used, w * miss[i])
        for j in options[k]:
            if int(j) not in used:
                pick[k] = int(j)
                enum(k + 1, used | {int(j)}, w * lik[i, j])
        pick[k] = N

    enum(0, frozenset(), 1.0)
    return acc


def mix_states(f: Guarded, states: list, w: Array, space, rng) -> object:
    """Mixture of ``f``'s states with weights ``w`` (summing to 1), as one state of ``f``:
    the filter contract's ``mix`` (Gaussians moment-matched, equal-size ensembles pooled
    with weights w_h * w_hj and systematically redrawn to M). The guard checks the result
    and keeps the largest reset count of the hypotheses."""
    return f.mix(states, w, space, rng)


class Tracker:
    """Multi-target tracker around one filter, GNN or JPDA (see module docstring)."""

    def __init__(self, filt, motion, cfg: TrackerConfig, rng: np.random.Generator) -> None:
        self.filter = Guarded(filt, strikes=10**9)  # numerical failures only; no NIS resets
        self.motion = motion
        self.cfg = cfg
        self.rng = rng
        self.tracks: list[Track] = []
        self.all_tracks: list[Track] = []
        self._next_id = 1
        self.seconds = 0.0
        self.n_scans = 0
        # LAPACK and the gate's chi-square quantile bound, and one throwaway init, with its
        # own generator (the tracker's draws unchanged), now: scipy's imports and a
        # filter's compiled kernels (numba's import and cache, 0.5-1 s once per process)
        # would otherwise land in the first scans' times
        bind_lapack()
        nis_gate(2, 0.99)
        from scipy.optimize import linear_sum_assignment  # noqa: F401 - GNN's, imported now
        n = motion.space.dim
        self.filter.init(Gaussian(np.zeros(n), np.eye(n)), motion.space,
                         np.random.default_rng(0))
        if getattr(filt, "update_mode", None) == "local":  # it reads linearise_rows
            RADAR_KERNELS.get()

    # -- helpers --------------------------------------------------------------------------
    def _init_state(self, z: Array, meas: RadarMeasurement) -> Gaussian:
        d = meas.ndim
        n = self.motion.space.dim
        p, C = meas.to_cartesian(z)
        x = np.zeros(n)
        x[:d] = p
        P = np.zeros((n, n))
        P[:d, :d] = C
        P[d : 2 * d, d : 2 * d] = np.eye(d) * self.cfg.init_vel_std**2
        if n > 2 * d:
            P[2 * d :, 2 * d :] = np.eye(n - 2 * d) * self.cfg.init_omega_std**2
        return Gaussian(x, P)

    def _gate(self, tracks: list[Track], Z: Array, meas) -> tuple[Array, Array]:
        """(d2 (T, N), cost (T, N)) with inf outside the gate: one unscented transform of
        all tracks' predicted Gaussians, one batched Cholesky of their S and one batched
        solve for every (track, detection) residual (:func:`predicted_measurements`)."""
        g = nis_gate(meas.dim, self.cfg.gate_prob)
        zhat, S = predicted_measurements([tr.pred for tr in tracks], meas)
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:  # a track's S not numerically PD: jittered, per track
            L = np.stack([chol(Si) for Si in S])
        nu = meas.residual(Z[None, :, :], zhat[:, None, :])  # (T, N, m)
        u = np.linalg.solve(L, nu.transpose(0, 2, 1))  # (T, m, N): L^-1 nu
        d2 = np.einsum("tmj,tmj->tj", u, u)
        logdet = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        ok = d2 <= g
        cost = np.where(ok, d2 + logdet[:, None], np.inf)
        return np.where(ok, d2, np.inf), cost

    def _jpda(self, group: list[Track], cost: Array, free: Array, m: int):
        """{track id: [(detection index, beta), ..., (-1, beta_none)]} for tracks with at
        least one gated detection (hypotheses with beta < 1e-6 dropped)."""
        c = self.cfg
        # cost = d2 + ln det S, so N(nu; 0, S) = exp(-cost / 2) / (2 pi)^(m/2)
        ok = np.isfinite(cost)
        lik = np.where(ok, c.pd * np.exp(-0.5 * np.where(ok, cost, 0.0))
                       / (2 * np.pi) ** (m / 2) / c.clutter_density, 0.0)
        miss = np.full(len(group), 1.0 - c.pd * c.gate_prob)
        beta = jpda_betas(lik, miss, c.jpda_max_cluster)
        out = {}
        for i, tr in enumerate(group):
            keep = [(int(free[j]), float(beta[i, j])) for j in np.flatnonzero(ok[i])
                    if beta[i, j] > 1e-6]
            if keep:
                out[tr.id] = keep + [(-1, float(beta[i, -1]))]
        return out

    def _mix(self, state, hyps: list[tuple[int, float]], Z: Array, meas):
        """The PDA update: one filter update per hypothesis, mixed with weights beta."""
        f, rng = self.filter, self.rng
        states = [state if j < 0 else f.update(state, Z[j], meas, rng)[0] for j, _ in hyps]
        w = np.array([b for _, b in hyps])
        return mix_states(f, states, w / w.sum(), self.motion.space, rng)

    @staticmethod
    def _assign(cost: Array) -> list[tuple[int, int]]:
        if cost.size == 0 or not np.isfinite(cost).any():
            return []
        big = 1e12
        C = np.where(np.isfinite(cost), cost, big)
        from scipy.optimize import linear_sum_assignment  # lazily: start-up time

        r, c = linear_sum_assignment(C)
        return [(int(i), int(j)) for i, j in zip(r, c, strict=True) if C[i, j] < big]

    # -- one scan -------------------------------------------------------------------------
    def step(self, k: int, t: float, dt: float, Z: Array, meas: RadarMeasurement) -> None:
        """Process scan ``k`` at time ``t`` (s) with detections ``Z`` (N, m)."""
        t0 = time.perf_counter()
        f, rng = self.filter, self.rng
        # all tracks at once (the filter's batched predict when it has one)
        for tr, st in zip(self.tracks, f.predict_many([tr.state for tr in self.tracks],
                                                      self.motion, t, dt, None, rng),
                          strict=True):
            tr.state = st
            tr.pred = f.estimate(st)
        used = np.zeros(len(Z), bool)
        in_conf_gate = np.zeros(len(Z), bool)
        assigned: dict[int, int] = {}
        mixed: dict[int, list[tuple[int, float]]] = {}  # JPDA: track id -> [(j, beta)]
        for status in ("confirmed", "tentative"):
            group = [tr for tr in self.tracks if tr.status == status]
            if not group or len(Z) == 0:
                continue
            free = np.flatnonzero(~used)
            d2, cost = self._gate(group, Z[free], meas)
            if status == "confirmed":
                in_conf_gate[free] |= np.isfinite(d2).any(axis=0)
                if self.cfg.association == "jpda":
                    mixed = self._jpda(group, cost, free, meas.dim)
                    used |= in_conf_gate
                    continue
            for i, j in self._assign(cost):
                assigned[group[i].id] = int(free[j])
                used[free[j]] = True
        # the assigned tracks' updates at once (the filter's batched update when it has
        # one), in track order; with JPDA mixtures in the scan the updates stay interleaved
        # with the mixtures in track order, so an ensemble's random draws keep their order
        batched = not mixed and bool(assigned)
        if batched:
            upd = [tr for tr in self.tracks if tr.id in assigned]
            res = f.update_many([tr.state for tr in upd], Z[[assigned[tr.id] for tr in upd]],
                                meas, rng)
            for tr, (st, _) in zip(upd, res, strict=True):
                tr.state = st
        for tr in self.tracks:
            j = assigned.get(tr.id)
            hyps = mixed.get(tr.id)  # JPDA: a detection in the gate is a hit
            if hyps:
                tr.state = self._mix(tr.state, hyps, Z, meas)
            elif j is not None and not batched:
                tr.state, _ = f.update(tr.state, Z[j], meas, rng)
            hit = bool(hyps) or j is not None
            tr.est = f.estimate(tr.state)
            self._bookkeep(tr, k, hit)
            tr.history.append((k, tr.pred, tr.est, hit, tr.status == "confirmed"))
        self.tracks = [tr for tr in self.tracks if tr.status != "deleted"]
        for j in np.flatnonzero(~used & ~in_conf_gate):
            g = self._init_state(Z[j], meas)
            tr = Track(self._next_id, f.init(g, self.motion.space, rng), born=k)
            tr.pred = tr.est = g
            self._next_id += 1
            tr.history.append((k, g, g, True, False))
            self.tracks.append(tr)
            self.all_tracks.append(tr)
            if self.cfg.confirm_m <= 1:
                tr.status, tr.confirmed_at = "confirmed", k
        self.seconds += time.perf_counter() - t0
        self.n_scans += 1

    def _bookkeep(self, tr: Track, k: int, hit: bool) -> None:
        c = self.cfg
        pos_std = float(np.sqrt(np.trace(tr.est.P[: self.motion.ndim, : self.motion.ndim])))
        if tr.status == "tentative":
            tr.scans += 1
            tr.hits += int(hit)
            if tr.hits >= c.confirm_m and tr.scans <= c.confirm_n:
                tr.status, tr.confirmed_at = "confirmed", k
            elif tr.hits + (c.confirm_n - tr.scans) < c.confirm_m:
                tr.status, tr.deleted_at = "deleted", k
        elif tr.status == "confirmed":
            tr.misses = 0 if hit else tr.misses + 1
            if tr.misses >= c.delete_misses or pos_std > c.max_pos_std:
                tr.status, tr.deleted_at = "deleted", k

    def snapshot(self) -> tuple:
        """This moment of the tracker, for :meth:`restore` (a live lane's history applies
        a late detection at its time by restoring the tracker before its scan): the live
        tracks' fields (filter states are immutable; histories and the list of all tracks
        only grow, kept as their lengths), the id counter and the generator's state."""
        rows = [(tr, tr.state, tr.status, tr.hits, tr.scans, tr.misses, tr.confirmed_at,
                 tr.deleted_at, tr.est, tr.pred, len(tr.history)) for tr in self.tracks]
        return (rows, len(self.all_tracks), self._next_id, self.seconds, self.n_scans,
                self.rng.bit_generator.state)

    def restore(self, snap: tuple) -> None:
        rows, n_all, self._next_id, self.seconds, self.n_scans, st = snap
        for (tr, tr.state, tr.status, tr.hits, tr.scans, tr.misses, tr.confirmed_at,
             tr.deleted_at, tr.est, tr.pred, nh) in rows:
            del tr.history[nh:]
        self.tracks = [r[0] for r in rows]
        del self.all_tracks[n_all:]
        self.rng.bit_generator.state = st

    def confirmed(self) -> dict[int, Gaussian]:
        """{track id: posterior Gaussian} of the currently confirmed tracks."""
        return {tr.id: tr.est for tr in self.tracks if tr.status == "confirmed"}
