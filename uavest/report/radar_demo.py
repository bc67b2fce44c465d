"""A radar tracking run recorded through the sink interface, without the engine: the
reference for the engine hook (a radar source hands each scan to ``Sink.sample`` as a
:class:`~uavest.engine.records.RadarScanSample`, with the truths when the
scenario has them, then every tracker's :class:`~uavest.engine.records.ScanRecord` to
``Sink.record``). Used by the tests, ``benchmarks/recording_channels.py`` and the docs."""

from __future__ import annotations

import time

import numpy as np

from ..engine.records import RadarScanSample, RunInfo, ScanRecord, TrackEstimate, package_versions

__all__ = ["run_radar_demo"]


def run_radar_demo(sinks: list, scenario: str = "radar_uav", steps: int = 40,
                   filters: tuple[str, ...] = ("ekf", "ukf"), seed: int = 0) -> dict:
    """Run ``filters``' trackers side by side on one seeded run of ``scenario`` (``steps``
    scans) and hand everything to ``sinks`` (opened and closed here). Returns
    ``{"run": RunData, "records": {label: [ScanRecord]}, "info": RunInfo}``."""
    from dataclasses import replace

    from ..experiments.radar import data_rng, filter_models, filter_rng, make_radar_filter
    from ..scenarios import load_typed, resolved
    from ..tracking.scenario import clutter_box, generate_run
    from ..tracking.tracker import Tracker, TrackerConfig

    sc = replace(load_typed(scenario), steps=steps)
    run = generate_run(sc, data_rng(seed, 0), steps)
    motion, radar = filter_models(sc)
    dt = float(sc.dt)
    lo, hi = clutter_box(sc.radar, radar)
    cfg = TrackerConfig.from_tables(sc.tracker, sc.radar, clutter_volume=float(np.prod(hi - lo)))
    trackers = {lab: Tracker(make_radar_filter(lab), motion, cfg, filter_rng(seed, 0, lab))
                for lab in filters}
    info = RunInfo(f"radar demo {scenario}", f"scenario:{scenario}", seed,
                   filters={lab: {"spec": lab, "tracker": cfg.__dict__} for lab in filters},
                   config={"scenario": scenario, "steps": steps, "dt": dt,
                           "gospa_c": float(sc.metrics.gospa_c)},
                   versions=package_versions(), scenario=resolved(sc))
    records: dict[str, list] = {lab: [] for lab in filters}
    for s in sinks:
        s.open(info)
    try:
        for lab in filters:
            for s in sinks:
                s.start(lab, 0.0, np.zeros(0), np.zeros((0, 0)))
        for k in range(1, steps + 1):
            t = k * dt
            model = radar.with_pose(run.poses_est[k - 1])
            Z = run.scans[k - 1]
            X = np.where(run.alive[:, k, None], run.truths[:, k], np.nan)
            smp = RadarScanSample(t, k, Z, model, run.origins[k - 1], X)
            for s in sinks:
                s.sample(smp)
            for lab, tr in trackers.items():
                before = {x.id for x in tr.tracks}
                c0 = time.perf_counter()
                tr.step(k, t, dt, Z, model)
                wall = time.perf_counter() - c0
                tracks = tuple(
                    TrackEstimate(x.id, x.est.x, x.est.P, x.status == "confirmed",
                                  bool(x.history and x.history[-1][0] == k
                                       and x.history[-1][3]),
                                  None if x.pred is None else x.pred.x)
                    for x in tr.tracks)
                rec = ScanRecord(lab, k, t, tracks,
                                 tuple(sorted(before - {x.id for x in tr.tracks})), 0, wall)
                records[lab].append(rec)
                for s in sinks:
                    s.record(rec)
    finally:
        for s in sinks:
            s.close()
    return {"run": run, "records": records, "info": info}
