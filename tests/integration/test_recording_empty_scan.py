"""Issue 18: an empty radar scan (no detections, no targets in range) and a tracker
update with no tracks are recorded as empty messages / scenes, not a crash. The scans go
through McapSink's sample/record queue exactly as the engine hands them on (``uavest run
--mcap`` on a live link: a scan with no detections is ``Z`` of shape (0, 3) and no truths
(0, 6)); the file is read back with the independent ``mcap`` reader."""

import json

import numpy as np
from mcap.reader import make_reader

from uavest.engine.records import (
    RadarScanSample,
    RunInfo,
    ScanRecord,
    TrackEstimate,
    package_versions,
)
from uavest.experiments.radar import data_rng
from uavest.scenarios import load_typed
from uavest.sinks.mcap import McapSink
from uavest.tracking.scenario import build_models, generate_run


def test_empty_scans_and_empty_track_updates_are_recorded(tmp_path):
    sc = load_typed("radar_uav")
    run = generate_run(sc, data_rng(0, 0), 3)
    _, radar = build_models(sc)
    Z1 = np.asarray(run.scans[0], float)
    assert len(Z1) > 0
    m = Z1.shape[1]
    X1 = np.where(run.alive[:, 1, None], run.truths[:, 1], np.nan)
    scans = [  # (k, Z, truths): a scan with detections, then empty ones of every shape
        (1, Z1, X1),
        (2, np.empty((0, m)), np.empty((0, X1.shape[1]))),  # the live link's empty scan
        (3, np.empty(0), np.empty(0)),
        (4, [], None),
    ]
    tr = TrackEstimate(7, np.arange(6.0), np.eye(6), True, True, None)
    tracks = {1: (tr,), 2: (), 3: (), 4: ()}
    deleted = {1: (), 2: (7,), 3: (), 4: ()}

    path = tmp_path / "empty.mcap"
    sink = McapSink(path)
    info = RunInfo("test empty scan", "test", 0, filters={"ekf": {"spec": "ekf"}},
                   config={"steps": 4, "dt": 1.0}, versions=package_versions())
    sink.open(info)
    sink.start("ekf", 0.0, np.zeros(0), np.zeros((0, 0)))
    for k, Z, X in scans:
        sink.sample(RadarScanSample(float(k), k, Z, radar.with_pose(run.poses_est[0]),
                                    None, X))
        sink.record(ScanRecord("ekf", k, float(k), tracks[k], deleted[k], 0, 0.0))
    sink.close()

    got: dict[str, list] = {}
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=True):
            got.setdefault(channel.topic, []).append((schema, msg))

    def js(topic):
        return [json.loads(msg.data) for _, msg in got[topic]]

    scan = js("/radar/scan")
    assert [s["k"] for s in scan] == [1, 2, 3, 4]
    assert [len(s["z"]) for s in scan] == [len(Z1), 0, 0, 0]
    assert [len(s["xyz"]) for s in scan] == [len(Z1), 0, 0, 0]
    # the detections scene exists for every scan (only the sensor sphere when empty)
    det = got["/radar/detections"]
    assert len(det) == 4 and all(s.name == "foxglove.SceneUpdate" for s, _ in det)
    assert [m.log_time for _, m in det] == [k * 10**9 for k in (1, 2, 3, 4)]
    truth = js("/radar/truth/state")
    assert [t["k"] for t in truth] == [1, 2, 3]
    assert truth[0]["n"] == int(run.alive[:, 1].sum()) and truth[1]["n"] == truth[2]["n"] == 0
    st = js("/tracks/ekf/state")
    assert [s["k"] for s in st] == [1, 2, 3, 4]
    assert [len(s["tracks"]) for s in st] == [1, 0, 0, 0]
    assert st[1]["deleted"] == [7]
    assert len(got["/tracks/ekf"]) == 4
