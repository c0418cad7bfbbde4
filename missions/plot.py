"""``eaglemission run --plot out.png`` and ``eaglemission log --plot out.png FILE.mcap``:
trajectory, target and state changes (matplotlib Agg)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from eaglemission.config import MissionFile

if TYPE_CHECKING:
    from eaglemission.missions.mission import ApproachOutcome

STATE_COLOURS = {"PREFLIGHT": "#999999", "TAKEOFF": "#8c564b", "CRUISE": "#1f77b4",
                 "COARSE_APPROACH": "#ff7f0e", "FINE_APPROACH": "#d62728",
                 "GRASP_READY": "#2ca02c", "TARGET_LOST": "#9467bd", "DONE": "#17becf",
                 "FAILSAFE": "#e377c2"}


def plot_outcome(out: ApproachOutcome, cfg: MissionFile, path: Path) -> None:
    """Top view (true and estimated path, route, target, state changes) and altitude/time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    traj = out.trajectory
    t0 = out.t0_ns
    ts = [(s.timestamp_ns - t0) * 1e-9 for s in traj]
    n = [s.position_ned_m[0] for s in traj]
    e = [s.position_ned_m[1] for s in traj]
    alt = [-s.position_ned_m[2] for s in traj]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5.5), gridspec_kw={"width_ratios": [1.2, 1]})
    route = [(w.east_m, w.north_m) for w in cfg.mission.route]
    ax.plot(*zip(*route), "k--", lw=1, label="route")
    ax.plot(e, n, color="#1f77b4", lw=1.5, label="true path")
    if out.estimated_trajectory:
        ax.plot([p[1] for _, p in out.estimated_trajectory],
                [p[0] for _, p in out.estimated_trajectory], color="#aaaaaa", lw=1,
                label="reported (estimate)")
    target = out.target_position_ned_m
    if target is not None:
        ax.plot(target[1], target[0], "s", color="#d62728", ms=9, label="target (truth)")
    tn, te = (target[0], target[1]) if target is not None else (n[-1] if n else 0.0,
                                                                 e[-1] if e else 0.0)
    for t_s, state, _reason in out.result.states[1:]:
        i = min(range(len(ts)), key=lambda k: abs(ts[k] - t_s)) if ts else None
        if i is None:
            continue
        ax.plot(e[i], n[i], "o", color=STATE_COLOURS.get(state, "k"), ms=6)
        ax.annotate(state, (e[i], n[i]), fontsize=7, xytext=(4, 4), textcoords="offset points")
    _fence(ax, cfg, n + [tn], e + [te])
    ax2.plot(ts, alt, color="#1f77b4", lw=1.5, label="altitude (true)")
    _state_bands(ax2, out.result.states + [(out.result.t_end_s, "", "")], alt)
    ev = out.evaluation
    title = f"{out.result.final_state}: {out.result.reason}"
    if ev.horizontal_error_m is not None:
        title += (f"\ntool point: {ev.horizontal_error_m * 100:.1f} cm horizontal, "
                  f"grasp distance {ev.grasp_distance_m:.3f} m")
    ax2.set_title(title, fontsize=9)
    _save(fig, path)


def _fence(ax: Any, cfg: MissionFile, n: list[float], e: list[float]) -> None:
    """The geofence circle, the axes' limits and labels of the top view."""
    fence = cfg.safety.geofence
    if fence.radius_m is not None and fence.radius_m < 200:
        import numpy as np

        a = np.linspace(0, 2 * np.pi, 200)
        ax.plot(fence.radius_m * np.sin(a), fence.radius_m * np.cos(a), ":", color="#999999",
                lw=1, label="geofence")
        ax.set_xlim(min(e) - 5, max(e) + 5)
        ax.set_ylim(min(n) - 5, max(n) + 5)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="box")
    ax.legend(fontsize=8, loc="best")
    ax.set_title("top view (local NED, home at 0)")


def _state_bands(ax2: Any, states: Sequence[tuple[float, str, str]], alt: list[float]) -> None:
    """One shaded band per state (the last entry only ends the previous one)."""
    for (a_t, st, _), (b_t, _, _) in zip(states[:-1], states[1:]):
        ax2.axvspan(a_t, b_t, color=STATE_COLOURS.get(st, "#ffffff"), alpha=0.15, lw=0)
        ax2.text(a_t, max(alt or [1]) * 1.02, st, fontsize=6, rotation=60, va="bottom")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("altitude above home (m)")


def _save(fig: Any, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_recording(records: Sequence[Mapping[str, Any]], cfg: MissionFile, path: Path) -> None:
    """The same figure from a recording's mission-log records (``log --plot``): the reported
    path (telemetry records), the target estimates, the route, the geofence, the state
    changes and the altitude over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    start = next((r for r in records if r.get("kind") == "start"), None)
    t0 = int(start["t_ns"]) if start is not None else int(records[0]["t_ns"]) if records else 0
    tel = [r for r in records if r.get("kind") == "telemetry" and r.get("position_ned_m")]
    ts = [(int(r["t_ns"]) - t0) * 1e-9 for r in tel]
    n = [float(r["position_ned_m"][0]) for r in tel]
    e = [float(r["position_ned_m"][1]) for r in tel]
    alt = [-float(r["position_ned_m"][2]) for r in tel]
    targets = [r["target"] for r in records if r.get("kind") == "setpoint" and r.get("target")]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5.5), gridspec_kw={"width_ratios": [1.2, 1]})
    route = [(w.east_m, w.north_m) for w in cfg.mission.route]
    ax.plot(*zip(*route), "k--", lw=1, label="route")
    ax.plot(e, n, color="#aaaaaa", lw=1.5, label="reported path (telemetry)")
    if targets:
        ax.plot([t[1] for t in targets], [t[0] for t in targets], ".", color="#d62728", ms=3,
                label="target estimates")
    states = [(0.0, str(start.get("config_state", "PREFLIGHT")) if start else "PREFLIGHT", "")]
    states += [((int(r["t_ns"]) - t0) * 1e-9, str(r["new"]), str(r.get("reason", "")))
               for r in records if r.get("kind") == "state"]
    for t_s, state, _ in states[1:]:
        if ts:
            i = min(range(len(ts)), key=lambda k: abs(ts[k] - t_s))
            ax.plot(e[i], n[i], "o", color=STATE_COLOURS.get(state, "k"), ms=6)
            ax.annotate(state, (e[i], n[i]), fontsize=7, xytext=(4, 4),
                        textcoords="offset points")
    _fence(ax, cfg, n + [t[0] for t in targets] + [0.0], e + [t[1] for t in targets] + [0.0])
    ax2.plot(ts, alt, color="#aaaaaa", lw=1.5, label="altitude (reported)")
    end = next((r for r in reversed(records) if r.get("kind") == "end"), None)
    t_end = (int(end["t_ns"]) - t0) * 1e-9 if end is not None else (ts[-1] if ts else 0.0)
    _state_bands(ax2, states + [(t_end, "", "")], alt)
    title = "recording"
    if end is not None:
        title = f"{end.get('final_state')}: {end.get('reason')}"
    ax2.set_title(title, fontsize=9)
    _save(fig, path)
