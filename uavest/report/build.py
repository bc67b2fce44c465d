"""Metrics and figures of a recording, and the HTML / Markdown pages.

Everything is recomputed from what the recording holds (never from the recorder's
memory): attitude runs score every filter's ``/attitude/<label>/estimate`` (q, P) against
the chosen reference channel ``/reference/<source>`` exactly as the replay's scorer does
(slerp at the step times, :func:`uavest.eval.attitude.rmse_deg` /
:func:`~uavest.eval.attitude.nees_attitude`), NIS from ``/attitude/<label>/health``;
radar runs score ``/tracks/<label>/state`` against ``/radar/truth/state`` with GOSPA and
the track-quality counts of :mod:`uavest.eval.tracking`.

Figures (``<figure class="report-figure" id="fig-...">`` in the HTML): see
:data:`ATTITUDE_FIGURES` / :data:`RADAR_FIGURES`. Each estimator has one colour
(:func:`uavest.layouts.colour`) in every figure; the reference/truth is black.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path

import numpy as np

from ..layouts import REFERENCE_COLOUR, colour
from ..sinks.foxglove import b64_floats, triu_to_full
from .read import Recording, read_recording

Array = np.ndarray

__all__ = ["ATTITUDE_FIGURES", "RADAR_FIGURES", "STATE_FIGURES", "attitude_data",
           "state_data", "state_metrics", "write_report"]

#: Figure ids of an attitude report, in page order.
ATTITUDE_FIGURES = ("fig-attitude", "fig-errors", "fig-nees", "fig-nis", "fig-trajectory",
                    "fig-timing", "fig-resets")
#: Figure ids of a radar report, in page order.
RADAR_FIGURES = ("fig-tracks-top", "fig-gospa", "fig-track-count", "fig-timing",
                 "fig-resets")

#: Figure ids of a generic vector-state report (``uavest bench --mcap``), in page order.
STATE_FIGURES = ("fig-state", "fig-errors", "fig-nees", "fig-nis", "fig-timing",
                 "fig-resets")

_AX = ("roll", "pitch", "yaw")


# ------------------------------------------------------------------------------- data


def _labels(rec: Recording, kind: str) -> list[str]:
    if kind == "attitude":
        found = [t.split("/")[2] for t in rec.topics("/attitude/", "/estimate")]
    else:
        found = [t.split("/")[2] for t in rec.topics("/tracks/", "/state")]
    info = rec.json.get("/run/info") or [{}]
    order = list(info[0].get("filters") or rec.metadata.get("filters", {}))
    return [lab for lab in order if lab in found] + [lab for lab in found if lab not in order]


def _stack(msgs: list[dict], key: str, width: int | None = None) -> Array:
    """Field ``key`` of every message as floats (None -> NaN): (K,) or (K, width)."""
    if width is None:
        return np.array([np.nan if m.get(key) is None else m[key] for m in msgs], float)
    return np.array([[np.nan if v is None else v for v in (m.get(key) or [None] * width)]
                     for m in msgs], float).reshape(len(msgs), width)


def _triu_of(m: dict) -> list:
    """The covariance triangle of an estimate message: ``P_triu`` (protobuf, channel set
    2) or ``P_triu_b64`` (JSON, channel set 1); None (NaN) where a value is missing."""
    v = m.get("P_triu")
    if v is None:
        v = b64_floats(m["P_triu_b64"]).tolist() if "P_triu_b64" in m else [None] * 21
    return [math.nan if x is None else x for x in v]


def attitude_data(rec: Recording) -> dict:
    """Per-filter arrays from the recording: ``t`` (K,) s, ``q`` (K, 4), ``P`` (K, 6, 6),
    ``nis`` (K,), ``nis_dof`` (K,), ``reset`` (K,), ``resets`` (K,), ``wall_us`` (K,); and
    the references ``refs[source] = (kind, t, q)``."""
    out: dict = {"filters": {}, "refs": {}, "positions": {}}
    for lab in _labels(rec, "attitude"):
        est = rec.json.get(f"/attitude/{lab}/estimate", [])
        hl = rec.json.get(f"/attitude/{lab}/health", [])
        n = min(len(est), len(hl))
        est, hl = est[:n], hl[:n]
        tri = np.array([_triu_of(m) for m in est], float).reshape(n, -1)
        d = int(round((math.sqrt(8 * tri.shape[1] + 1) - 1) / 2)) if n else 6
        P = triu_to_full(tri, d)  # 6x6 attitude, 15x15 navigation (tangent order)
        out["filters"][lab] = {
            "t": _stack(est, "t"), "k": _stack(est, "k"), "q": _stack(est, "q", 4),
            "P": P, "nis": _stack(hl, "nis"), "nis_dof": _stack(hl, "nis_dof"),
            "reset": np.array([bool(m.get("reset")) for m in hl]),
            "resets": _stack(hl, "resets"), "wall_us": _stack(hl, "wall_us"),
        }
    out["nav"] = navigation_data(rec)
    for topic in rec.topics("/reference/"):
        msgs = rec.json.get(topic, [])
        if msgs:
            out["refs"][topic.split("/", 2)[2]] = (
                msgs[0]["kind"], _stack(msgs, "t"), _stack(msgs, "q", 4))
    for topic in rec.topics("/position/"):
        msgs = [m for m in rec.json.get(topic, []) if m.get("ned_m")]
        if msgs:
            out["positions"][topic.split("/", 2)[2]] = (_stack(msgs, "t"),
                                                       _stack(msgs, "ned_m", 3))
    if not out["positions"]:  # only lat/lon/alt (a live link's GLOBAL_POSITION_INT)
        fixes = {}
        for topic in rec.topics("/position/"):
            msgs = [m for m in rec.json.get(topic, []) if m.get("lat_lon_alt")
                    and None not in m["lat_lon_alt"]]
            if msgs:
                fixes[topic.split("/", 2)[2]] = (_stack(msgs, "t"),
                                                 _stack(msgs, "lat_lon_alt", 3))
        # one origin for every source: the earliest fix of the preferred one
        order = sorted(fixes, key=lambda src: (_LLA_ORDER.index(src) if src in _LLA_ORDER
                                               else len(_LLA_ORDER), src))
        origin = fixes[order[0]][1][0] if order else None
        for src in order:
            t, lla = fixes[src]
            out["positions"][src + " (lat/lon/alt)"] = (t, lla_to_local_ned(lla, origin))
    return out


#: The raw GNSS sources, whose first fix is the navigation model's local origin.
_RAW_GNSS = ("GPS_RAW_INT", "GPS2_RAW", "GPS_INPUT", "GPS", "vehicle_gps_position",
             "sensor_gps")


def navigation_data(rec: Recording) -> dict:
    """The navigation model's channels (``/navigation/<label>/estimate``): per label ``t``
    (K,) s, ``v``, ``p`` (K, 3) NED m/s and m, ``s3v``, ``s3p`` (K, 3) their 3-sigma; and
    ``ref``: (source, t, v (K, 3) m/s, p (K, 3) m or None) from the recorded source with
    velocities that the replay's scorer would take
    (:func:`uavest.eval.navigation.choose_position_ref`: a simulator's truth, else the
    autopilot's fused solution, never a measurement), its position in the local NED
    frame at the first raw GNSS fix (the model's origin; the run's ``/navigation/anchor``
    when recorded); and
    ``pos_from``, the time (s) from which positions are in that frame (None: all).
    Empty without navigation channels."""
    out: dict = {"filters": {}, "ref": None}
    for topic in rec.topics("/navigation/"):
        msgs = rec.json.get(topic, [])
        if not msgs or not topic.endswith("/estimate"):
            continue
        out["filters"][topic.split("/")[2]] = {
            "t": _stack(msgs, "t"), "v": _stack(msgs, "velocity_ned_m_s", 3),
            "p": _stack(msgs, "position_ned_m", 3),
            "s3v": _stack(msgs, "sigma3_velocity_m_s", 3),
            "s3p": _stack(msgs, "sigma3_position_m", 3)}
    if not out["filters"]:
        return out
    origin, out["pos_from"], out["geodesy"] = _nav_anchor(rec)
    from ..eval.navigation import choose_position_ref

    with_vel = {}
    for topic in rec.topics("/position/"):
        msgs = [m for m in rec.json.get(topic, []) if m.get("vel_ned_m_s")
                and None not in m["vel_ned_m_s"]]
        if msgs:
            with_vel[topic.split("/", 2)[2]] = msgs
    src = choose_position_ref(list(with_vel))
    if src is not None:
        msgs = with_vel[src]
        lla = [m.get("lat_lon_alt") for m in msgs]
        p = (lla_to_local_ned(np.array(lla, float), origin, out["geodesy"])
             if origin is not None and all(x and None not in x for x in lla) else None)
        out["ref"] = (src, _stack(msgs, "t"), _stack(msgs, "vel_ned_m_s", 3), p)
        out["ref_lla"] = np.array(lla, float) if p is not None else None
    out["origin"] = origin
    return out


def _nav_anchor(rec: Recording) -> tuple[Array | None, float | None, str]:
    """The navigation frame's origin [lat deg, lon deg, alt m], the time (s) from which
    positions are in it and its geodesy: the run's own ``/navigation/anchor`` (its last),
    else (a recording without that channel) the first raw GNSS fix, no time, WGS84."""
    anchors = [m for m in rec.json.get("/navigation/anchor", [])
               if m.get("lat_lon_alt") and None not in m["lat_lon_alt"]]
    if anchors:
        a = anchors[-1]
        return np.array(a["lat_lon_alt"], float), float(a["t"]), a.get("geodesy", "wgs84")
    for src in _RAW_GNSS:
        fix = [m for m in rec.json.get(f"/position/{src}", []) if m.get("lat_lon_alt")
               and None not in m["lat_lon_alt"]]
        if fix:
            return np.array(fix[0]["lat_lon_alt"], float), None, "wgs84"
    return None, None, "wgs84"


def navigation_metrics(nav: dict, att: dict) -> dict:
    """Per label the velocity and position errors against ``nav["ref"]`` for the figure:
    ``ev`` (K, 3) m/s, ``ep`` (K, 3) m, the reference interpolated at the step times by
    the scorer's own :func:`uavest.eval.navigation.interp_reference`, NaN at the steps
    the scores leave out (outside the reference's span, or in a reference gap longer
    than ``MAX_REF_GAP_S``); and the replay's own scores
    (:class:`uavest.eval.navigation.NavScorer` over the recorded states, ``att`` the
    attitude filters of :func:`attitude_data` for ``q`` and the full P): ``vel_rmse_ms``,
    ``hpos_rmse_m``, ``vpos_rmse_m`` and the share of steps in the 95 % NEES band per
    block (``nees_vel_in95``, ``nees_pos_in95``)."""
    from ..eval.navigation import NavScorer, interp_reference
    from ..geometry.geodesy import make_frame

    out: dict = {}
    if nav["ref"] is None:
        return out
    src, tr, vr, pr = nav["ref"]
    origin = nav.get("origin")
    for lab, f in nav["filters"].items():
        t = f["t"]
        v_ref, ok_v = interp_reference(tr, vr, t)
        m: dict = {"t": t, "ev": np.where(ok_v[:, None], f["v"] - v_ref, np.nan)}
        if pr is not None:
            p_ref, ok_p = interp_reference(tr, pr, t)
            if nav.get("pos_from") is not None:  # before it the positions are in no frame
                ok_p = ok_p & (t >= nav["pos_from"])
            m["ep"] = np.where(ok_p[:, None], f["p"] - p_ref, np.nan)
        a = att.get(lab)
        if a is not None and len(a["t"]) == len(t) and a["P"].shape[1] >= 15:
            sc = NavScorer()
            sc.pos_from = nav.get("pos_from")
            x = np.zeros(16)
            for k in range(len(t)):
                x[:4], x[4:7], x[7:10] = a["q"][k], f["v"][k], f["p"][k]
                sc.add_estimate(lab, float(t[k]), x, a["P"][k])
            for k in range(len(tr)):
                sc.add_position(src, float(tr[k]), None, vr[k], nav["ref_lla"][k]
                                if nav.get("ref_lla") is not None else None)
            r = sc.scores(lab, None, None if origin is None
                          else make_frame(*origin, nav.get("geodesy", "wgs84")))
            for key in ("vel_rmse_ms", "hpos_rmse_m", "vpos_rmse_m"):
                if r.get(key) is not None:
                    m[key] = r[key]
            for blk, key in (("velocity", "nees_vel_in95"), ("position", "nees_pos_in95")):
                b = r.get("nees", {}).get(blk)
                if b and b.get("in_band95") is not None:
                    m[key] = b["in_band95"]
        out[lab] = m
    return out


def _navigation_fig(nav: dict, nm: dict) -> tuple:
    """Velocity and position errors (N, E, D) of every navigation filter against the
    reference, with each filter's own +-3 sigma (dashed)."""
    plt = _plt()
    src = nav["ref"][0]
    fig, axs = plt.subplots(3, 2, figsize=(14, 8.5), sharex=True)
    for lab, m in nm.items():
        f = nav["filters"][lab]
        for j, (key, s3, unit) in enumerate((("ev", "s3v", "m/s"), ("ep", "s3p", "m"))):
            if key not in m:
                continue
            for i in range(3):
                ax = axs[i, j]
                ax.plot(m["t"], m[key][:, i], color=colour(lab), lw=0.9,
                        label=lab if i == 0 else None)
                ax.plot(m["t"], f[s3][:, i], color=colour(lab), lw=0.7, ls="--")
                ax.plot(m["t"], -f[s3][:, i], color=colour(lab), lw=0.7, ls="--")
                ax.set_ylabel(f"{'NED'[i]} {'velocity' if j == 0 else 'position'} "
                              f"error ({unit})")
                ax.grid(alpha=0.3)
    axs[0, 0].legend(loc="upper right", fontsize=8)
    axs[-1, 0].set_xlabel("time t (s)")
    axs[-1, 1].set_xlabel("time t (s)")
    fig.suptitle(f"Navigation errors vs {src} with each filter's own +-3 sigma (dashed)")
    return ("fig-navigation", "Velocity and position errors", _fig_png(fig),
            f"Velocity (left) and position (right) error of each filter against {src} "
            "(interpolated to the step time as the scores are, steps in a reference gap "
            "left out; position in the local NED frame at the first raw GNSS fix, the "
            "model's origin) and the filter's own +-3 sigma.")


#: Preference among lat/lon/alt sources for the origin of the trajectory (the fused
#: position before the raw GPS).
_LLA_ORDER = ("GLOBAL_POSITION_INT", "vehicle_global_position", "POS", "GPS_RAW_INT",
              "GPS", "vehicle_gps_position")


def lla_to_local_ned(lla: Array, origin: Array | None = None, geodesy: str = "wgs84"
                     ) -> Array:
    """NED (K, 3) m of fixes ``lla`` (K, 3) [lat deg, lon deg, alt m] in the local
    tangent plane at ``origin`` [lat deg, lon deg, alt m] (default: the first fix), WGS84
    through ECEF (:class:`uavest.geometry.geodesy.LocalFrame`; the altitude is taken as the
    ellipsoidal height, which moves only the origin's height), or with ``geodesy``
    "sphere" ArduPilot's scaling (:class:`~uavest.geometry.geodesy.SphereFrame`). A
    tangent plane, not a map projection: fine for a flight of a few km (at a distance d
    the plane's "down" is d^2 / (2 R) below the sphere, 0.08 m at 1 km, 8 m at 10 km)."""
    from ..geometry.geodesy import make_frame

    lla = np.asarray(lla, float).reshape(-1, 3)
    if not len(lla):
        return np.zeros((0, 3))
    o = lla[0] if origin is None else np.asarray(origin, float)
    return make_frame(*o, geodesy).geodetic_to_ned(lla[:, 0], lla[:, 1], lla[:, 2])


class _Ref:
    def __init__(self, kind, t):
        self.kind, self.t = kind, t

    def __len__(self):
        return len(self.t)


def attitude_metrics(data: dict) -> tuple[dict, dict]:
    """(rows per filter, per-step series per filter) recomputed from the recording."""
    from ..eval.attitude import euler_errors_deg, nees_attitude, rmse_deg, select_reference
    from ..geometry.rotation import quat_slerp_interp, quat_to_euler
    from ..sinks.foxglove import euler_sigma_deg

    refs = data["refs"]
    ref, _ = select_reference({k: _Ref(v[0], v[1]) for k, v in refs.items()})
    rows, series = {}, {}
    for lab, f in data["filters"].items():
        row: dict = {"steps": int(len(f["t"]))}
        s: dict = {"t": f["t"], "rpy": np.degrees(quat_to_euler(f["q"])) if len(f["t"])
                   else np.zeros((0, 3))}
        if ref is not None and len(f["t"]):
            kind, tr, qr = refs[ref]
            q_ref, mask = quat_slerp_interp(tr, qr, f["t"])
            row.update(rmse_deg(f["q"], q_ref, mask))
            s["mask"] = mask
            s["err"] = euler_errors_deg(f["q"], q_ref)
            s["sig3"] = 3.0 * euler_sigma_deg(f["q"], f["P"])
            if kind == "truth" and mask.any():
                ne = np.full(len(f["t"]), np.nan)
                ne[mask] = nees_attitude(f["q"][mask], f["P"][mask], q_ref[mask])
                s["nees"] = ne
                row["nees_mean"] = float(np.nanmean(ne))
                row["frac_in_3sigma"] = float(np.mean(np.all(
                    np.abs(s["err"][mask]) <= s["sig3"][mask], axis=1)))
        nis = f["nis"]
        ok = np.isfinite(nis)
        if ok.any():
            row["nis_mean"] = float(np.mean(nis[ok]))
            row["nis_dof_mean"] = float(np.mean(f["nis_dof"][ok]))
        row["resets"] = int(np.nanmax(f["resets"])) if len(f["resets"]) else 0
        row["us_per_step"] = float(np.nanmean(f["wall_us"])) if len(f["wall_us"]) else math.nan
        rows[lab] = row
        series[lab] = s
    navm = navigation_metrics(data["nav"], data["filters"]) if data.get("nav") else {}
    for lab, nm in navm.items():
        if lab in rows:
            rows[lab].update({k: nm[k] for k in ("vel_rmse_ms", "hpos_rmse_m", "vpos_rmse_m",
                                                 "nees_vel_in95", "nees_pos_in95") if k in nm})
    return rows, {"series": series, "reference": ref,
                  "reference_kind": refs[ref][0] if ref else None, "navigation": navm}


def _moving_mean(x: Array, w: int) -> Array:
    """Mean over the last ``w`` finite samples' window (NaN-aware), same length as x."""
    ok = np.isfinite(x)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, x, 0.0))])
    n = np.concatenate([[0], np.cumsum(ok)])
    i = np.arange(1, len(x) + 1)
    j = np.maximum(i - w, 0)
    cnt = n[i] - n[j]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, (c[i] - c[j]) / np.maximum(cnt, 1), np.nan)


# ------------------------------------------------------------------- generic states


def state_data(rec: Recording) -> dict:
    """Generic vector-state runs (``uavest bench --mcap``): per filter ``t`` (K,), ``k``
    (K,), ``x`` (K, n), ``P`` (K, n, n), ``nis``, ``nis_dof``, ``resets``, ``wall_us``
    (K,); the truth ``truth = (t, k, x (T, n))`` from ``/truth/state`` (or None) and the
    measurements ``meas = (t, z (T, m))`` from ``/measurement/z`` (or None)."""
    out: dict = {"filters": {}, "truth": None, "meas": None}
    labels = [t.split("/")[2] for t in rec.topics("/state/", "/estimate")]
    info = rec.json.get("/run/info") or [{}]
    order = list(info[0].get("filters") or rec.metadata.get("filters", {}))
    labels = [lab for lab in order if lab in labels] + [lab for lab in labels
                                                        if lab not in order]
    for lab in labels:
        est = rec.json.get(f"/state/{lab}/estimate", [])
        hl = rec.json.get(f"/state/{lab}/health", [])
        m = min(len(est), len(hl))
        est, hl = est[:m], hl[:m]
        n = int(est[0]["n"]) if est else 0
        out["filters"][lab] = {
            "t": _stack(est, "t"), "k": _stack(est, "k"), "x": _stack(est, "x", n),
            "P": _stack(est, "P", n * n).reshape(m, n, n),
            "nis": _stack(hl, "nis"), "nis_dof": _stack(hl, "nis_dof"),
            "resets": _stack(hl, "resets"), "wall_us": _stack(hl, "wall_us")}
    tr = rec.json.get("/truth/state", [])
    if tr:
        n = len(tr[0]["x"])
        out["truth"] = (_stack(tr, "t"), _stack(tr, "k"), _stack(tr, "x", n))
    zm = rec.json.get("/measurement/z", [])
    if zm:
        out["meas"] = (_stack(zm, "t"), _stack(zm, "z", len(zm[0]["z"])))
    return out


def state_metrics(data: dict) -> tuple[dict, dict]:
    """(rows per filter, per-step series) of a generic-state recording, recomputed from
    the file: the estimates matched to the truth by step number k, error e = estimate -
    truth, ``rmse`` = sqrt(mean_k ||e_k||^2) (as the Monte Carlo trial's), per-component
    RMSE ``rmse_x<i>``, ``nees_mean`` (e^T P^-1 e, n dof), ``frac_in_3sigma`` (steps with
    every |e_i| <= 3 sqrt(P_ii)), mean NIS and its dof, resets, us per step."""
    from ..eval.metrics import nees, rmse

    rows, series = {}, {}
    truth = data["truth"]
    by_k = ({int(k): i for i, k in enumerate(truth[1])} if truth is not None else {})
    for lab, f in data["filters"].items():
        row: dict = {"steps": int(len(f["t"]))}
        s: dict = {"t": f["t"]}
        n = f["x"].shape[1] if f["x"].ndim == 2 else 0
        idx = np.array([by_k.get(int(k), -1) for k in f["k"]], int)
        mk = idx >= 0
        if truth is not None and mk.any() and truth[2].shape[1] == n:
            e = np.full_like(f["x"], np.nan)
            e[mk] = f["x"][mk] - truth[2][idx[mk]]
            with np.errstate(invalid="ignore"):
                sig3 = 3.0 * np.sqrt(np.einsum("kii->ki", f["P"]))
            ne = np.full(len(f["t"]), np.nan)
            ne[mk] = nees(e[mk], f["P"][mk])
            s.update(mask=mk, err=e, sig3=sig3, nees=ne)
            row["rmse"] = rmse(e[mk])
            for i in range(n):
                row[f"rmse_x{i}"] = float(np.sqrt(np.mean(e[mk, i] ** 2)))
            row["nees_mean"] = float(np.mean(ne[mk]))
            row["nees_dof"] = n
            row["frac_in_3sigma"] = float(np.mean(np.all(np.abs(e[mk]) <= sig3[mk], axis=1)))
        ok = np.isfinite(f["nis"])
        if ok.any():
            row["nis_mean"] = float(np.mean(f["nis"][ok]))
            row["nis_dof_mean"] = float(np.mean(f["nis_dof"][ok]))
        row["resets"] = int(np.nanmax(f["resets"])) if len(f["resets"]) else 0
        row["us_per_step"] = float(np.nanmean(f["wall_us"])) if len(f["wall_us"]) else math.nan
        rows[lab] = row
        series[lab] = s
    return rows, {"series": series}


def _error_axes(axs, S: dict, legend, ylabel) -> None:
    """Each filter's error per axis (solid) with its own +-3 sigma (dashed), one colour
    per filter; ``legend(lab, i)`` the error's legend text, ``ylabel(i)`` the axis label;
    y limits at 3x the 99.5th percentile of |error| over the filters."""
    for lab, s in S.items():
        if "err" not in s:
            continue
        mk, c = s["mask"], colour(lab)
        for i, ax in enumerate(axs):
            t = s["t"][mk]
            ax.plot(t, s["err"][mk, i], color=c, lw=0.9, label=legend(lab, i))
            ax.plot(t, s["sig3"][mk, i], color=c, lw=0.8, ls="--")
            ax.plot(t, -s["sig3"][mk, i], color=c, lw=0.8, ls="--",
                    label=f"{lab} +-3 sigma" if i == 0 else None)
    for i, ax in enumerate(axs):
        ax.set_ylabel(ylabel(i))
        ax.grid(alpha=0.3)
        lim = [np.nanpercentile(np.abs(s["err"][s["mask"], i]), 99.5) * 3
               for s in S.values() if "err" in s and s["mask"].any()]
        if lim and np.isfinite(max(lim)) and max(lim) > 0:
            ax.set_ylim(-max(lim), max(lim))
        ax.legend(loc="upper right", fontsize=7, ncol=3)


def _state_figures(data: dict, rows: dict, m: dict, events: list) -> list[tuple]:
    """The figures of a generic-state report in :data:`STATE_FIGURES` order (the first
    six state components drawn)."""
    S = m["series"]
    n = max((f["x"].shape[1] for f in data["filters"].values() if f["x"].ndim == 2),
            default=1)
    nc = max(1, min(n, 6))  # components drawn
    return [_state_fig(data, nc), _state_errors_fig(S, rows, nc), _state_nees_fig(S, rows, n),
            _state_nis_fig(data, rows),
            _timing_fig({lab: (f["t"], f["wall_us"]) for lab, f in data["filters"].items()},
                        "filter step"),
            _resets_fig({lab: (f["t"], f["resets"]) for lab, f in data["filters"].items()},
                        events)]


def _state_fig(data: dict, nc: int) -> tuple:
    """The first ``nc`` state components of every filter's estimate and of the truth
    (black) over time."""
    plt = _plt()
    truth = data["truth"]
    fig, axs = plt.subplots(nc, 1, figsize=(12, 2.6 * nc + 1), sharex=True, squeeze=False)
    axs = axs[:, 0]
    for i, ax in enumerate(axs):
        if truth is not None:
            ax.plot(truth[0], truth[2][:, i], color=REFERENCE_COLOUR, lw=1.4, label="truth")
        for lab, f in data["filters"].items():
            ax.plot(f["t"], f["x"][:, i], color=colour(lab), lw=0.9, label=lab)
        ax.set_ylabel(f"x[{i}]")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="upper right", fontsize=8, ncol=4)
    axs[-1].set_xlabel("time t (s)")
    fig.suptitle("State of every filter and the truth (black)")
    return ("fig-state", "State", _fig_png(fig),
            "Each state component of every filter's estimate and the truth.")


def _state_errors_fig(S: dict, rows: dict, nc: int) -> tuple:
    """Error (estimate - truth) of the first ``nc`` components with each filter's own
    +-3 sqrt(P_ii)."""
    plt = _plt()
    fig, axs = plt.subplots(nc, 1, figsize=(12, 2.8 * nc + 1), sharex=True, squeeze=False)
    axs = axs[:, 0]
    _error_axes(axs, S, lambda lab, i: f"{lab} error (RMSE "
                f"{rows[lab].get(f'rmse_x{i}', math.nan):.3g})", lambda i: f"x[{i}] error")
    axs[-1].set_xlabel("time t (s)")
    fig.suptitle("Error (estimate - truth) per component with each filter's own +-3 sigma "
                 "(dashed)")
    return ("fig-errors", "Errors with +-3 sigma", _fig_png(fig),
            "Per-component error (solid) and the filter's own +-3 sqrt(P_ii) "
            "(dashed).")


def _state_nees_fig(S: dict, rows: dict, n: int) -> tuple:
    """NEES per step against the truth (``n`` dof) with the chi-square 95 % band of one
    step."""
    from scipy.stats import chi2

    plt = _plt()
    fig, ax = plt.subplots(figsize=(12, 4))
    have = False
    for lab, s in S.items():
        if "nees" in s:
            have = True
            ax.plot(s["t"], s["nees"], ".-", ms=3, lw=0.6, color=colour(lab),
                    label=f"{lab} (mean {rows[lab]['nees_mean']:.3g})")
    if have:
        lo, hi = chi2.ppf([0.025, 0.975], n)
        ax.axhspan(lo, hi, color="grey", alpha=0.2,
                   label=f"95% chi-square band of one step ({n} dof)")
        ax.axhline(float(n), color="k", lw=0.8, ls=":", label=f"expected {n}")
        ax.set_yscale("log")
        ax.legend(loc="upper right", fontsize=8)
    else:
        ax.text(0.5, 0.5, "no truth in this recording: NEES needs truth", ha="center",
                va="center", transform=ax.transAxes)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel(f"NEES ({n} dof)")
    ax.grid(alpha=0.3)
    ax.set_title("NEES per step against the truth, with the chi-square 95% band")
    return ("fig-nees", "NEES", _fig_png(fig),
            f"NEES e^T P^-1 e per step ({n} dof) and the 95% band of one step.")


def _state_nis_fig(data: dict, rows: dict) -> tuple:
    """NIS of every filter's updates per step with the chi-square 95 % band at their mean
    dof."""
    from scipy.stats import chi2

    plt = _plt()
    fig, ax = plt.subplots(figsize=(12, 4))
    dofm = []
    for lab, f in data["filters"].items():
        nis, dof = f["nis"], f["nis_dof"]
        ok = np.isfinite(nis) & (dof > 0)
        if ok.any():
            ax.plot(f["t"], np.where(ok, nis, np.nan), ".-", ms=3, lw=0.6, color=colour(lab),
                    label=f"{lab} (mean {rows[lab]['nis_mean']:.3g})")
            dofm.append(float(np.mean(dof[ok])))
    if dofm:
        dm = float(np.mean(dofm))
        lo, hi = chi2.ppf([0.025, 0.975], dm)
        ax.axhspan(lo, hi, color="grey", alpha=0.2, label=f"95% band ({dm:g} dof)")
        ax.set_yscale("log")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("NIS")
    ax.grid(alpha=0.3)
    ax.set_title("NIS of each step's update with the chi-square band")
    return ("fig-nis", "NIS", _fig_png(fig), "Normalised innovation squared per step.")


# ------------------------------------------------------------------------------ radar


def radar_data(rec: Recording) -> dict:
    """Per scan: truths {id: x}, per tracker the tracks, detections (world ENU)."""
    truth = {m["k"]: (m["t"], {int(g["id"]): np.array(g["x"], float) for g in m["targets"]})
             for m in rec.json.get("/radar/truth/state", [])}
    scans = rec.json.get("/radar/scan", [])
    det = np.array([p for m in scans for p in m.get("xyz", [])], float).reshape(-1, 3)
    trackers = {}
    for lab in _labels(rec, "radar"):
        trackers[lab] = rec.json.get(f"/tracks/{lab}/state", [])
    return {"truth": truth, "detections": det, "trackers": trackers}


def radar_metrics(data: dict, c: float = 100.0) -> tuple[dict, dict]:
    from ..eval.tracking import gospa, track_quality

    rows, series = {}, {}
    truth = data["truth"]
    for lab, msgs in data["trackers"].items():
        t = np.array([m["t"] for m in msgs], float)
        ks = [m["k"] for m in msgs]
        d = None
        tr_steps, tk_steps, g = [], [], []
        for m in msgs:
            conf = {int(x["id"]): np.array(x["x"], float) for x in m["tracks"] if x["confirmed"]}
            tv = truth.get(m["k"], (None, {}))[1]
            if d is None:
                any_x = next(iter(conf.values()), None)
                any_t = next(iter(tv.values()), None)
                v = any_x if any_x is not None else any_t
                if v is not None:
                    d = 3 if v.size >= 6 else 2
            dd = d or 2
            tr_steps.append({i: x[:dd] for i, x in tv.items()})
            tk_steps.append({i: x[:dd] for i, x in conf.items()})
            if truth:
                X = np.array(list(tr_steps[-1].values())).reshape(-1, dd)
                Y = np.array(list(tk_steps[-1].values())).reshape(-1, dd)
                g.append(gospa(X, Y, c)[0])
        row: dict = {"scans": len(msgs),
                     "confirmed_mean": float(np.mean([len(s) for s in tk_steps]))
                     if tk_steps else 0.0,
                     "resets": int(sum(m.get("resets", 0) for m in msgs)),
                     "us_per_scan": float(np.mean([m["wall_us"] for m in msgs]))
                     if msgs else math.nan}
        if truth and msgs:
            dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
            q = track_quality(tr_steps, tk_steps, c, dt=dt)
            row.update({"gospa_mean": q.gospa, "track_breaks": q.track_breaks,
                        "id_swaps": q.id_swaps, "false_tracks": q.false_tracks,
                        "tracks_confirmed_total": q.confirmed_tracks,
                        "time_to_confirm_s": q.time_to_confirm})
        rows[lab] = row
        series[lab] = {"t": t, "k": ks, "gospa": np.array(g, float),
                       "n_conf": np.array([len(s) for s in tk_steps]),
                       "n_truth": np.array([len(s) for s in tr_steps]),
                       "wall_us": np.array([m["wall_us"] for m in msgs], float),
                       "resets": np.cumsum([m.get("resets", 0) for m in msgs]),
                       "msgs": msgs}
    return rows, {"series": series, "gospa_c": c}


# ---------------------------------------------------------------------------- figures


def _fig_png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return buf.getvalue()


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _attitude_figures(data: dict, rows: dict, m: dict, events: list) -> list[tuple]:
    """The figures of an attitude report in :data:`ATTITUDE_FIGURES` order (the
    navigation errors after the trajectory when the recording has navigation channels)."""
    S = m["series"]
    dt = _dt(S)
    w = max(1, int(round(1.0 / dt))) if dt else 1  # steps in the 1 s moving means
    figs = [_attitude_angles_fig(data, S, m["reference"]),
            _attitude_errors_fig(S, rows, m["reference"]),
            _attitude_nees_fig(S, rows, w),
            _attitude_nis_fig(data, rows, w),
            _trajectory_fig(data)]
    if m.get("navigation"):
        figs.append(_navigation_fig(data["nav"], m["navigation"]))
    figs.append(_timing_fig({lab: (f["t"], f["wall_us"]) for lab, f in data["filters"].items()},
                            "filter step"))
    figs.append(_resets_fig({lab: (f["t"], f["resets"]) for lab, f in data["filters"].items()},
                            events))
    return figs


def _attitude_angles_fig(data: dict, S: dict, ref: str | None) -> tuple:
    """Roll, pitch, yaw (deg, ZYX Euler of body FRD -> NED) of every filter and of the
    reference ``ref`` (black)."""
    plt = _plt()
    fig, axs = plt.subplots(3, 1, figsize=(12, 7.5), sharex=True)
    if ref:
        from ..geometry.rotation import quat_to_euler

        _, tr, qr = data["refs"][ref]
        rpy = np.degrees(quat_to_euler(qr))
        for i, ax in enumerate(axs):
            ax.plot(tr, rpy[:, i], color=REFERENCE_COLOUR, lw=1.2, label=f"reference {ref}")
    for lab, s in S.items():
        for i, ax in enumerate(axs):
            ax.plot(s["t"], s["rpy"][:, i], color=colour(lab), lw=0.9, label=lab)
    for i, ax in enumerate(axs):
        ax.set_ylabel(f"{_AX[i]} (deg)")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="upper right", fontsize=8, ncol=4)
    axs[-1].set_xlabel("time t (s, source clock)")
    fig.suptitle("Attitude (ZYX Euler, body FRD -> NED) of every filter and the reference")
    return ("fig-attitude", "Attitude", _fig_png(fig),
            "Roll, pitch, yaw of each filter and the reference (black).")


def _attitude_errors_fig(S: dict, rows: dict, ref: str | None) -> tuple:
    """Per-axis attitude error (deg, wrapped) against ``ref`` with each filter's own
    +-3 sigma."""
    plt = _plt()
    fig, axs = plt.subplots(3, 1, figsize=(12, 8.5), sharex=True)
    _error_axes(axs, S, lambda lab, i: f"{lab} error (RMSE "
                f"{rows[lab].get(_AX[i] + '_rmse_deg', math.nan):.2f})",
                lambda i: f"{_AX[i]} error (deg)")
    axs[-1].set_xlabel("time t (s)")
    fig.suptitle(f"Error vs {ref} (estimate - reference, wrapped) with each filter's own "
                 "+-3 sigma (dashed)")
    return ("fig-errors", "Errors with +-3 sigma", _fig_png(fig),
            "Per-axis error (solid) and the filter's own +-3 sigma bound (dashed, from "
            "its covariance, linearised to Euler angles).")


def _attitude_nees_fig(S: dict, rows: dict, w: int) -> tuple:
    """Attitude NEES (3 dof) per step against truth and its ``w``-step moving mean with
    the chi-square 95 % band of that mean."""
    from scipy.stats import chi2

    plt = _plt()
    fig, ax = plt.subplots(figsize=(12, 4))
    have = False
    for lab, s in S.items():
        if "nees" not in s:
            continue
        have = True
        ax.plot(s["t"], s["nees"], ".", ms=1.5, color=colour(lab), alpha=0.25)
        ax.plot(s["t"], _moving_mean(s["nees"], w), color=colour(lab), lw=1.2,
                label=f"{lab} ({w}-step mean; overall {rows[lab]['nees_mean']:.2f})")
    if have:
        lo, hi = chi2.ppf([0.025, 0.975], 3 * w) / w
        ax.axhspan(lo, hi, color="grey", alpha=0.2, label=f"95% band of a {w}-step mean")
        ax.axhline(3.0, color="k", lw=0.8, ls=":", label="expected 3")
        ax.set_yscale("log")
        ax.legend(loc="upper right", fontsize=8)
    else:
        ax.text(0.5, 0.5, "no truth reference in this recording: NEES needs truth",
                ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("attitude NEES (3 dof)")
    ax.grid(alpha=0.3)
    ax.set_title("NEES against truth: dots per step, lines the moving mean, band chi-square")
    return ("fig-nees", "NEES", _fig_png(fig),
            "Attitude NEES (3 dof) per step and its 1 s moving mean with the chi-square "
            "95% band of that mean.")


def _attitude_nis_fig(data: dict, rows: dict, w: int) -> tuple:
    """NIS / dof of every filter's updates, ``w``-step moving mean, with the chi-square
    95 % band of that mean."""
    from scipy.stats import chi2

    plt = _plt()
    fig, ax = plt.subplots(figsize=(12, 4))
    dofm = []
    for lab, f in data["filters"].items():
        nis, dof = f["nis"], f["nis_dof"]
        ok = np.isfinite(nis) & (dof > 0)
        if not ok.any():
            continue
        r = np.where(ok, nis / np.where(dof > 0, dof, 1), np.nan)
        ax.plot(f["t"], _moving_mean(r, w), color=colour(lab), lw=1.2,
                label=f"{lab} (mean NIS {rows[lab]['nis_mean']:.2f}, dof "
                      f"{rows[lab]['nis_dof_mean']:.1f})")
        dofm.append(float(np.mean(dof[ok])))
    if dofm:
        dm = float(np.mean(dofm))
        lo, hi = chi2.ppf([0.025, 0.975], dm * w) / (dm * w)
        ax.axhspan(lo, hi, color="grey", alpha=0.2, label=f"95% band ({w} steps x {dm:.1f} dof)")
        ax.axhline(1.0, color="k", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("NIS / dof (moving mean)")
    ax.grid(alpha=0.3)
    ax.set_title("NIS of the updates divided by their dof, with the chi-square band")
    return ("fig-nis", "NIS", _fig_png(fig),
            "Normalised innovation squared per degree of freedom (1 s moving mean).")


def _trajectory_fig(data: dict) -> tuple:
    """The vehicle's position sources, top view (east/north m in the local NED frame;
    from lat/lon/alt at the first fix when the recording has no NED position)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 7))
    if data["positions"]:
        styles = [(REFERENCE_COLOUR, "-", 1.2), ("#888888", "--", 0.9), ("#bbbbbb", ":", 0.9)]
        for j, (src, (_t, ned)) in enumerate(data["positions"].items()):
            col, ls, lw = styles[min(j, len(styles) - 1)]
            ax.plot(ned[:, 1], ned[:, 0], color=col, ls=ls, lw=lw, label=src)
            ax.plot(ned[:1, 1], ned[:1, 0], "o", color="g", label="start" if j == 0 else None)
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no position in this recording", ha="center", va="center",
                transform=ax.transAxes)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(alpha=0.3)
    from_lla = any(src.endswith("(lat/lon/alt)") for src in data["positions"])
    ax.set_title("Vehicle trajectory, top view (" + (
        "local NED at the first fix, from lat/lon/alt" if from_lla else "local NED origin")
        + ")")
    return ("fig-trajectory", "Trajectory", _fig_png(fig),
            "Vehicle position from the log (top view, east/north in m)" + (
                "; no local NED position was recorded, so the lat/lon/alt fixes are "
                "shown in the local tangent plane at the first fix (of the fused "
                "position when there is one), the same origin for every source"
                if from_lla
                else "") + ".")


def _dt(S: dict) -> float:
    for s in S.values():
        if len(s["t"]) > 1:
            return float(np.median(np.diff(s["t"])))
    return 0.0


def _timing_fig(series: dict, what: str) -> tuple:
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.8), gridspec_kw={"width_ratios": [3, 1]})
    for lab, (t, us) in series.items():
        if len(us) == 0:
            continue
        a1.plot(t, us, color=colour(lab), lw=0.6, alpha=0.8,
                label=f"{lab} (mean {np.nanmean(us):.0f} us)")
        a2.hist(us[np.isfinite(us)], bins=50, color=colour(lab), alpha=0.5, label=lab)
    a1.set_xlabel("time t (s)")
    a1.set_ylabel(f"wall time per {what} (us)")
    a1.set_yscale("log")
    a1.grid(alpha=0.3)
    a1.legend(fontsize=8)
    a2.set_xlabel("wall time (us)")
    a2.set_ylabel("count")
    a2.grid(alpha=0.3)
    fig.suptitle(f"Per-{what} wall time")
    return ("fig-timing", "Timing", _fig_png(fig), f"Wall time of each {what} (us).")


def _resets_fig(series: dict, events: list) -> tuple:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(12, 3.2))
    total = 0
    for lab, (t, r) in series.items():
        r = np.nan_to_num(np.asarray(r, float))
        total += int(r[-1]) if len(r) else 0
        ax.step(t, r, where="post", color=colour(lab), lw=1.5, label=lab)
    for ev in events:
        if ev["level"] >= 3:
            ax.axvline(ev["t"], color="r", lw=0.6, alpha=0.5)
    ax.set_ylim(-0.05, max(total, 1) * 1.15)
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("resets (cumulative)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"Filter resets (divergence guard, GNSS lock-out): {total} in total "
                 "(red lines: warnings in /log)")
    return ("fig-resets", "Resets", _fig_png(fig), "Cumulative resets per estimator.")


def _radar_figures(data: dict, rows: dict, m: dict, events: list) -> list[tuple]:
    plt = _plt()
    S = m["series"]
    figs = []
    fig, ax = plt.subplots(figsize=(9, 9))
    det = data["detections"]
    if len(det):
        ax.plot(det[:, 0], det[:, 1], ".", ms=2, color="#aaaaaa", label="detections")
    paths: dict[int, list] = {}
    for k in sorted(data["truth"]):
        for i, x in data["truth"][k][1].items():
            paths.setdefault(i, []).append(x[:2])
    for j, (i, p) in enumerate(sorted(paths.items())):
        p = np.array(p)
        ax.plot(p[:, 0], p[:, 1], color=REFERENCE_COLOUR, lw=2.2,
                label="truth" if j == 0 else None)
        ax.text(p[0, 0], p[0, 1], f"target {i}", fontsize=8)
    for lab, s in S.items():
        tp: dict[int, list] = {}
        for msg in s["msgs"]:
            for x in msg["tracks"]:
                if x["confirmed"]:
                    tp.setdefault(int(x["id"]), []).append(x["x"][:2])
        for j, (i, p) in enumerate(sorted(tp.items())):
            p = np.array(p)
            ax.plot(p[:, 0], p[:, 1], color=colour(lab), lw=1.0,
                    label=f"{lab} tracks" if j == 0 else None)
            ax.text(p[-1, 0], p[-1, 1], f"#{i}", color=colour(lab), fontsize=7)
    pts = [np.array(p)[:, :2] for p in paths.values()]
    if pts:  # zoom on the targets (clutter far away is cut off)
        a = np.vstack(pts)
        lo, hi = a.min(axis=0), a.max(axis=0)
        pad = 0.25 * max(float(np.max(hi - lo)), 500.0)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_xlabel("east (m, world ENU)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Confirmed tracks (per tracker) and truth, top view")
    figs.append(("fig-tracks-top", "Tracks, top view", _fig_png(fig),
                 "Truth paths (black), confirmed track paths with their ids (one colour per "
                 "tracker), detections (grey)."))
    fig, ax = plt.subplots(figsize=(12, 3.8))
    for lab, s in S.items():
        if len(s["gospa"]):
            ax.plot(s["t"], s["gospa"], color=colour(lab), lw=1.2,
                    label=f"{lab} (mean {rows[lab].get('gospa_mean', math.nan):.1f} m)")
    if not any(len(s["gospa"]) for s in S.values()):
        ax.text(0.5, 0.5, "no truth recorded", ha="center", va="center",
                transform=ax.transAxes)
    else:
        ax.legend(fontsize=8)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel(f"GOSPA (m, c = {m['gospa_c']:g})")
    ax.grid(alpha=0.3)
    ax.set_title("GOSPA of the confirmed tracks against the truth per scan")
    figs.append(("fig-gospa", "GOSPA", _fig_png(fig), "GOSPA per scan (m)."))
    fig, ax = plt.subplots(figsize=(12, 3.5))
    for j, (lab, s) in enumerate(S.items()):
        ax.step(s["t"], s["n_conf"], where="post", color=colour(lab), lw=1.3, label=lab)
        if j == 0 and data["truth"]:
            ax.step(s["t"], s["n_truth"], where="post", color=REFERENCE_COLOUR, lw=2,
                    ls="--", label="truth targets")
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("confirmed tracks")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Number of confirmed tracks vs the number of true targets")
    figs.append(("fig-track-count", "Track count", _fig_png(fig), "Confirmed tracks per scan."))
    figs.append(_timing_fig({lab: (s["t"], s["wall_us"]) for lab, s in S.items()}, "scan"))
    figs.append(_resets_fig({lab: (s["t"], s["resets"]) for lab, s in S.items()}, events))
    return figs


# ------------------------------------------------------------------------------ pages


def _events(rec: Recording) -> list[dict]:
    if "/log" not in rec.raw:
        return []
    out = []
    for m in rec.decode("/log"):
        ts = m.get("timestamp", {})
        out.append({"t": ts.get("seconds", 0) + 1e-9 * ts.get("nanos", 0),
                    "level": int(m.get("level", 0)), "name": m.get("name", ""),
                    "message": m.get("message", "")})
    return out


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if not math.isfinite(v):
            return "nan"
        return f"{v:.4g}" if abs(v) < 1e5 else f"{v:.3e}"
    return str(v)


def _table_md(rows: dict, cols: list[str]) -> str:
    head = "| filter | " + " | ".join(cols) + " |"
    sep = "|---|" + "---|" * len(cols)
    body = ["| " + lab + " | " + " | ".join(_fmt(r.get(c)) for c in cols) + " |"
            for lab, r in rows.items()]
    return "\n".join([head, sep] + body)


def _table_html(rows: dict, cols: list[str]) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    b = "".join(
        f"<tr><td style='color:{colour(lab)};font-weight:bold'>{html.escape(lab)}</td>"
        + "".join(f"<td>{_fmt(r.get(c))}</td>" for c in cols) + "</tr>"
        for lab, r in rows.items())
    return f"<table class='comparison'><tr><th>filter</th>{h}</tr>{b}</table>"


_CSS = """body{font-family:sans-serif;margin:2em;max-width:1400px}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;
text-align:right}th{background:#f3f3f3}figure{margin:1.5em 0}img{max-width:100%}
figcaption{color:#444;font-size:90%}.meta td{text-align:left}"""


def write_report(mcap_path: str | Path, out_dir: str | Path | None = None,
                 on_stage=None) -> dict[str, Path]:
    """Read the recording ``mcap_path``, recompute the metrics from it and write
    ``<out_dir>/<stem>.html`` (self-contained: figures as base64 PNG) and
    ``<out_dir>/<stem>.md`` (figures as ``<stem>_figures/<id>.png``). ``out_dir``
    defaults to the recording's directory. Returns ``{"html", "markdown", "metrics",
    "figures": [png paths]}``; ``metrics`` is ``<stem>.metrics.json``. ``on_stage(name)``
    is called as each stage starts (progress)."""
    stage = on_stage or (lambda name: None)
    mcap_path = Path(mcap_path)
    out = Path(out_dir) if out_dir is not None else mcap_path.parent
    out.mkdir(parents=True, exist_ok=True)
    stage(f"reading {mcap_path.name}")
    rec = read_recording(mcap_path)
    events = _events(rec)
    kinds = [k for k, topic in (("attitude", "/attitude/"), ("radar", "/tracks/"),
                                ("state", "/state/")) if rec.topics(topic)] or ["attitude"]
    kind = "+".join(kinds)  # a live run (uavest demo) records both
    sections = []  # (title, rows, cols)
    figs: list = []
    extra: dict = {}
    rows: dict = {}
    for kd in kinds:
        stage(f"{kd}: metrics and figures")
        make = {"attitude": _attitude_section, "state": _state_section}.get(kd, _radar_section)
        krows, cols, kf, kextra = make(rec, events, len(kinds) > 1)
        extra.update(kextra)
        sections.append((kd, krows, cols))
        figs += kf
        rows.update(krows)
    stage("writing HTML and Markdown")
    stem = mcap_path.stem
    figdir = out / f"{stem}_figures"
    figdir.mkdir(exist_ok=True)
    pngs = []
    for fid, _, png, _ in figs:
        p = figdir / f"{fid}.png"
        p.write_bytes(png)
        pngs.append(p)
    html_path = out / f"{stem}.html"
    html_path.write_text(_html_page(rec, mcap_path, kind, extra, sections, figs, events))
    md_path = out / f"{stem}.md"
    md_path.write_text(_markdown_page(rec, mcap_path, kind, extra, sections, figs, events,
                                      figdir.name))
    metrics_path = out / f"{stem}.metrics.json"
    metrics_path.write_text(json.dumps({"kind": kind, **extra, "filters": rows},
                                       indent=2, default=_jsonnum))
    return {"html": html_path, "markdown": md_path, "metrics": metrics_path, "figures": pngs}


def _attitude_section(rec: Recording, events: list, _multi: bool) -> tuple:
    """(rows, table columns, figures, page facts) of the attitude (and navigation)
    channels; the navigation columns only when the recording has navigation channels."""
    data = attitude_data(rec)
    rows, m = attitude_metrics(data)
    figs = _attitude_figures(data, rows, m, events)
    cols = ["roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "n", "nees_mean",
            "frac_in_3sigma", "nis_mean", "nis_dof_mean", "resets", "us_per_step"]
    if m["navigation"]:
        cols[5:5] = ["vel_rmse_ms", "hpos_rmse_m", "vpos_rmse_m", "nees_vel_in95",
                     "nees_pos_in95"]
    return rows, cols, figs, {"reference": m["reference"],
                              "reference_kind": m["reference_kind"]}


def _state_section(rec: Recording, events: list, _multi: bool) -> tuple:
    """(rows, table columns, figures, page facts) of a generic vector-state recording
    (``uavest bench --mcap``): per-component RMSE columns for up to six components, and
    the scenario and trial from the recording's config."""
    data = state_data(rec)
    rows, m = state_metrics(data)
    figs = _state_figures(data, rows, m, events)
    n = max((r.get("nees_dof", 0) for r in rows.values()), default=0)
    cols = (["rmse"] + [f"rmse_x{i}" for i in range(min(n, 6))]
            + ["nees_mean", "nees_dof", "frac_in_3sigma", "nis_mean", "nis_dof_mean",
               "resets", "us_per_step", "steps"])
    cfg = rec.metadata.get("config", {})
    return rows, cols, figs, {k: json.loads(cfg[k]) for k in ("scenario", "trial") if k in cfg}


def _radar_gospa_c(cfg: dict) -> float:
    """The GOSPA cut-off c (m) of the run from the recording's config (``gospa_c``, or
    ``metrics`` as a number or a dict with ``gospa_c``); 100 m when it has none."""
    c = 100.0
    for key in ("gospa_c", "metrics"):
        if key in cfg:
            try:
                v = json.loads(cfg[key])
                c = float(v["gospa_c"] if isinstance(v, dict) else v)
            except (ValueError, KeyError, TypeError):
                pass
    return c


def _radar_section(rec: Recording, events: list, multi: bool) -> tuple:
    """(rows, table columns, figures, page facts) of the radar tracker channels; with
    ``multi`` (another kind on the same page) the figure ids are prefixed ``radar-`` to
    stay unique."""
    data = radar_data(rec)
    c = _radar_gospa_c(rec.metadata.get("config", {}))
    rows, m = radar_metrics(data, c)
    figs = _radar_figures(data, rows, m, events)
    if multi:  # ids unique on the page: the radar's timing, resets...
        figs = [(f"radar-{fid}", t, png, cap) for fid, t, png, cap in figs]
    cols = ["gospa_mean", "tracks_confirmed_total", "false_tracks", "track_breaks",
            "id_swaps", "time_to_confirm_s", "confirmed_mean", "resets",
            "us_per_scan", "scans"]
    return rows, cols, figs, {"gospa_c": c}


def _html_page(rec: Recording, mcap_path: Path, kind: str, extra: dict, sections: list,
               figs: list, events: list) -> str:
    """The self-contained HTML page: the run facts, a comparison table per section, the
    figures as base64 PNG and the /log events."""
    stem = mcap_path.stem
    run = rec.metadata.get("run", {})
    meta_rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(str(v))}</td></tr>"
                        for k, v in [("recording", mcap_path.name), ("kind", kind),
                                     *run.items(), *extra.items(),
                                     ("truncated (writer killed)", rec.truncated),
                                     ("chunks", rec.chunks)])
    ev_rows = "".join(
        f"<tr><td>{e['t']:.3f}</td><td>{e['level']}</td><td>{html.escape(e['name'])}</td>"
        f"<td style='text-align:left'>{html.escape(e['message'])}</td></tr>" for e in events)
    fig_html = "".join(
        f"<figure class='report-figure' id='{fid}'><h2>{html.escape(title)}</h2>"
        f"<img alt='{html.escape(title)}' src='data:image/png;base64,"
        f"{base64.b64encode(png).decode()}'><figcaption>{html.escape(cap)}</figcaption>"
        "</figure>" for fid, title, png, cap in figs)
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>uavest report "
            f"{html.escape(stem)}</title><style>{_CSS}</style></head><body>"
            f"<h1>uavest report: {html.escape(stem)}</h1><table class='meta'>{meta_rows}"
            f"</table>" + "".join(f"<h2>Comparison ({k})</h2>{_table_html(r, c)}"
                                  for k, r, c in sections) + f"{fig_html}"
            f"<h2>Events (/log)</h2><table><tr><th>t (s)</th><th>level</th><th>name</th>"
            f"<th>message</th></tr>{ev_rows}</table></body></html>")


def _markdown_page(rec: Recording, mcap_path: Path, kind: str, extra: dict, sections: list,
                   figs: list, events: list, figdir: str) -> str:
    """The Markdown page: the same content as the HTML, figures linked from ``figdir``."""
    stem = mcap_path.stem
    run = rec.metadata.get("run", {})
    md = [f"# uavest report: {stem}", "", f"- recording: `{mcap_path.name}` ({kind})"]
    md += [f"- {k}: {v}" for k, v in [*run.items(), *extra.items()]]
    md += [f"- truncated: {rec.truncated}; chunks: {rec.chunks}", ""]
    for k, r, c in sections:
        md += [f"## Comparison ({k})", "", _table_md(r, c), ""]
    md += ["## Figures", ""]
    md += [f"![{title}]({figdir}/{fid}.png)\n\n{cap}\n" for fid, title, _, cap in figs]
    md += ["## Events", ""] + [f"- t = {e['t']:.3f} s [{e['name']}] {e['message']}"
                               for e in events]
    return "\n".join(md) + "\n"


def _jsonnum(o):
    if isinstance(o, np.generic):
        return o.item()
    return str(o)
