"""The Foxglove layouts (shipped ``uavest/layouts/*.json`` and the ones written beside a
recording) have the structure Foxglove's *Import layout* expects, and every topic (and
every message path of a plot) a panel refers to is one the recording of that kind holds.

The structure is the app's layout file (``LayoutData``: ``configById`` with one config per
panel id ``"<PanelType>!<id>"``, a ``layout`` mosaic tree of panel ids or ``{direction:
row|column, first, second, splitPercentage}``, ``globalVariables``, ``userNodes``,
``linkedGlobalVariables``, ``playbackConfig`` with ``speed`` and ``messageOrder``), as in
the app's default layout (studio-base ``CurrentLayoutProvider/defaultLayout.ts``). It
cannot be imported into the real app here (no network); this checks what can be checked
offline."""

import json
import re
from importlib import resources

import pytest
from conftest import shared_logs_dir

from uavest.apps.replay import ReplayConfig, replay
from uavest.cli import main
from uavest.report import read_recording
from uavest.report.radar_demo import run_radar_demo
from uavest.sinks.mcap import McapSink

VTOL = shared_logs_dir() / "vtol.tlog"
PANEL_ID = re.compile(r"^(3D|Plot|RosOut|Map|RawMessages|Indicator|Table)![A-Za-z0-9_]+$")
#: Foxglove message path (its grammar, the subset the layouts use): a topic of
#: "/"-separated [A-Za-z0-9_-] names, or any topic double-quoted with \\ and \" escapes,
#: then .field or .field[i] parts
_TOPIC = r'(?P<plain>(?:/[A-Za-z0-9_-]*)+)|"(?P<quoted>(?:[^"\\]|\\.)*)"'
PATH = re.compile(rf"^(?:{_TOPIC})(?P<fields>(?:\.[A-Za-z0-9_-]+(?:\[\d+\])?)+)$")


def split_path(value: str) -> tuple[str, str]:
    """(topic, ".field...") of a message path, quotes and escapes undone."""
    m = PATH.match(value)
    assert m, f"not a Foxglove message path: {value}"
    topic = m["plain"] if m["plain"] is not None else re.sub(r"\\(.)", r"\1", m["quoted"])
    return topic, m["fields"]


def shipped_layouts() -> dict[str, dict]:
    d = resources.files("uavest.layouts")
    return {p.name: json.loads(p.read_text()) for p in d.iterdir() if p.name.endswith(".json")}


def leaves(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict), node
    assert set(node) >= {"direction", "first", "second"}, node
    assert node["direction"] in ("row", "column")
    assert 0 < float(node.get("splitPercentage", 50)) < 100 or node.get("splitPercentage") == 100
    return leaves(node["first"]) + leaves(node["second"])


def check_structure(lay: dict) -> None:
    assert set(lay) >= {"configById", "layout", "globalVariables", "userNodes",
                        "playbackConfig"}
    assert isinstance(lay["globalVariables"], dict) and isinstance(lay["userNodes"], dict)
    assert isinstance(lay.get("linkedGlobalVariables", []), list)
    pc = lay["playbackConfig"]
    assert pc["speed"] > 0 and pc["messageOrder"] in ("receiveTime", "headerStamp")
    ids = leaves(lay["layout"])
    assert len(ids) == len(set(ids)), "a panel appears twice in the mosaic"
    assert set(ids) == set(lay["configById"]), "mosaic and configById disagree"
    for pid, cfg in lay["configById"].items():
        assert PANEL_ID.match(pid), pid
        assert isinstance(cfg, dict)
        if pid.startswith("Plot!"):
            assert cfg["paths"], pid
            for p in cfg["paths"]:
                split_path(p["value"])
                assert p["timestampMethod"] in ("receiveTime", "headerStamp")
                assert re.match(r"^#[0-9a-f]{6}([0-9a-f]{2})?$", p["color"]), p["color"]
        if pid.startswith("3D!"):
            assert isinstance(cfg["topics"], dict) and cfg["followTf"]


def referenced(lay: dict) -> tuple[set[str], list[str], set[str]]:
    """(topics, plot message paths, followed frames) the panels refer to."""
    topics, paths, frames = set(), [], set()
    for cfg in lay["configById"].values():
        for p in cfg.get("paths", []):
            paths.append(p["value"])
            topics.add(split_path(p["value"])[0])
        topics |= set(cfg.get("topics", {}))
        if cfg.get("followTf"):
            frames.add(cfg["followTf"])
    return topics, paths, frames


def resolve(msg: dict, fields: str):
    """The value at ``.a.b[i]`` of a JSON message (KeyError/IndexError if absent)."""
    v = msg
    for name, idx in re.findall(r"\.([A-Za-z0-9_-]+)(?:\[(\d+)\])?", fields):
        v = v[name]
        if idx:
            v = v[int(idx)]
    return v


def check_against(lay: dict, rec) -> None:
    topics, paths, frames = referenced(lay)
    missing = topics - set(rec.counts)
    assert not missing, f"layout refers to topics the recording lacks: {sorted(missing)}"
    for t in topics:
        assert rec.counts[t] > 0, f"{t} has no messages"
    for p in paths:
        topic, fields = split_path(p)
        msgs = rec.json[topic]
        assert any(_has(m, fields) for m in msgs), f"no message of {topic} has {fields}"
    child = {"world"}
    for t in rec.topics("/tf/"):
        child |= {m["child_frame_id"] for m in rec.decode(t)}
    assert frames <= child, frames - child


def _has(m, fields) -> bool:
    try:
        resolve(m, fields)
        return True
    except (KeyError, IndexError, TypeError):
        return False


def test_shipped_layouts_have_the_import_structure():
    lays = shipped_layouts()
    assert set(lays) == {"attitude.json", "radar.json"}
    for lay in lays.values():
        check_structure(lay)


@pytest.mark.skipif(not VTOL.exists(), reason=f"needs {VTOL} (or UAVEST_LOGS)")
def test_attitude_layouts_refer_only_to_recorded_topics(tmp_path):
    path = tmp_path / "vtol.mcap"
    sink = McapSink(path)
    replay(VTOL, ReplayConfig(end=640.0), sinks=[sink], command="test")
    rec = read_recording(path)
    written = json.loads(sink.layout_path.read_text())
    check_structure(written)
    check_against(written, rec)
    check_against(shipped_layouts()["attitude.json"], rec)  # default filters ekf/ukf/hybrid


def test_radar_layouts_refer_only_to_recorded_topics(tmp_path):
    path = tmp_path / "radar.mcap"
    sink = McapSink(path)
    run_radar_demo([sink], steps=8, filters=("ekf", "ukf", "hybrid"))
    rec = read_recording(path)
    written = json.loads(sink.layout_path.read_text())
    check_structure(written)
    check_against(written, rec)
    check_against(shipped_layouts()["radar.json"], rec)


def test_state_layout_refers_only_to_recorded_topics(tmp_path):
    path = tmp_path / "nl2d.mcap"
    assert main(["bench", "nonlinear2d", "--runs", "1", "--steps", "8", "--filters",
                 "ekf,ukf", "--mcap", str(path), "--no-progress"]) == 0
    rec = read_recording(path)
    lay = json.loads(path.with_name("nl2d.layout.json").read_text())
    check_structure(lay)
    check_against(lay, rec)
    # one error plot per state component (nonlinear2d: 2)
    assert {p for p in lay["configById"] if p.startswith("Plot!uavest_err_x")} == {
        "Plot!uavest_err_x0", "Plot!uavest_err_x1"}


def test_a_layout_with_a_missing_topic_fails_the_check(tmp_path):
    """The checks can fail: a layout for a filter the recording does not have."""
    from uavest.layouts import build_layout

    path = tmp_path / "radar.mcap"
    run_radar_demo([McapSink(path)], steps=4, filters=("ekf",))
    with pytest.raises(AssertionError, match="lacks"):
        check_against(build_layout(["ekf", "pf"], "radar"), read_recording(path))


def test_labels_with_special_characters_are_quoted_topics(tmp_path):
    """A label like ``ukf(alpha=0.5)`` (bench specs) or ``track:ekf`` (the live demo's
    trackers) is not a plain Foxglove topic name: the layout quotes it, and the quoted
    path still names the recorded topic."""
    from uavest.layouts import build_layout, mpath

    assert mpath("/tracks/track:ekf/state", "n_confirmed") == \
        '"/tracks/track:ekf/state".n_confirmed'
    assert split_path(mpath('/a/we"ird', "x[0]")) == ('/a/we"ird', ".x[0]")
    lay = build_layout(["track:ekf"], "radar")
    assert split_path(lay["configById"]["Plot!uavest_tracks"]["paths"][0]["value"])[0] == \
        "/tracks/track:ekf/state"
    path = tmp_path / "u.mcap"
    assert main(["bench", "ungm", "--runs", "1", "--steps", "5", "--filters",
                 "ekf,ukf(alpha=0.5)", "--mcap", str(path), "--no-progress"]) == 0
    lay = json.loads(path.with_name("u.layout.json").read_text())
    check_structure(lay)
    check_against(lay, read_recording(path))
    values = [p["value"] for c in lay["configById"].values() for p in c.get("paths", [])]
    assert '"/state/ukf(alpha=0.5)/error".nees' in values
