"""Foxglove layouts shipped with uavest, and the colours every view uses per estimator.

``attitude.json`` and ``radar.json`` (package data, beside this module) are the layouts
for the default filters (``ekf``, ``ukf``, ``hybrid``); :func:`build_layout` makes the
same layout for any set of estimator labels, and the recording sinks write it beside each
recording as ``<name>.layout.json`` (Foxglove: *Layouts -> Import from file*).

The layout JSON is the Foxglove app's layout file format (``configById`` with one config
per panel id ``"<PanelType>!<id>"``, and a ``layout`` mosaic tree of ``direction`` /
``first`` / ``second`` / ``splitPercentage``).
"""

from __future__ import annotations

import json
import re
import zlib
from importlib import resources

__all__ = ["COLOURS", "REFERENCE_COLOUR", "build_layout", "colour", "layout_text", "mpath",
           "shipped"]

#: Fixed colours of the usual estimator labels (hex RGB); any other label takes a colour
#: of :data:`_CYCLE` chosen by a CRC of its name, so every process (recorder, layout,
#: report) gives a label the same colour.
COLOURS = {
    "ekf": "#1f77b4",
    "ukf": "#ff7f0e",
    "hybrid": "#2ca02c",
    "enkf": "#d62728",
    "pf": "#9467bd",
    "ahrs": "#8c564b",
}
_CYCLE = ("#e377c2", "#17becf", "#bcbd22", "#7f7f7f", "#aec7e8", "#ffbb78", "#98df8a")
#: Truth / reference colour.
REFERENCE_COLOUR = "#000000"


def colour(label: str) -> str:
    """Hex colour ``#rrggbb`` of an estimator label."""
    if label in COLOURS:
        return COLOURS[label]
    return _CYCLE[zlib.crc32(label.encode()) % len(_CYCLE)]


_PLAIN_TOPIC = re.compile(r"^(/[A-Za-z0-9_-]*)+$")


def mpath(topic: str, fields: str) -> str:
    """A Foxglove message path ``<topic>.<fields>``: the topic as it is when it is made of
    ``/``-separated ``[A-Za-z0-9_-]`` names, else double-quoted (Foxglove's message-path
    grammar; a label such as ``track:ekf`` or ``ukf(alpha=0.5)`` needs the quotes)."""
    if not _PLAIN_TOPIC.match(topic):
        topic = '"' + topic.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return f"{topic}.{fields}"


def _plot(title: str, paths: list[tuple[str, str, str]], ylabel: str = "",
          min_y: float | None = None, max_y: float | None = None) -> dict:
    cfg: dict = {
        "title": title,
        "paths": [
            {"value": v, "enabled": True, "timestampMethod": "receiveTime", "label": lab,
             "color": col}
            for v, lab, col in paths
        ],
        "showXAxisLabels": True,
        "showYAxisLabels": True,
        "showLegend": True,
        "legendDisplay": "floating",
        "showPlotValuesInLegend": False,
        "isSynced": True,
        "xAxisVal": "timestamp",
        "sidebarDimension": 240,
        "foxglovePanelTitle": title,
    }
    if ylabel:
        cfg["yAxisLabel"] = ylabel
    if min_y is not None:
        cfg["minYValue"] = min_y
    if max_y is not None:
        cfg["maxYValue"] = max_y
    return cfg


def _three_d(follow: str, topics: list[str], distance: float) -> dict:
    return {
        "followTf": follow,
        "followMode": "follow-position",
        "scene": {"enableStats": False, "transforms": {"showLabel": True, "axisScale": 1.5}},
        "transforms": {},
        "topics": {t: {"visible": True} for t in topics},
        "layers": {"grid": {"layerId": "foxglove.Grid", "visible": True, "frameId": "world",
                            "size": 10 * distance, "divisions": 20}},
        "cameraState": {"distance": distance, "perspective": True, "phi": 60.0,
                        "thetaOffset": 45.0, "targetOffset": [0, 0, 0], "target": [0, 0, 0],
                        "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.5,
                        "far": 50000},
        "foxglovePanelTitle": "3-D: world ENU, bodies FLU",
    }


def _split(direction: str, first, second, pct: float = 50.0) -> dict:
    return {"direction": direction, "first": first, "second": second, "splitPercentage": pct}


def _column(ids: list[str]) -> str | dict:
    if len(ids) == 1:
        return ids[0]
    return _split("column", ids[0], _column(ids[1:]), 100.0 / len(ids))


def _event_log() -> dict:
    """The event-log panel (``/log``, info and above)."""
    return {"searchTerms": [], "minLogLevel": 1, "foxglovePanelTitle": "events (/log)"}

#: A layout's panels: the panel configs by id and the mosaic tree that places them.
Panels = tuple[dict[str, dict], str | dict]


def _sigma_paths(base: str, err: str, sigma: str, neg_sigma: str, lab: str) -> list[tuple]:
    """One estimator's error and +-3 sigma plot paths under ``base`` (the bounds in the
    estimator's colour at half opacity)."""
    c = colour(lab)
    return [(mpath(base, err), f"{lab} error", c),
            (mpath(base, sigma), f"{lab} +3 sigma", c + "80"),
            (mpath(base, neg_sigma), f"{lab} -3 sigma", c + "80")]


def _attitude_panels(labels: list[str], follow: str | None) -> Panels:
    """The attitude layout's panels: the 3-D bodies, roll/pitch/yaw error (deg) with every
    filter's +-3 sigma, NEES, NIS and the event log."""
    cfg: dict[str, dict] = {}
    topics = ["/attitude/bodies"] + [f"/tf/{lab}" for lab in labels]
    cfg["3D!uavest3d"] = _three_d(follow or "body_truth", topics, 12.0)
    plots = []
    for ax in ("roll", "pitch", "yaw"):
        paths = []
        for lab in labels:
            paths += _sigma_paths(f"/attitude/{lab}/error", f"err_deg.{ax}",
                                  f"sigma3_deg.{ax}", f"neg_sigma3_deg.{ax}", lab)
        pid = f"Plot!uavest_err_{ax}"
        cfg[pid] = _plot(f"{ax} error vs reference (deg), +-3 sigma", paths, "deg")
        plots.append(pid)
    cfg["Plot!uavest_nees"] = _plot(
        "attitude NEES (3 dof; 95% band of one step 0.22..9.35)",
        [(mpath(f"/attitude/{lab}/error", "nees"), lab, colour(lab)) for lab in labels],
        "NEES", 0.0, 30.0)
    cfg["Plot!uavest_nis"] = _plot(
        "NIS of the step's updates (dof in .nis_dof)",
        [(mpath(f"/attitude/{lab}/health", "nis"), lab, colour(lab)) for lab in labels],
        "NIS", 0.0, 50.0)
    cfg["RosOut!uavest_log"] = _event_log()
    right = _column(plots + ["Plot!uavest_nees", "Plot!uavest_nis"])
    left = _split("column", "3D!uavest3d", "RosOut!uavest_log", 75.0)
    return cfg, _split("row", left, right, 45.0)


def _radar_panels(labels: list[str], follow: str | None) -> Panels:
    """The radar layout's panels: the 3-D detections, truths and tracks (15 km view), the
    confirmed-track count per tracker against the truth's, and the event log."""
    cfg: dict[str, dict] = {}
    topics = ["/radar/detections", "/radar/truth"] + [f"/tracks/{lab}" for lab in labels]
    td = _three_d(follow or "world", topics, 15000.0)
    td["followMode"] = "follow-none"
    cfg["3D!uavest3d"] = td
    cfg["Plot!uavest_tracks"] = _plot(
        "confirmed tracks per tracker (truth: /radar/truth/state.n)",
        [(mpath(f"/tracks/{lab}/state", "n_confirmed"), lab, colour(lab)) for lab in labels]
        + [("/radar/truth/state.n", "truth", REFERENCE_COLOUR)], "tracks")
    cfg["RosOut!uavest_log"] = _event_log()
    layout = _split("row", "3D!uavest3d",
                    _split("column", "Plot!uavest_tracks", "RosOut!uavest_log", 60.0),
                    65.0)
    return cfg, layout


def _state_panels(labels: list[str], dim: int) -> Panels:
    """The generic vector-state layout's panels: per component (``dim``, at most 6) the
    error with every filter's +-3 sigma, x[0] of the truth and estimates, NEES, NIS and
    the event log."""
    cfg: dict[str, dict] = {}
    plots = []
    for i in range(max(1, min(int(dim), 6))):  # one error plot per state component
        paths = []
        for lab in labels:
            paths += _sigma_paths(f"/state/{lab}/error", f"err[{i}]", f"sigma3[{i}]",
                                  f"neg_sigma3[{i}]", lab)
        pid = f"Plot!uavest_err_x{i}"
        cfg[pid] = _plot(f"x[{i}] error (estimate - truth), +-3 sigma", paths)
        plots.append(pid)
    cfg["Plot!uavest_state"] = _plot(
        "x[0]: truth and estimates",
        [("/truth/state.x[0]", "truth", REFERENCE_COLOUR)]
        + [(mpath(f"/state/{lab}/estimate", "x[0]"), lab, colour(lab))
           for lab in labels], "x[0]")
    cfg["Plot!uavest_nees"] = _plot(
        f"NEES ({dim} dof)",
        [(mpath(f"/state/{lab}/error", "nees"), lab, colour(lab)) for lab in labels],
        "NEES", 0.0)
    cfg["Plot!uavest_nis"] = _plot(
        "NIS of the step's updates (dof in .nis_dof)",
        [(mpath(f"/state/{lab}/health", "nis"), lab, colour(lab)) for lab in labels],
        "NIS", 0.0)
    cfg["RosOut!uavest_log"] = _event_log()
    left = _split("column", "Plot!uavest_state", "RosOut!uavest_log", 70.0)
    layout = _split("row", left, _column(plots + ["Plot!uavest_nees", "Plot!uavest_nis"]),
                    40.0)
    return cfg, layout


def _attitude_and_radar(labels: list[str], follow: str | None,
                        track_labels: list[str]) -> dict:
    """The live run's layout: the attitude layout for ``labels`` with a radar 3-D panel
    and the track-count plot for ``track_labels`` on its right."""
    att = build_layout(labels, "attitude", follow)
    rad = build_layout(track_labels, "radar")
    cfg = dict(att["configById"])
    cfg["3D!uavest3d_radar"] = rad["configById"]["3D!uavest3d"]
    cfg["Plot!uavest_tracks"] = rad["configById"]["Plot!uavest_tracks"]
    att["configById"] = cfg
    att["layout"] = _split("row", att["layout"],
                           _split("column", "3D!uavest3d_radar", "Plot!uavest_tracks",
                                  60.0), 70.0)
    return att


def build_layout(labels: list[str] | tuple[str, ...], kind: str = "attitude",
                 follow: str | None = None, dim: int = 1,
                 track_labels: list[str] | tuple[str, ...] = ()) -> dict:
    """The Foxglove layout (a JSON-ready dict) for estimators ``labels``.

    ``kind="attitude"``: the 3-D panel (every filter's body frame and the truth's side by
    side), roll/pitch/yaw error plots each with every filter's +-3 sigma bounds (deg), the
    NEES and NIS plots, and the event log. ``kind="radar"``: the 3-D panel with the
    detections, the truths and every tracker's tracks, and the track-count plot.
    ``kind="state"`` (generic vector states, ``uavest bench --mcap``): per component
    (``dim`` of them, at most 6) the error plot with every filter's +-3 sigma, x[0] of the
    truth and the estimates, NEES, NIS and the event log.
    ``kind="attitude+radar"`` (a live run with filters and trackers): the attitude layout
    for ``labels`` beside a radar 3-D panel and the track-count plot for
    ``track_labels``.
    ``follow``: the frame the 3-D view follows (default ``body_truth`` / ``world``)."""
    labels = list(labels)
    if kind == "attitude+radar":
        return _attitude_and_radar(labels, follow, list(track_labels))
    if kind == "attitude":
        cfg, layout = _attitude_panels(labels, follow)
    elif kind == "radar":
        cfg, layout = _radar_panels(labels, follow)
    elif kind == "state":
        cfg, layout = _state_panels(labels, dim)
    else:
        raise ValueError("layout kind must be attitude, radar, attitude+radar or state, "
                         f"not {kind!r}")
    return {
        "configById": cfg,
        "globalVariables": {},
        "userNodes": {},
        "linkedGlobalVariables": [],
        "playbackConfig": {"speed": 1.0, "messageOrder": "receiveTime"},
        "layout": layout,
    }


def layout_text(labels, kind: str = "attitude", follow: str | None = None,
                dim: int = 1, track_labels=()) -> str:
    """:func:`build_layout` as indented JSON text."""
    return json.dumps(build_layout(labels, kind, follow, dim, track_labels), indent=2) + "\n"


def shipped(kind: str = "attitude") -> str:
    """Text of the layout shipped as package data (``attitude.json`` / ``radar.json``)."""
    return resources.files(__package__).joinpath(f"{kind}.json").read_text()
