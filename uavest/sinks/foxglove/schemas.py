"""JSON schemas (titled ``uavest.*``) of uavest's own JSON channels (the per-step
attitude channels and the raw samples are protobuf: :mod:`uavest.sinks.protobuf`)."""

from __future__ import annotations

__all__ = ["SCHEMAS"]


def _obj(title: str, desc: str, props: dict, required=()) -> dict:
    return {"title": title, "description": desc, "type": "object", "properties": props,
            "required": list(required)}


_NUM = {"type": ["number", "null"]}

_VEC3 = {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3}

_RPY = {"type": "object", "properties": {"roll": _NUM, "pitch": _NUM, "yaw": _NUM}}


#: JSON schemas (by title) of uavest's own JSON channels (the per-step attitude channels
#: and the raw samples are protobuf: :mod:`uavest.sinks.protobuf`; ``uavest.FilterHealth``
#: is also the JSON schema of the generic ``/state/<label>/health``).
SCHEMAS: dict[str, dict] = {
    "uavest.Position": _obj("uavest.Position", "vehicle position: NED m from the local "
                            "origin, velocity NED m/s, lat deg, lon deg, alt m AMSL", {
        "t": _NUM, "source": {"type": "string"}, "ned_m": _VEC3, "vel_ned_m_s": _VEC3,
        "lat_lon_alt": _VEC3}, ["t"]),
    "uavest.FilterHealth": _obj(
        "uavest.FilterHealth", "a filter step's health: total NIS of the updates and its "
        "degrees of freedom, per-update NIS, guard resets, wall time us", {
            "t": _NUM, "k": {"type": "integer"}, "nis": _NUM, "nis_dof": {"type": "integer"},
            "updates": {"type": "array"}, "reset": {"type": "boolean"},
            "reason": {"type": "string"}, "resets": {"type": "integer"},
            "wall_us": _NUM}, ["t", "k", "wall_us"]),
    "uavest.RadarScan": _obj(
        "uavest.RadarScan", "radar detections of one scan: z rows [range m, az rad, (el "
        "rad), (range rate m/s)], world ENU positions m, origins (target index, -1 clutter)",
        {"t": _NUM, "k": {"type": "integer"}, "z": {"type": "array"},
         "xyz": {"type": "array"}, "origins": {"type": "array"},
         "sensor_position": {"type": "array"}}, ["t", "k", "z"]),
    "uavest.TargetTruth": _obj(
        "uavest.TargetTruth", "true targets alive at the scan: id (target index), x world "
        "ENU [p m, v m/s]", {"t": _NUM, "k": {"type": "integer"}, "n": {"type": "integer"},
                             "targets": {"type": "array"}}, ["t", "k", "targets"]),
    "uavest.Tracks": _obj(
        "uavest.Tracks", "a tracker's live tracks after a scan: id, x, P (row-major), "
        "confirmed, hit; deleted ids; wall time us", {
            "t": _NUM, "k": {"type": "integer"}, "n_confirmed": {"type": "integer"},
            "n_tentative": {"type": "integer"}, "tracks": {"type": "array"},
            "deleted": {"type": "array"}, "resets": {"type": "integer"},
            "wall_us": _NUM}, ["t", "k", "tracks"]),
    "uavest.StateEstimate": _obj(
        "uavest.StateEstimate", "a filter's posterior of a generic vector state (the "
        "system's own units): x (n,), per-component 3-sigma 3 sqrt(P_ii), P (n x n, "
        "row-major; the same coordinates as x)", {
            "t": _NUM, "k": {"type": "integer"}, "n": {"type": "integer"},
            "x": {"type": "array", "items": _NUM}, "sigma3": {"type": "array", "items": _NUM},
            "P": {"type": "array", "items": _NUM}}, ["t", "k", "x", "P"]),
    "uavest.StateError": _obj(
        "uavest.StateError", "estimate - truth of a generic vector state per component, "
        "the filter's own +-3 sigma per component (3 sqrt(P_ii)), NEES e^T P^-1 e with "
        "dof = n (truth of the same step)", {
            "t": _NUM, "k": {"type": "integer"}, "err": {"type": "array", "items": _NUM},
            "sigma3": {"type": "array", "items": _NUM},
            "neg_sigma3": {"type": "array", "items": _NUM}, "nees": _NUM,
            "dof": {"type": "integer"}}, ["t", "k", "err", "sigma3", "nees"]),
    "uavest.StateTruth": _obj(
        "uavest.StateTruth", "the true state of a simulated run at step k (system units)", {
            "t": _NUM, "k": {"type": "integer"}, "x": {"type": "array", "items": _NUM}},
        ["t", "k", "x"]),
    "uavest.Measurement": _obj(
        "uavest.Measurement", "the measurement z of step k (system units)", {
            "t": _NUM, "k": {"type": "integer"}, "z": {"type": "array", "items": _NUM}},
        ["t", "k", "z"]),
    "uavest.NavAnchor": _obj(
        "uavest.NavAnchor", "a navigation run's local NED frame: its origin (lat, lon deg, "
        "alt m; the first raw GNSS fix of source), the time t (s) from which positions are "
        "in it (later than the first estimate when the run started before the first fix) "
        "and its geodesy (wgs84: tangent plane through ECEF; sphere: ArduPilot's flat-Earth "
        "scaling, for an ArduPilot SITL)", {
            "t": _NUM, "lat_lon_alt": {"type": "array", "items": _NUM},
            "source": {"type": "string"}, "reason": {"type": "string"},
            "geodesy": {"type": "string", "enum": ["wgs84", "sphere"]}},
        ["t", "lat_lon_alt"]),
    "uavest.RunInfo": _obj("uavest.RunInfo", "the run (also in the MCAP metadata)", {
        "command": {"type": "string"}, "source": {"type": "string"},
        "seed": {"type": "integer"}, "filters": {"type": "object"},
        "config": {"type": "object"}, "versions": {"type": "object"}}),
}

