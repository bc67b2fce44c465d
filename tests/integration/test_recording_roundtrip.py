"""Round trip: what McapSink wrote, read back independently with the ``mcap`` reader
(JSON decoded, protobuf decoded with the schema's own descriptor), equals what the run
computed, values and counts; every channel has a well-known or a titled JSON schema; the
report recomputes the replay's metrics from the file alone."""

import json
import re
from collections import Counter

import numpy as np
import pytest
from conftest import google_decoded, shared_logs_dir

from uavest.apps.replay import ReplayConfig, replay
from uavest.ingest.types import AttitudeRef, ImuSample, MagSample
from uavest.report import read_recording, write_report
from uavest.report.build import ATTITUDE_FIGURES, RADAR_FIGURES
from uavest.report.radar_demo import run_radar_demo
from uavest.sinks.base import Collector, Sink
from uavest.sinks.foxglove import ned_frd_to_enu_flu, triu_to_full
from uavest.sinks.mcap import McapSink

VTOL = shared_logs_dir() / "vtol.tlog"
pytestmark = pytest.mark.skipif(not VTOL.exists(), reason=f"needs {VTOL} (or UAVEST_LOGS)")


class Samples(Sink):
    def __init__(self):
        self.n = Counter()
        self.last_ref = {}

    def sample(self, s):
        if isinstance(s, ImuSample):
            self.n["/imu/" + s.source] += 1
        elif isinstance(s, MagSample):
            self.n["/mag/" + s.source] += 1
        elif isinstance(s, AttitudeRef):
            if s.t > self.last_ref.get(s.source, -1e18):  # references keep increasing times
                self.last_ref[s.source] = s.t
                self.n["/reference/" + s.source] += 1


@pytest.fixture(scope="module")
def vtol(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec")
    path = d / "vtol.mcap"
    coll, smp = Collector(), Samples()
    sink = McapSink(path, frame_rate_hz=None)  # every step on the 3-D channels too
    doc = replay(VTOL, ReplayConfig(end=660.0), sinks=[coll, smp, sink], command="test")
    return {"path": path, "coll": coll, "samples": smp, "doc": doc, "sink": sink,
            "rec": read_recording(path)}


@pytest.mark.slow
def test_every_channel_has_a_well_known_or_titled_json_schema(vtol):
    rec = vtol["rec"]
    assert not rec.truncated and rec.chunks >= 2
    own = set()
    for topic, (name, enc, msg_enc) in rec.schemas.items():
        if enc == "protobuf":
            assert name.startswith(("foxglove.", "uavest.")) and msg_enc == "protobuf", topic
            if name.startswith("uavest."):
                own.add(name)
        else:
            assert enc == "jsonschema" and msg_enc == "json", topic
            schema = json.loads(rec.schema_data[topic])
            assert schema["title"] == name and name.startswith("uavest."), topic
    # the per-step channels are uavest's own protobuf messages
    assert {"uavest.Imu", "uavest.Mag", "uavest.AttitudeReference", "uavest.AttitudeEstimate",
            "uavest.AttitudeError", "uavest.FilterHealth"} <= own
    names = {v[0] for v in rec.schemas.values()}
    assert {"foxglove.FrameTransform", "foxglove.PoseInFrame", "foxglove.LocationFix",
            "foxglove.SceneUpdate", "foxglove.Log"} <= names


def test_counts_equal_what_the_run_produced(vtol):
    rec, coll, smp = vtol["rec"], vtol["coll"], vtol["samples"]
    labels = list(coll.records)
    assert labels == ["ekf", "ukf", "hybrid"]
    for lab in labels:
        n = len(coll.records[lab])
        assert n > 100
        for ch in ("estimate", "health", "pose"):
            assert rec.counts[f"/attitude/{lab}/{ch}"] == n, (lab, ch)
        assert rec.counts[f"/tf/{lab}"] == n
        # every step inside the truth's span has an error message
        assert rec.counts[f"/attitude/{lab}/error"] == vtol["doc"]["filters"][lab]["n"]
    for topic, n in smp.n.items():
        assert rec.counts[topic] == n, topic
    assert rec.counts["/tf/truth"] == smp.n["/reference/SIMSTATE"]


def test_values_equal_what_the_run_computed(vtol):
    rec, coll = vtol["rec"], vtol["coll"]
    for lab, recs in coll.records.items():
        est = rec.json[f"/attitude/{lab}/estimate"]
        a = coll.arrays(lab)
        np.testing.assert_array_equal(np.array([m["t"] for m in est]), a["t"])
        np.testing.assert_array_equal(np.array([m["q"] for m in est]), a["x"][:, :4])
        np.testing.assert_array_equal(np.array([m["bias_rad_s"] for m in est]), a["x"][:, 4:])
        iu = np.triu_indices(6)
        Pt = np.array([m["P_triu"] for m in est], float)
        np.testing.assert_array_equal(Pt, a["P"][:, iu[0], iu[1]])
        # the filters' covariances are symmetric up to rounding (the recorder keeps the
        # upper triangle exactly)
        np.testing.assert_allclose(triu_to_full(Pt, 6), a["P"],
                                   rtol=1e-12, atol=1e-18)
        hl = rec.json[f"/attitude/{lab}/health"]
        nis = np.array([np.nan if m["nis"] is None else m["nis"] for m in hl])
        np.testing.assert_array_equal(nis, a["nis"])
        assert [m["nis_dof"] for m in hl] == [sum(u.nu.size for u in r.updates) for r in recs]
        np.testing.assert_allclose([m["wall_us"] for m in hl], 1e6 * a["wall_s"])
        # the 3-D frame: ENU/FLU of the estimate, under world, log time = step time
        tf = rec.decode(f"/tf/{lab}")
        assert {m["child_frame_id"] for m in tf} == {f"body_{lab}"}
        assert {m["parent_frame_id"] for m in tf} == {"world"}
        qe = np.array([[m["rotation"][k] for k in ("w", "x", "y", "z")] for m in tf])
        np.testing.assert_allclose(qe, ned_frd_to_enu_flu(a["x"][:, :4]), atol=1e-12)
        assert rec.log_times.get(f"/tf/{lab}") is None or True
        ts = np.array([m["timestamp"]["seconds"] + 1e-9 * m["timestamp"]["nanos"] for m in tf])
        np.testing.assert_allclose(ts, a["t"], atol=1e-9)


@pytest.mark.slow
def test_error_channel_and_report_reproduce_the_replay_scores(vtol, tmp_path):
    doc, rec = vtol["doc"], vtol["rec"]
    assert doc["reference"] == "SIMSTATE"
    for lab in ("ekf", "ukf", "hybrid"):
        err = rec.json[f"/attitude/{lab}/error"]
        assert {m["reference"] for m in err} == {"SIMSTATE"}
        e = np.array([[m["err_deg"][k] for k in ("roll", "pitch", "yaw")] for m in err])
        rmse = np.sqrt(np.mean(e**2, axis=0))
        row = doc["filters"][lab]
        np.testing.assert_allclose(
            rmse, [row["roll_rmse_deg"], row["pitch_rmse_deg"], row["yaw_rmse_deg"]],
            rtol=1e-9)
        np.testing.assert_allclose(np.mean([m["nees"] for m in err]), row["nees_mean"],
                                   rtol=1e-9)
    paths = write_report(vtol["path"], tmp_path)
    m = json.loads(paths["metrics"].read_text())
    assert m["reference"] == "SIMSTATE"
    for lab, row in doc["filters"].items():
        if lab not in ("ekf", "ukf", "hybrid"):
            continue
        got = m["filters"][lab]
        for k in ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "nees_mean"):
            assert got[k] == pytest.approx(row[k], rel=1e-9), (lab, k)
        assert got["n"] == row["n"]
        assert got["resets"] == row["resets"]
    page = paths["html"].read_text()
    _check_page(page, ATTITUDE_FIGURES)
    md = paths["markdown"].read_text()
    assert "| ekf |" in md and all(p.exists() for p in paths["figures"])


def _check_page(page: str, figures):
    # self-contained: no http(s) resources, every figure an inline image
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", page)
    ids = re.findall(r"<figure class='report-figure' id='([^']+)'>", page)
    assert tuple(ids) == tuple(figures)
    assert page.count("src='data:image/png;base64,") == len(figures)


def test_metadata_and_layout(vtol):
    rec, doc = vtol["rec"], vtol["doc"]
    assert rec.metadata["run"] == {"command": "test", "source": str(VTOL), "seed": "0"}
    filters = {k: json.loads(v) for k, v in rec.metadata["filters"].items()}
    assert filters == json.loads(json.dumps(doc["run"]["filters"]))
    assert rec.metadata["versions"]["numpy"] == np.__version__
    assert "ENU" in rec.metadata["recording"]["frames"]
    lay = json.loads(vtol["sink"].layout_path.read_text())
    referenced = set()
    for cfg in lay["configById"].values():
        for p in cfg.get("paths", []):
            referenced.add(p["value"].split(".")[0])
        referenced |= set(cfg.get("topics", {}))
    assert referenced <= set(rec.counts), referenced - set(rec.counts)


@pytest.mark.slow
def test_radar_recording_round_trip(tmp_path):
    path = tmp_path / "radar.mcap"
    out = run_radar_demo([McapSink(path)], steps=25, filters=("ekf", "ukf"))
    rec = read_recording(path)
    run = out["run"]
    for lab, recs in out["records"].items():
        st = rec.json[f"/tracks/{lab}/state"]
        assert len(st) == len(recs) == 25 == rec.counts[f"/tracks/{lab}"]
        for m, r in zip(st, recs, strict=True):
            assert [x["id"] for x in m["tracks"]] == [x.id for x in r.tracks]
            assert [x["confirmed"] for x in m["tracks"]] == [x.confirmed for x in r.tracks]
            for x, y in zip(m["tracks"], r.tracks, strict=True):
                np.testing.assert_array_equal(x["x"], y.x)
                np.testing.assert_array_equal(np.reshape(x["P"], y.P.shape), y.P)
        scene = rec.decode(f"/tracks/{lab}")
        ids = [sorted(e["id"] for e in s.get("entities", [])) for s in scene]
        assert ids == [sorted(f"{lab}/{x.id}" for x in r.tracks) for r in recs]
        ents = [e for s in scene for e in s.get("entities", [])]
        assert all(e["texts"][0]["text"].startswith(f"{lab} #") for e in ents)
    scans = rec.json["/radar/scan"]
    assert [len(m["z"]) for m in scans] == [len(z) for z in run.scans]
    truth = rec.json["/radar/truth/state"]
    assert [m["n"] for m in truth] == list(run.alive[:, 1:].sum(axis=0))
    paths = write_report(path, tmp_path / "rep")
    m = json.loads(paths["metrics"].read_text())
    assert m["kind"] == "radar" and m["gospa_c"] == 200.0
    assert m["filters"]["ekf"]["tracks_confirmed_total"] >= 1
    assert m["filters"]["ekf"]["gospa_mean"] > 0
    _check_page(paths["html"].read_text(), RADAR_FIGURES)


def test_own_protobuf_channels_decode_with_google_protobuf(vtol):
    """uavest's protobuf channels, read with the ``mcap`` reader and decoded by Google's
    ``protobuf`` from the schema in the file (not by our decoder), equal what the report's
    reader decoded, field by field (NaN there as None here)."""
    rec = vtol["rec"]
    got = google_decoded(vtol["path"])
    assert {"/attitude/ekf/estimate", "/attitude/ekf/health", "/attitude/ekf/error",
            "/reference/SIMSTATE"} <= set(got)

    def same(a, b):  # ours (None for NaN) against Google's
        if a is None:
            assert b != b, b
        else:
            assert a == b

    for topic, msgs in got.items():
        mine = rec.json[topic]
        assert len(mine) == len(msgs), topic
        for m, g in zip(mine, msgs, strict=True):
            same(m["t"], g.t)
            if topic.endswith("/estimate"):
                assert m["k"] == g.k
                for a, b in zip(m["q"] + m["P_triu"], list(g.q) + list(g.P_triu), strict=True):
                    same(a, b)
                same(m["sigma3_deg"]["yaw"], g.sigma3_deg.yaw)
            elif topic.endswith("/health"):
                assert m.get("updates", []) == [
                    {"kind": u.kind, "nis": u.nis, "dof": u.dof} for u in g.updates]
                assert (m["reset"], m["resets"], m["nis_dof"]) == (g.reset, g.resets, g.nis_dof)
                same(m["nis"], g.nis)
            elif topic.endswith("/error"):
                assert (m["reference"], m["kind"]) == (g.reference, g.kind)
                same(m["err_deg"]["roll"], g.err_deg.roll)
                same(m["nees"], g.nees)
            elif topic.startswith("/imu/"):
                assert m["gyro_rad_s"] == list(g.gyro_rad_s) and m["source"] == g.source


@pytest.mark.slow
def test_batched_recording_equals_one_message_at_a_time(tmp_path):
    """The recorder encodes in batches (the default) or one record at a time (batch=1, as
    the live view): the same messages on every topic, in the same order per topic."""
    a, b = McapSink(tmp_path / "a.mcap", batch=1), McapSink(tmp_path / "b.mcap")
    replay(VTOL, ReplayConfig(end=660.0), sinks=[a, b], command="test")
    ra, rb = read_recording(tmp_path / "a.mcap"), read_recording(tmp_path / "b.mcap")
    wall = "/attitude/bodies"  # re-sent once a wall second: its count depends on the clock
    assert {k: v for k, v in ra.counts.items() if k != wall} == {
        k: v for k, v in rb.counts.items() if k != wall}
    assert ra.counts["/attitude/ekf/error"] > 100
    for topic, msgs in ra.json.items():
        if topic != "/run/info":
            assert rb.json[topic] == msgs, topic
    for topic, msgs in ra.raw.items():
        if topic != wall:
            assert [m for _, m in rb.raw[topic]] == [m for _, m in msgs], topic


def test_bulk_decoder_equals_the_message_decoder(vtol):
    """The reader decodes uavest's protobuf channels in bulk (numpy over the fixed layout,
    the message decoder for the others): the same dicts as decoding each message, on the
    recording and on a batch with NaN / inf values and odd messages mixed in."""
    from mcap.reader import make_reader

    from uavest.report.protowire import ProtoDecoder
    from uavest.report.read import _nulls, decode_own
    from uavest.sinks import protobuf as pb

    by_topic, names = {}, {}
    with open(vtol["path"], "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=False):
            if schema.encoding == "protobuf" and schema.name.startswith("uavest."):
                by_topic.setdefault(channel.topic, []).append(bytes(msg.data))
                names[channel.topic] = schema.name
    dec = ProtoDecoder(pb.DESCRIPTOR_SET)
    assert len(by_topic) >= 15
    for topic, msgs in by_topic.items():
        assert decode_own(dec, names[topic], msgs) == [
            _nulls(dec.decode(m, names[topic])) for m in msgs], topic
    rng = np.random.default_rng(6)
    n = 20
    P = rng.standard_normal((n, 21))
    P[3, 5], P[7, 0], P[7, 20] = np.nan, np.inf, -np.inf
    enc = pb.FixedEncoder("AttitudeEstimate", lengths={"q": 4, "bias_rad_s": 3, "P_triu": 21})
    msgs = enc.encode(n, {"t": rng.random(n), "k": np.arange(n), "q": rng.random((n, 4)),
                          "P_triu": P, "rpy_deg": np.full((n, 3), np.nan)})
    msgs[4] = msgs[4] + pb.field_bytes(1, 9.5)  # a repeated scalar field: decoded singly
    msgs[9] = msgs[9][:-8] + struct_pack_d(1.0)  # same length, other values: bulk
    got = decode_own(dec, "uavest.AttitudeEstimate", msgs)
    assert got == [_nulls(dec.decode(m, "uavest.AttitudeEstimate")) for m in msgs]
    assert got[3]["P_triu"][5] is None and got[7]["P_triu"][20] is None
    assert got[0]["rpy_deg"] == {"roll": None, "pitch": None, "yaw": None}


def struct_pack_d(v: float) -> bytes:
    import struct

    return struct.pack("<d", v)
