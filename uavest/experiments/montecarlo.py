"""Monte Carlo trials of the benchmark systems, through the streaming engine.

A trial is a pure function (:func:`run_trial`): from (system, filter specs, seed, trial
index) it draws the truth and measurements from ``rng(seed, r, "truth")`` and runs every
filter (each with ``rng(seed, r, "filter:<label>")``, see :mod:`uavest.seeding`) through
:func:`uavest.engine.run`, giving one row of per-trial metrics per filter. Trial r is the
same whatever the number of trials, so trials can be split over processes or machines
and :func:`aggregate` combines any set of trial rows into the table.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence

import numpy as np

from ..engine import FilterRunner, Start, Step, run
from ..engine.build import build_filters
from ..engine.records import RunInfo, package_versions
from ..eval.metrics import mean_abs, nees, nees_band, rmse
from ..presets import resolve_list
from ..seeding import filter_stream, rng
from ..sinks.base import Collector
from .systems import System, simulate

Array = np.ndarray

METRICS = (
    "rmse_mean", "rmse_median", "approx_error", "est_error", "nees_mean", "diverged_fraction",
    "us_per_step",
)


def trial_data(sysm: System, seed: int, r: int) -> tuple[Array, Array]:
    """Truth (T, n) and measurements (T, m) of trial ``r``."""
    X, Z = simulate(sysm, 1, rng(seed, r, "truth"))
    return X[0], Z[0]


def trial_steps(sysm: System, Z: Array, X: Array | None = None) -> Iterator[Start | Step]:
    """The engine's items for one trial: start at the filter prior, then one step per
    measurement (predict over dt, update with z_k). With the truth ``X`` (T, n) every step
    also carries a :class:`~uavest.engine.records.StateSample` (truth x_k and
    z_k) in ``info["samples"]`` for recorders (filters never see ``info``)."""
    tr, me = sysm.transition, sysm.measurement
    yield Start(0.0, sysm.filter_prior, tr.space)
    if X is None:
        for k in range(Z.shape[0]):
            yield Step(k + 1, (k + 1) * sysm.dt, sysm.dt, tr, ((Z[k], me),))
        return
    from ..engine.records import StateSample

    for k in range(Z.shape[0]):
        t = (k + 1) * sysm.dt
        yield Step(k + 1, t, sysm.dt, tr, ((Z[k], me),),
                   info={"samples": (StateSample(t, k + 1, X[k], Z[k]),)})


def trial_info(sysm: System, specs: list[str], seed: int, r: int, scenario: str = "",
               command: str = "") -> RunInfo:
    """The run description of trial ``r`` for a recording: scenario, seed, trial, the
    resolved filters (label -> resolved spec), the system's steps and dt."""
    built = build_filters(resolve_list(specs, "bench", dim=sysm.transition.space.dim))
    return RunInfo(command, f"scenario:{scenario}" if scenario else "bench", seed,
                   filters={sp.label: sp.as_dict() for sp, _ in built},
                   config={"scenario": scenario, "trial": r, "steps": sysm.steps,
                           "dt": sysm.dt, "state_dim": sysm.transition.space.dim},
                   versions=package_versions())


def run_trial(sysm: System, specs: list[str], seed: int, r: int, sinks: Sequence = (),
              info: RunInfo | None = None) -> dict[str, dict]:
    """Per-filter metrics of trial ``r``: rmse, approx_error (mean |x_pred - x|),
    est_error (mean |x_est - x|), nees (mean over steps), resets, diverged, seconds.
    ``sinks`` (e.g. an MCAP recorder) see the same engine run (records, and the truth and
    measurement of every step as :class:`~uavest.engine.records.StateSample`);
    the numbers do not depend on them."""
    X, Z = trial_data(sysm, seed, r)
    n = sysm.transition.space.dim
    built = build_filters(resolve_list(specs, "bench", dim=n))
    runners = [FilterRunner(sp.label, f, rng(seed, r, filter_stream(sp.label)),
                            record_prediction=True) for sp, f in built]
    coll = Collector()
    run(trial_steps(sysm, Z, X if sinks else None), runners, [coll, *sinks], info)
    out = {}
    for fr in runners:
        a = coll.arrays(fr.label)
        e = X - a["x"]
        rm = rmse(e)
        out[fr.label] = {
            "rmse": rm,
            "approx_error": mean_abs(X - a["x_pred"]),
            "est_error": mean_abs(e),
            "nees": float(np.mean(nees(e, a["P"]))),
            "resets": fr.resets,
            "diverged": bool(rm > sysm.divergence_rmse or fr.resets > 0),
            "seconds": fr.seconds,
            "steps": int(Z.shape[0]),
        }
    return out


def trial_rows(sysm: System, specs: list[str], seed: int, trials: Iterable[int],
               progress: Callable[[int], None] | None = None,
               record: tuple[int, Sequence, RunInfo | None] | None = None
               ) -> list[dict[str, dict]]:
    """:func:`run_trial` for each trial index (a shard of a study); ``record = (r, sinks,
    info)`` hands trial r's run to ``sinks``."""
    rows = []
    for r in trials:
        if record is not None and r == record[0]:
            rows.append(run_trial(sysm, specs, seed, r, record[1], record[2]))
        else:
            rows.append(run_trial(sysm, specs, seed, r))
        if progress:
            progress(1)
    return rows


def aggregate(rows: list[dict[str, dict]], n: int) -> dict[str, dict]:
    """The table over trial rows (any split of the trials gives the same table)."""
    out = {}
    labels = list(rows[0]) if rows else []
    R = len(rows)
    for lab in labels:
        c = [row[lab] for row in rows]
        rm = [x["rmse"] for x in c]
        ne = [x["nees"] for x in c]
        lo, hi = nees_band(n, R)
        out[lab] = {
            "rmse_mean": float(np.mean(rm)),
            "rmse_median": float(np.median(rm)),
            "approx_error": float(np.mean([x["approx_error"] for x in c])),
            "est_error": float(np.mean([x["est_error"] for x in c])),
            "nees_mean": float(np.mean(ne)),
            "nees_median": float(np.median(ne)),
            "nees_band": [lo, hi],
            "diverged_fraction": sum(x["diverged"] for x in c) / R,
            "resets": int(sum(x["resets"] for x in c)),
            "us_per_step": 1e6 * sum(x["seconds"] for x in c) / sum(x["steps"] for x in c),
        }
    return out


def evaluate(sysm: System, specs: list[str], runs: int, seed: int,
             progress: Callable[[int], None] | None = None,
             record: tuple[int, Sequence, RunInfo | None] | None = None) -> dict[str, dict]:
    """Per-filter metrics (see ``METRICS``) over trials 0..runs-1; ``record = (r, sinks,
    info)``: trial r's engine run also goes to ``sinks`` (``uavest bench --mcap``)."""
    rows = trial_rows(sysm, specs, seed, range(runs), progress, record)
    return aggregate(rows, sysm.transition.space.dim)


ABLATION_CELLS = (
    ("random", "equal"), ("expanded", "equal"), ("random", "confidence"), ("expanded", "confidence")
)


def ablation(sysm: System, runs: int, seed: int, progress=None) -> dict[str, dict]:
    """The hybrid paper's 2x2 (sampling x weights; Cui, Sun and Wen, Sensors 2022) for
    the literal and the consistent hybrid."""
    out = {}
    for family in ("hybrid_literal", "hybrid"):
        specs = [f"{family}(sampling={s}, weights={w})" for s, w in ABLATION_CELLS]
        res = evaluate(sysm, specs, runs, seed, progress)
        out[family] = {
            f"{s}+{w}": res[spec] for (s, w), spec in zip(ABLATION_CELLS, specs, strict=True)
        }
    return out
