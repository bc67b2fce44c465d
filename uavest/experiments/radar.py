"""Radar scenarios under ``uavest bench``: Monte Carlo runs, metrics per filter.

Two modes (scenario key ``mode``):

``filter``
    The standard bound-comparison set-up: one target, known association (its detection
    each scan, none when missed), truth started at the prior mean ``m0``, each run's filter
    started from a draw x0 ~ N(m0, P0) (the same draw for every filter), PCRLB from
    J0 = P0^-1 by the Tichavsky recursion with Monte Carlo expectations over the runs'
    truths (:mod:`uavest.eval.pcrlb`). The bound assumes the truth follows the filters'
    model, so settings that break that (``truth_q != q``, target turns, ``model = "ct"``,
    a target start off the prior mean) raise ScenarioError; a moving (UAV) radar is bounded
    with each scan's true sensor pose.
``tracker``
    The full tracker (:mod:`uavest.tracking.tracker`) per filter on the same detections;
    errors are taken over the per-scan GOSPA assignment of confirmed tracks to truths.

Seeding (:mod:`uavest.seeding`): run r draws its truths, detections and x0 from
``rng(seed, r, "truth")`` (shared by all filters) and each filter's own randomness from
``rng(seed, r, "filter:<label>")``, so a filter's numbers do not depend on which other
filters run, and run r does not depend on the number of runs.

Averaging (see :mod:`uavest.eval.tracking`): ``pos_rmse``/``vel_rmse`` and
``pcrlb_pos``/``pcrlb_vel`` are per-scan RMSE over runs (resp. per-scan bound) averaged
over the scans; ``rmse_mean``/``rmse_median`` the mean/median over runs of each run's
position RMSE over its scans; ``nees_mean`` the scan-average of the per-scan averaged NEES.
``nees_band`` is the 95% band of *one scan's* average (chi2.ppf(., N n) / N with N the
samples averaged per scan: the runs in filter mode; in tracker mode every assigned
(run, truth) pair, N = their mean count per scan, ``nees_samples_per_scan``), not of the
additional average over scans; ``nees_in_band_fraction`` is the fraction of scans whose
averaged NEES lies in its scan's band (tracker mode: the band for that scan's count);
``us_per_step`` the wall time of one predict+update (filter mode)
or of one whole tracker scan (tracker mode), in microseconds.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from ..core.gaussian import Gaussian
from ..core.guard import Guarded
from ..core.spec import FilterSpec
from ..engine import FilterRunner, Start, Step, TrackerRunner
from ..engine import run as run_engine
from ..engine.build import build_filters
from ..eval.pcrlb import conditional_bounds, pcrlb, position_bound, velocity_bound
from ..eval.tracking import nees, nees_band, track_quality
from ..presets import build, resolve_list, spec_labels
from ..scenarios import ScenarioError, typed
from ..seeding import filter_stream, rng
from ..sinks.base import Collector
from ..tracking.scenario import (
    clutter_box,
    generate_run,
    initial_prior,
    motion_model,
    radar_model,
    state_dim,
)
from ..tracking.tracker import Tracker, TrackerConfig

Array = np.ndarray


def make_radar_filter(spec: str | FilterSpec, dim: int | None = None):
    """A core filter from its spec with the ``radar`` preset (see ``uavest list``)."""
    return build(spec, "radar", dim)


def data_rng(seed: int, run: int) -> np.random.Generator:
    """Trial ``run``'s truths, detections and filter start (shared by every filter)."""
    return rng(seed, run, "truth")


def filter_rng(seed: int, run: int, label: str) -> np.random.Generator:
    return rng(seed, run, filter_stream(label))


def filter_models(sc: Any):
    """(motion model, radar model) of the filters, from the typed scenario's tables."""
    motion = motion_model(sc.motion, sc.ndim)
    return motion, radar_model(sc.radar, sc.ndim, motion.space.dim)


def _prior(sc: Any) -> tuple[Array, Array]:
    """Filter-mode (m0, P0) from the typed scenario's ``[prior]`` table."""
    return initial_prior(sc.prior, state_dim(sc.ndim, sc.motion))


def _scan_models(radar, run):
    return [radar.with_pose(p) for p in run.poses_est]


# ------------------------------------------------------------------------------ filter mode


def filter_steps(motion, radar, run, P0: Array, dt: float) -> Iterator[Start | Step]:
    """Engine items of one filter-mode run: start at N(run.x0, P0), then per scan a
    predict over dt and the target's own detection (none when it was missed)."""
    yield Start(0.0, Gaussian(run.x0, P0), motion.space)
    for k, model in enumerate(_scan_models(radar, run), start=1):
        Z, o = run.scans[k - 1], run.origins[k - 1]
        z = Z[o == 0]
        yield Step(k, k * dt, dt, motion, ((z[0], model),) if len(z) else ())


def run_filter(filt, motion, radar, run, P0: Array, dt: float, rng) -> dict:
    """One filter on one run in filter mode, started from N(run.x0, P0). Returns per-scan
    arrays ``pred`` (K, n), ``post`` (K, n), ``P`` (K, n, n), and ``seconds``,
    ``resets`` (numerical-failure recoveries of the guard)."""
    fr = FilterRunner("f", filt, rng, guard=Guarded(filt, strikes=10**9),
                      record_prediction=True)  # numerical failures only; no NIS resets
    coll = Collector()
    run_engine(filter_steps(motion, radar, run, P0, dt), [fr], [coll])
    a = coll.arrays("f")
    return {"pred": a["x_pred"], "post": a["x"], "P": a["P"], "seconds": fr.seconds,
            "resets": fr.resets}


def check_filter_mode(sc: Any) -> None:
    """Raise ScenarioError for filter-mode settings (of the typed scenario ``sc``) under
    which the PCRLB would silently be the bound of another problem: the bound assumes the
    truth follows the filters' own model (NCV with the filters' ``q``) from
    x0 ~ N(m0, P0)."""
    m = sc.motion
    q = float(m.q)
    tgt = sc.targets[0] if sc.targets else None
    truth_q = float(tgt.q if tgt is not None and tgt.q is not None else m.truth_noise)
    bad = []
    if m.model != "ncv":
        bad.append(f"motion.model = {m.model!r} (the truth is NCV with omega = 0, "
                   "not a coordinated turn with a random turn rate)")
    if truth_q != q:
        bad.append(f"truth process noise {truth_q} != the filters' motion.q {q}")
    if tgt is not None and tgt.turns:
        bad.append("a scripted turn in the target (the filters' NCV model has none)")
    if tgt is not None and tgt.start:
        m0, _ = _prior(sc)
        if not np.allclose(np.asarray(tgt.start, float), m0[: len(tgt.start)]):
            bad.append("a target start other than the prior mean")
    if bad:
        raise ScenarioError(
            f"scenario {sc.name!r}: mode = \"filter\" computes the PCRLB for a truth "
            "that follows the filters' model; unsupported here: " + "; ".join(bad)
            + ' (use mode = "tracker", or drop these settings)'
        )


def _bound_measurement(radar, rundata):
    """The radar model the truths were measured with: fixed, or per scan the true pose of
    a moving (UAV) sensor (the same in every run)."""
    poses = rundata[0].poses_true
    if all(p is radar.pose for p in poses):
        return radar
    for rd in rundata[1:]:
        for a, b in zip(poses, rd.poses_true, strict=True):
            if not (np.array_equal(a.position, b.position) and np.array_equal(a.R_ws, b.R_ws)):
                raise ScenarioError("filter mode: the true sensor poses differ between runs; "
                                    "the PCRLB needs one pose per scan")
    models = [radar.with_pose(p) for p in poses]
    return lambda k: models[k - 1]


def bench_filter_mode(sc: Any, filters: Sequence[str | FilterSpec], runs: int, seed: int,
                      steps: int | None):
    """Filter-mode table of the typed scenario ``sc`` over runs 0..runs-1 (module doc)."""
    check_filter_mode(sc)
    motion, radar = filter_models(sc)
    ndim = radar.ndim
    dt = float(sc.dt)
    m0, P0 = initial_prior(sc.prior, motion.space.dim)
    div = float(sc.divergence_rmse)
    rundata = []
    for r in range(runs):
        rundata.append(generate_run(sc, data_rng(seed, r), steps))
    K = len(rundata[0].scans)
    n = motion.space.dim
    truths = np.stack([rd.truths[0] for rd in rundata])  # (runs, K+1, 2 ndim)
    detected = np.stack([[np.any(o == 0) for o in rd.origins] for rd in rundata]).astype(float)
    meas = _bound_measurement(radar, rundata)
    bound = pcrlb(np.linalg.inv(P0), truths, motion, meas, dt, detected=detected)
    bpos, bvel = position_bound(bound, ndim), velocity_bound(bound, ndim)
    cond = conditional_bounds(np.linalg.inv(P0), truths, motion, meas, dt, detected=detected)
    bcond = np.sqrt(np.einsum("rkii->k", cond[:, :, :ndim, :ndim]) / runs)  # RMS over runs
    out = {}
    for spec in filters:
        label = spec.label if isinstance(spec, FilterSpec) else spec
        filt = make_radar_filter(spec, motion.space.dim)
        E_pre = np.empty((runs, K, ndim))
        E = np.empty((runs, K, 2 * ndim))
        NE = np.empty((runs, K))
        sec, diverged = 0.0, 0
        for r, rd in enumerate(rundata):
            res = run_filter(filt, motion, radar, rd, P0, dt, filter_rng(seed, r, label))
            tx = truths[r, 1:]
            E_pre[r] = res["pred"][:, :ndim] - tx[:, :ndim]
            e = res["post"] - tx
            E[r] = e[:, : 2 * ndim]
            NE[r] = nees(e, res["P"])
            sec += res["seconds"]
            run_rmse = np.sqrt(np.mean(np.sum(E[r, :, :ndim] ** 2, axis=1)))
            if res["resets"] > 0 or not np.isfinite(run_rmse) or run_rmse > div:
                diverged += 1
        pos_k = np.sqrt(np.mean(np.sum(E[:, :, :ndim] ** 2, axis=2), axis=0))
        vel_k = np.sqrt(np.mean(np.sum(E[:, :, ndim:] ** 2, axis=2), axis=0))
        per_run = np.sqrt(np.mean(np.sum(E[:, :, :ndim] ** 2, axis=2), axis=1))
        pos_rmse, vel_rmse = float(pos_k.mean()), float(vel_k.mean())
        rms_ratio = float(np.sqrt(np.mean(pos_k**2) / np.mean(bpos**2)))
        band = nees_band(n, runs)  # per scan: the run average of one scan's NEES
        nees_k = NE.mean(axis=0)
        out[label] = {
            "rmse_mean": float(per_run.mean()),
            "rmse_median": float(np.median(per_run)),
            "approx_error": float(np.linalg.norm(E_pre, axis=2).mean()),
            "est_error": float(np.linalg.norm(E[:, :, :ndim], axis=2).mean()),
            "nees_mean": float(nees_k.mean()),
            "nees_band": list(band),
            "nees_in_band_fraction": float(np.mean((nees_k >= band[0]) & (nees_k <= band[1]))),
            "diverged_fraction": diverged / runs,
            "us_per_step": 1e6 * sec / (runs * K),
            "pos_rmse": pos_rmse,
            "vel_rmse": vel_rmse,
            "pcrlb_pos": float(bpos.mean()),
            "pcrlb_vel": float(bvel.mean()),
            "pcrlb_ratio": pos_rmse / float(bpos.mean()),
            "pcrlb_vel_ratio": vel_rmse / float(bvel.mean()),
            "pcrlb_ratio_rms": rms_ratio,
            "cond_bound_pos": float(bcond.mean()),
            "cond_ratio": pos_rmse / float(bcond.mean()),
            "gospa": None,
            "id_swaps": None,
            "false_tracks": None,
            "track_breaks": None,
        }
    return out


# ----------------------------------------------------------------------------- tracker mode


def scan_steps(run, radar, motion, dt: float) -> Iterator[Start | Step]:
    """Engine items of one tracker-mode run: a start, then every scan's detections (with
    the scan and the truths as a sample for recorders)."""
    from ..engine.records import RadarScanSample

    yield Start(0.0, None, motion.space)
    for k, model in enumerate(_scan_models(radar, run), start=1):
        Z = run.scans[k - 1]
        X = np.where(run.alive[:, k, None], run.truths[:, k], np.nan)
        smp = RadarScanSample(k * dt, k, Z, model, run.origins[k - 1], X)
        yield Step(k, k * dt, dt, motion, ((Z, model),), info={"samples": (smp,)})


def run_trackers(sc: Any, filters: list[str], run, seed: int, r: int, sinks=(),
                 info=None) -> dict[str, Tracker]:
    """All filters' trackers on the same run (same detections) of the scenario ``sc``
    (typed, or its dict), one tracker per filter, side by side through the engine
    (records and scans to ``sinks``)."""
    sc = typed(sc)
    motion, radar = filter_models(sc)
    dt = float(sc.dt)
    lo, hi = clutter_box(sc.radar, radar)
    cfg = TrackerConfig.from_tables(sc.tracker, sc.radar, clutter_volume=float(np.prod(hi - lo)))
    runners = [
        TrackerRunner(label, lambda f=f, label=label: Tracker(f, motion, cfg,
                                                              filter_rng(seed, r, label)))
        for label, f in ((sp.label, f) for sp, f in build_filters(
            resolve_list(filters, "radar", dim=motion.space.dim)))
    ]
    run_engine(scan_steps(run, radar, motion, dt), runners, sinks, info)
    return {tr.label: tr.tracker for tr in runners}


def tracker_errors(tracker: Tracker, run, ndim: int, c: float, dt: float):
    """Per-scan truth/track dictionaries, quality report and matched errors.

    Returns (quality, list of (k, e_pred_pos, e_post (2 ndim), nees))."""
    K = len(run.scans)
    posts: list[dict] = [dict() for _ in range(K)]
    preds: list[dict] = [dict() for _ in range(K)]
    for trk in tracker.all_tracks:
        for k, gp, ge, _, conf in trk.history:
            if conf:
                posts[k - 1][trk.id] = ge
                preds[k - 1][trk.id] = gp
    truth_steps = [
        {i: run.truths[i, k, :ndim] for i in np.flatnonzero(run.alive[:, k])}
        for k in range(1, K + 1)
    ]
    track_steps = [{j: g.x[:ndim] for j, g in p.items()} for p in posts]
    q = track_quality(truth_steps, track_steps, c=c, dt=dt)
    errs = []
    for tid, lst in q.assigned.items():
        for k0, j in lst:
            g, gp = posts[k0][j], preds[k0][j]
            tx = run.truths[tid, k0 + 1]
            e = g.x[: 2 * ndim] - tx
            ne = float(nees(e, g.P[: 2 * ndim, : 2 * ndim]))
            errs.append((k0, gp.x[:ndim] - tx[:ndim], e, ne))
    return q, errs


def bench_tracker_mode(sc: Any, filters: Sequence[str | FilterSpec], runs: int, seed: int,
                       steps: int | None, record: tuple | None = None):
    """Tracker-mode table of the typed scenario ``sc`` over runs 0..runs-1;
    ``record = (r, sinks, info)`` hands run r's engine run (scans, truths, every tracker's
    records) to ``sinks``."""
    acc, K = _run_tracker_trials(sc, filters, runs, seed, steps, record)
    return {lab: _tracker_row(a, sc.ndim, K) for lab, a in acc.items()}


def _run_tracker_trials(sc: Any, filters: Sequence[str | FilterSpec], runs: int, seed: int,
                        steps: int | None, record: tuple | None
                        ) -> tuple[dict[str, dict], int | None]:
    """Run every tracker on trials 0..runs-1 and gather per label the trials' quality
    (``q``), the assigned-pair errors tagged with their run (``e``: (r, k, approximation
    error, estimate error, NEES)), the compute time (``sec``, s), the scans run and each
    run's position RMSE (m, ``runrmse``); also the scans per run (None without runs)."""
    ndim = sc.ndim
    dt = float(sc.dt)
    c = float(sc.metrics.gospa_c)
    labels = spec_labels(filters)
    acc = {lab: {"q": [], "e": [], "sec": 0.0, "scans": 0, "runrmse": []} for lab in labels}
    K = None
    for r in range(runs):
        rd = generate_run(sc, data_rng(seed, r), steps)
        K = len(rd.scans)
        if record is not None and r == record[0]:
            trackers = run_trackers(sc, filters, rd, seed, r, record[1], record[2])
        else:
            trackers = run_trackers(sc, filters, rd, seed, r)
        for lab, tr in trackers.items():
            q, errs = tracker_errors(tr, rd, ndim, c, dt)
            a = acc[lab]
            a["q"].append(q)
            a["e"].extend((r, *e) for e in errs)
            a["sec"] += tr.seconds
            a["scans"] += tr.n_scans
            if errs:
                a["runrmse"].append(
                    float(np.sqrt(np.mean([np.sum(e[2][:ndim] ** 2) for e in errs])))
                )
    return acc, K


def _assigned_error_stats(e: list[tuple], ndim: int) -> dict[str, Any]:
    """Per-scan error statistics over every assigned (run, truth) pair ``e`` (as gathered
    by :func:`_run_tracker_trials`), averaged over the scans: position and velocity RMSE
    (m, m/s), NEES with its 95% band and the fraction of scans inside it, the samples per
    scan, and the mean approximation and estimate error norms (m). NaN without pairs."""
    if not e:
        nan = float("nan")
        return {"pos_rmse": nan, "vel_rmse": nan, "nees_mean": nan, "approx_error": nan,
                "est_error": nan, "nees_in_band_fraction": nan,
                "nees_samples_per_scan": nan, "nees_band": (nan, nan)}
    ks = np.array([x[1] for x in e])
    pe = np.array([np.sum(x[3][:ndim] ** 2) for x in e])
    ve = np.array([np.sum(x[3][ndim:] ** 2) for x in e])
    ne = np.array([x[4] for x in e])
    uk = np.unique(ks)
    pos_k = np.array([np.sqrt(pe[ks == k].mean()) for k in uk])
    vel_k = np.array([np.sqrt(ve[ks == k].mean()) for k in uk])
    nees_k = np.array([ne[ks == k].mean() for k in uk])
    # a scan's NEES averages every assigned (run, truth) pair at that scan, so the
    # band is for that many samples (~ runs x targets), not for `runs`
    cnt_k = np.array([np.count_nonzero(ks == k) for k in uk])
    band = nees_band(2 * ndim, float(cnt_k.mean()))
    bands = np.array([nees_band(2 * ndim, int(c)) for c in cnt_k])
    return {
        "pos_rmse": float(pos_k.mean()), "vel_rmse": float(vel_k.mean()),
        "nees_mean": float(nees_k.mean()),
        "approx_error": float(np.mean([np.linalg.norm(x[2]) for x in e])),
        "est_error": float(np.mean([np.linalg.norm(x[3][:ndim]) for x in e])),
        "nees_in_band_fraction": float(np.mean((nees_k >= bands[:, 0])
                                               & (nees_k <= bands[:, 1]))),
        "nees_samples_per_scan": float(cnt_k.mean()),
        "nees_band": band,
    }


def _tracker_row(a: dict, ndim: int, K: int | None) -> dict[str, Any]:
    """One tracker's row of the tracker-mode table from its gathered trials ``a``."""
    qs = a["q"]
    st = _assigned_error_stats(a["e"], ndim)
    rr = np.array(a["runrmse"]) if a["runrmse"] else np.array([np.nan])
    ttc = [q.time_to_confirm for q in qs if q.time_to_confirm is not None]
    return {
        "rmse_mean": float(rr.mean()),
        "rmse_median": float(np.median(rr)),
        "approx_error": st["approx_error"],
        "est_error": st["est_error"],
        "nees_mean": st["nees_mean"],
        "nees_band": list(st["nees_band"]),
        "nees_in_band_fraction": st["nees_in_band_fraction"],
        "nees_samples_per_scan": st["nees_samples_per_scan"],
        "diverged_fraction": float(np.mean([q.track_breaks > 0 for q in qs])),
        "us_per_step": 1e6 * a["sec"] / max(a["scans"], 1),
        "pos_rmse": st["pos_rmse"],
        "vel_rmse": st["vel_rmse"],
        "pcrlb_pos": None,
        "pcrlb_ratio": None,
        "pcrlb_ratio_rms": None,
        "cond_ratio": None,
        "gospa": float(np.mean([q.gospa for q in qs])),
        "id_swaps": float(np.mean([q.id_swaps for q in qs])),
        "false_tracks": float(np.mean([q.false_tracks for q in qs])),
        "track_breaks": float(np.mean([q.track_breaks for q in qs])),
        "tracks_confirmed_total": float(np.mean([q.confirmed_tracks for q in qs])),
        "time_to_confirm": float(np.mean(ttc)) if ttc else None,
        "scans": K,
    }


def trial_info(sc: Any, filters: list[str], seed: int, r: int, command: str = ""):
    """The run description of radar trial ``r`` of the scenario ``sc`` (typed, or its
    dict) for a recording (scenario, seed, trial, resolved filters, dt, GOSPA c)."""
    from ..engine.records import RunInfo, package_versions
    from ..scenarios import resolved

    sc = typed(sc)
    built = build_filters(resolve_list(filters, "radar", dim=state_dim(sc.ndim, sc.motion)))
    return RunInfo(command, f"scenario:{sc.name}", seed,
                   filters={sp.label: sp.as_dict() for sp, _ in built},
                   config={"scenario": sc.name, "trial": r, "mode": sc.mode,
                           "dt": float(sc.dt), "gospa_c": float(sc.metrics.gospa_c)},
                   versions=package_versions(), scenario=resolved(sc))


def run_bench(
    scenario: Any, filters: list[str], runs: int, seed: int, steps: int | None,
    record: tuple | None = None,
) -> dict[str, dict[str, float]]:
    """Entry point for ``uavest bench`` on ``kind = "radar"`` scenarios (see module doc).

    ``filters`` empty/None -> the scenario's ``filters`` list; ``runs`` None/0 -> the
    scenario's ``runs``. ``record = (r, sinks, info)``: trial r's tracker run goes to
    ``sinks`` (tracker mode: the very run the table uses; filter mode, which runs no
    tracker: the trackers on trial r's data, as ``uavest track`` does)."""
    sc = typed(scenario)
    # once for all runs; the command line refused two names of one filter already (a
    # library caller may list them: each label its own random stream)
    filters = resolve_list(list(filters or sc.filters), "radar",
                           dim=state_dim(sc.ndim, sc.motion), distinct=False)
    runs = int(runs or sc.runs)
    if sc.mode == "filter":
        out = bench_filter_mode(sc, filters, runs, seed, steps)
        if record is not None:
            r, sinks, info = record
            run_trackers(sc, filters, generate_run(sc, data_rng(seed, r), steps),
                         seed, r, sinks, info)
        return out
    return bench_tracker_mode(sc, filters, runs, seed, steps, record)
