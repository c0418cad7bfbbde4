"""``eaglemission run --plot out.png`` and ``eaglemission log --plot out.png FILE.mcap``: the
flight figure (:mod:`eaglemission.missions.flight_figure`) from a flown outcome or from a
recording's mission-log records."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from eaglemission.missions.flight_figure import STATE_COLOURS, FlightPicture, draw_flight

from eaglemission.config import MissionFile

if TYPE_CHECKING:
    from eaglemission.missions.mission import ApproachOutcome

__all__ = ["STATE_COLOURS", "outcome_picture", "plot_outcome", "plot_recording",
           "recording_picture"]


def _title(final_state: Any, reason: Any, action: Any) -> str:
    title = f"{final_state}: {reason}"
    if action and str(action) != "none":
        title += f" (action: {action})"
    return title


def outcome_picture(out: ApproachOutcome) -> FlightPicture:
    """The figure's content from a flown outcome: the judged trajectory (the truth in
    simulation), the mission's own estimate of its path, the true target."""
    traj = out.trajectory
    t0 = out.t0_ns
    truth = out.judged_on == "truth"
    r = out.result
    title = _title(r.final_state, r.reason, r.action)
    ev = out.evaluation
    h_err = getattr(ev, "horizontal_error_m", None)
    if h_err is not None:
        title += (f"; tool point {h_err * 100:.1f} cm horizontal, grasp distance "
                  f"{getattr(ev, 'grasp_distance_m', float('nan')):.3f} m")
    target = out.target_position_ned_m
    return FlightPicture(
        t_s=[(s.timestamp_ns - t0) * 1e-9 for s in traj],
        north_m=[s.position_ned_m[0] for s in traj],
        east_m=[s.position_ned_m[1] for s in traj],
        altitude_m=[-s.position_ned_m[2] for s in traj],
        path_label="true path" if truth else "reported path",
        states=list(r.states), t_end_s=r.t_end_s, title=title,
        target_ne_m=(target[0], target[1]) if target is not None else None,
        estimated_path_ne_m=[(p[0], p[1]) for _, p in out.estimated_trajectory] if truth else [])


def plot_outcome(out: ApproachOutcome, cfg: MissionFile, path: Path) -> None:
    """Top view (path by state, route, target, take-off and end), altitude over time on the
    state bands, legends beside them."""
    draw_flight(outcome_picture(out), cfg, path)


def recording_picture(records: Sequence[Mapping[str, Any]]) -> FlightPicture:
    """The figure's content from a recording's mission-log records: the reported path
    (telemetry records), the target estimates (setpoint records), the state changes and the
    end record's outcome."""
    start = next((r for r in records if r.get("kind") == "start"), None)
    t0 = int(start["t_ns"]) if start is not None else int(records[0]["t_ns"]) if records else 0
    tel = [r for r in records if r.get("kind") == "telemetry" and r.get("position_ned_m")]
    targets = [r["target"] for r in records if r.get("kind") == "setpoint" and r.get("target")]
    states = [(0.0, str(start.get("config_state", "PREFLIGHT")) if start else "PREFLIGHT", "")]
    states += [((int(r["t_ns"]) - t0) * 1e-9, str(r["new"]), str(r.get("reason", "")))
               for r in records if r.get("kind") == "state"]
    ts = [(int(r["t_ns"]) - t0) * 1e-9 for r in tel]
    end = next((r for r in reversed(records) if r.get("kind") == "end"), None)
    t_end = (int(end["t_ns"]) - t0) * 1e-9 if end is not None else (ts[-1] if ts else 0.0)
    title = ("recording without an end record (cut short)" if end is None else
             _title(end.get("final_state"), end.get("reason"), end.get("action")))
    return FlightPicture(
        t_s=ts, north_m=[float(r["position_ned_m"][0]) for r in tel],
        east_m=[float(r["position_ned_m"][1]) for r in tel],
        altitude_m=[-float(r["position_ned_m"][2]) for r in tel],
        path_label="reported path (telemetry)", states=states, t_end_s=t_end, title=title,
        target_estimates_ne_m=[(float(t[0]), float(t[1])) for t in targets])


def plot_recording(records: Sequence[Mapping[str, Any]], cfg: MissionFile, path: Path) -> None:
    """The figure of :func:`plot_outcome` from a recording's mission-log records
    (``log --plot``)."""
    draw_flight(recording_picture(records), cfg, path)
