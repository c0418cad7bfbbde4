"""The flight figure of ``run --plot`` and ``log --plot``, drawn from a :class:`FlightPicture`
(matplotlib Agg).

Three columns: the top view (path coloured by mission state, arrows along it in the direction
flown, take-off and end marked, route, target), altitude over time (state changes as coloured
bands) and a column of legends, so no legend or title lies over the data or an axis label.
The top view's limits come from what was flown (path, home, target, estimates), not from the
route or the geofence, and its panel is as wide as that area at equal scale. A state after an
interruption or a failsafe (``FAILSAFE``) is drawn as a wide band under the other states'
lines: a return along the outbound path shows as the band around the outbound line, with its
own arrows pointing back.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eaglemission.config import MissionFile

STATE_COLOURS = {"PREFLIGHT": "#7f7f7f", "TAKEOFF": "#8c564b", "CRUISE": "#1f77b4",
                 "COARSE_APPROACH": "#ff7f0e", "FINE_APPROACH": "#d62728",
                 "FINE_DESCENT": "#bcbd22", "GRASP_READY": "#2ca02c",
                 "TARGET_LOST": "#9467bd", "DONE": "#17becf", "FAILSAFE": "#e377c2"}
"""One colour per mission state, shared by the path, the bands and the legend."""

_SPARE_COLOURS = ("#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd")

RETURN_STATES = frozenset({"FAILSAFE"})
"""States drawn as a wide band under the others (the return after an interruption)."""

BAND_ALPHA = 0.3
"""Opacity of the state bands of the altitude panel (and of the legend's patches)."""

LANDED_BELOW_M = 0.3

DPI = 100
"""An end below this altitude above home is drawn as a landing."""


@dataclass
class FlightPicture:
    """What the flight figure shows, in local NED metres and seconds from the mission start.

    ``states`` is ``[(t_s, state, reason), ...]`` from the initial state on; ``t_end_s`` ends
    the last one.
    """

    t_s: list[float]
    north_m: list[float]
    east_m: list[float]
    path_label: str
    states: list[tuple[float, str, str]]
    t_end_s: float
    title: str
    target_ne_m: tuple[float, float] | None = None
    estimated_path_ne_m: list[tuple[float, float]] = field(default_factory=list)
    estimated_path_label: str = "reported path (estimate)"
    target_estimates_ne_m: list[tuple[float, float]] = field(default_factory=list)
    altitude_m: list[float] = field(default_factory=list)


def state_colour(state: str) -> str:
    """The state's colour (a spare one, fixed per name, for a state the table lacks)."""
    if state in STATE_COLOURS:
        return STATE_COLOURS[state]
    return _SPARE_COLOURS[sum(map(ord, state)) % len(_SPARE_COLOURS)]


def state_spans(states: Sequence[tuple[float, str, str]],
                t_end_s: float) -> list[tuple[float, float, str]]:
    """``(start_s, end_s, state)`` per state, each ending where the next begins."""
    times = [t for t, _, _ in states] + [t_end_s]
    return [(a, max(a, b), st) for (a, st, _), b in zip(states, times[1:])]


def draw_flight(pic: FlightPicture, cfg: MissionFile, path: Path) -> None:
    """Write the flight figure of ``pic`` to ``path`` (PNG)."""
    import matplotlib.pyplot as plt

    fig = flight_figure(pic, cfg)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def flight_figure(pic: FlightPicture, cfg: MissionFile) -> Any:
    """The flight figure of ``pic`` (a matplotlib Figure on the Agg backend; the caller
    closes it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    spans = state_spans(pic.states, pic.t_end_s)
    view = _view_limits(pic)
    (e0, e1), (n0, n1) = view
    top_h_in = 4.6
    top_w_in = min(7.0, max(2.6, top_h_in * (e1 - e0) / (n1 - n0)))
    fig = plt.figure(figsize=(top_w_in + 6.2 + 2.6, 5.6), layout="constrained")
    grid = fig.add_gridspec(1, 3, width_ratios=[top_w_in, 6.2, 2.6])
    ax, ax2, ax_leg = (fig.add_subplot(grid[0, k]) for k in range(3))
    marks = _top_view(ax, pic, cfg, spans, view)
    _altitude(ax2, pic, cfg, spans)
    ax_leg.axis("off")
    seen: dict[str, float] = {}
    for a, _, st in spans:
        seen.setdefault(st, a)
    from matplotlib.colors import to_rgba
    from matplotlib.patches import Patch

    state_handles = [Patch(facecolor=to_rgba(state_colour(st), BAND_ALPHA),
                           edgecolor=state_colour(st), lw=1.5, label=f"{t:5.1f} s  {st}")
                     for st, t in seen.items()]
    leg = ax_leg.legend(handles=state_handles, loc="upper left", fontsize=8,
                        title="mission state (from)", title_fontsize=8, frameon=False,
                        borderaxespad=0.0)
    ax_leg.add_artist(leg)
    ax_leg.legend(handles=marks, loc="lower left", fontsize=8, title="top view",
                  title_fontsize=8, frameon=False, borderaxespad=0.0)
    fig.suptitle("\n".join(textwrap.wrap(pic.title, 120)), fontsize=10)
    return fig


def _view_limits(pic: FlightPicture) -> tuple[tuple[float, float], tuple[float, float]]:
    """(east, north) limits of the top view: what was flown, home and the target, with a
    margin; the short side at least 45 % of the long one, so the panel stays readable."""
    es = list(pic.east_m) + [0.0] + [e for _, e in pic.target_estimates_ne_m]
    ns = list(pic.north_m) + [0.0] + [n for n, _ in pic.target_estimates_ne_m]
    es += [e for _, e in pic.estimated_path_ne_m]
    ns += [n for n, _ in pic.estimated_path_ne_m]
    if pic.target_ne_m is not None:
        ns.append(pic.target_ne_m[0])
        es.append(pic.target_ne_m[1])
    lo_e, hi_e, lo_n, hi_n = min(es), max(es), min(ns), max(ns)
    span = max(hi_e - lo_e, hi_n - lo_n, 2.0)
    margin = max(1.0, 0.08 * span)
    lo_e, hi_e, lo_n, hi_n = lo_e - margin, hi_e + margin, lo_n - margin, hi_n + margin
    big = max(hi_e - lo_e, hi_n - lo_n)

    def widen(lo: float, hi: float) -> tuple[float, float]:
        need = 0.45 * big - (hi - lo)
        return (lo - need / 2, hi + need / 2) if need > 0 else (lo, hi)

    return widen(lo_e, hi_e), widen(lo_n, hi_n)


def _top_view(ax: Any, pic: FlightPicture, cfg: MissionFile,
              spans: list[tuple[float, float, str]],
              view: tuple[tuple[float, float], tuple[float, float]]) -> list[Any]:
    """Route, geofence (where in view), path by state with direction arrows, estimates,
    target, take-off and end. Returns the legend handles of the marks."""
    from matplotlib.lines import Line2D

    marks: list[Any] = []
    (e0, e1), (n0, n1) = view
    route = [(w.east_m, w.north_m) for w in cfg.mission.route]
    if len(route) > 1:
        ax.plot(*zip(*route), "k--", lw=0.9, zorder=1)
        marks.append(Line2D([], [], color="k", ls="--", lw=0.9, label="route"))
    if _geofence(ax, cfg, view):
        marks.append(Line2D([], [], color="#555555", ls=":", lw=1.2, label="geofence"))
    if pic.estimated_path_ne_m:
        ax.plot([p[1] for p in pic.estimated_path_ne_m], [p[0] for p in pic.estimated_path_ne_m],
                color="#555555", lw=0.8, ls=(0, (1, 1.5)), zorder=5)
        marks.append(Line2D([], [], color="#555555", lw=0.8, ls=(0, (1, 1.5)),
                            label=pic.estimated_path_label))
    t = np.asarray(pic.t_s, np.float64)
    n = np.asarray(pic.north_m, np.float64)
    e = np.asarray(pic.east_m, np.float64)
    if t.size:
        marks.append(Line2D([], [], color="#333333", lw=2, label=pic.path_label + ", by state"))
        returned = _path_by_state(ax, t, n, e, spans, spacing_m=max(e1 - e0, n1 - n0) / 9)
        for st in returned:
            marks.append(Line2D([], [], color=state_colour(st), lw=7, alpha=0.55,
                                label=f"{st}: the return (wide)"))
        ax.plot(e[0], n[0], "o", mfc="white", mec="k", ms=8, zorder=8)
        marks.append(Line2D([], [], ls="", marker="o", mfc="white", mec="k", ms=8,
                            label="take-off"))
        alt = pic.altitude_m[-1] if pic.altitude_m else math.nan
        landed = alt < LANDED_BELOW_M
        ax.plot(e[-1], n[-1], "X", color="k", ms=9, zorder=9)
        marks.append(Line2D([], [], ls="", marker="X", color="k", ms=9,
                            label="end (landed)" if landed else
                            f"end ({alt:.1f} m up)" if math.isfinite(alt) else "end"))
    if pic.target_estimates_ne_m:
        ax.plot([p[1] for p in pic.target_estimates_ne_m],
                [p[0] for p in pic.target_estimates_ne_m], ".", color="#d62728", ms=3,
                zorder=6)
        marks.append(Line2D([], [], ls="", marker=".", color="#d62728", ms=5,
                            label="target estimates"))
    if pic.target_ne_m is not None:
        ax.plot(pic.target_ne_m[1], pic.target_ne_m[0], "s", mfc="none", mec="#d62728",
                mew=2, ms=11, zorder=7)
        marks.append(Line2D([], [], ls="", marker="s", mfc="none", mec="#d62728", mew=2,
                            ms=9, label="target (truth)"))
    ax.set_xlim(e0, e1)
    ax.set_ylim(n0, n1)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title("top view (local NED, home at 0)", fontsize=9)
    ax.grid(alpha=0.25)
    return marks


def _path_by_state(ax: Any, t: np.ndarray, n: np.ndarray, e: np.ndarray,
                   spans: list[tuple[float, float, str]], *, spacing_m: float) -> list[str]:
    """One line per state span (the samples before the first span belong to it), a wide
    band for the return states, and arrowheads every ``spacing_m`` of path. Returns the return
    states drawn."""
    returned: list[str] = []
    edges = [a for a, _, _ in spans[1:]]
    idx = np.searchsorted(np.asarray(edges), t, side="right")  # span index of every sample
    for k, (_, _, st) in enumerate(spans):
        sel = np.flatnonzero(idx == k)
        if sel.size == 0:
            continue
        sel = np.r_[sel, sel[-1] + 1] if sel[-1] + 1 < t.size else sel  # join to the next
        colour = state_colour(st)
        if st in RETURN_STATES:
            if st not in returned:
                returned.append(st)
            ax.plot(e[sel], n[sel], color=colour, lw=7, alpha=0.55, solid_capstyle="round",
                    zorder=2)
        else:
            ax.plot(e[sel], n[sel], color=colour, lw=2, zorder=3)
        _arrows(ax, e[sel], n[sel], colour, spacing_m)
    return returned


def _arrows(ax: Any, e: np.ndarray, n: np.ndarray, colour: str, spacing_m: float) -> None:
    """Arrowheads along a polyline, in the direction flown, every ``spacing_m`` (from half
    a spacing in)."""
    if e.size < 2 or not spacing_m > 0:
        return
    seg = np.hypot(np.diff(e), np.diff(n))
    s = np.r_[0.0, np.cumsum(seg)]
    for d in np.arange(spacing_m / 2, s[-1], spacing_m):
        i = int(np.searchsorted(s, d, side="right")) - 1
        i = min(max(i, 0), seg.size - 1)
        if seg[i] <= 1e-9:
            continue
        f = (d - s[i]) / seg[i]
        pe, pn = e[i] + f * (e[i + 1] - e[i]), n[i] + f * (n[i + 1] - n[i])
        de, dn = (e[i + 1] - e[i]) / seg[i], (n[i + 1] - n[i]) / seg[i]
        ax.annotate("", xy=(pe + 0.01 * de, pn + 0.01 * dn), xytext=(pe, pn),
                    arrowprops={"arrowstyle": "-|>,head_length=0.8,head_width=0.4",
                                "color": colour, "lw": 0, "shrinkA": 0, "shrinkB": 0},
                    zorder=10)


def _geofence(ax: Any, cfg: MissionFile,
              view: tuple[tuple[float, float], tuple[float, float]]) -> bool:
    """Draw the geofence when a part of it lies in the view; True when drawn."""
    fence = cfg.safety.geofence
    (e0, e1), (n0, n1) = view
    if fence.polygon_ned_m is not None:
        pts = np.asarray(list(fence.polygon_ned_m) + [fence.polygon_ned_m[0]], np.float64)
        ne = pts
    elif fence.radius_m is not None:
        a = np.linspace(0.0, 2 * np.pi, 361)
        ne = np.c_[fence.radius_m * np.cos(a), fence.radius_m * np.sin(a)]
    else:
        return False
    inside = (ne[:, 1] >= e0) & (ne[:, 1] <= e1) & (ne[:, 0] >= n0) & (ne[:, 0] <= n1)
    if not inside.any():
        return False
    ax.plot(ne[:, 1], ne[:, 0], ":", color="#555555", lw=1.2, zorder=1)
    return True


def _altitude(ax2: Any, pic: FlightPicture, cfg: MissionFile,
              spans: list[tuple[float, float, str]]) -> None:
    """Altitude above home over time on the state bands; the safety ceiling when near."""
    for a, b, st in spans:
        ax2.axvspan(a, b, color=state_colour(st), alpha=BAND_ALPHA, lw=0)
    ax2.plot(pic.t_s, pic.altitude_m, color="#111111", lw=1.6)
    top = max(pic.altitude_m, default=1.0)
    ceiling = cfg.safety.max_altitude_m
    if ceiling <= 1.5 * max(top, 1.0):
        ax2.axhline(ceiling, color="#d62728", lw=0.8, ls="--")
        ax2.annotate("safety.max_altitude_m", (1.0, ceiling), xycoords=("axes fraction", "data"),
                     xytext=(-2, 2), textcoords="offset points", ha="right", va="bottom",
                     fontsize=7, color="#d62728")
        top = max(top, ceiling)
    bottom = min(min(pic.altitude_m, default=0.0), 0.0)
    pad = 0.06 * max(top - bottom, 1.0)
    ax2.set_ylim(bottom - pad, top + 2.5 * pad)
    t_lo = min(pic.t_s[0] if pic.t_s else 0.0, spans[0][0] if spans else 0.0)
    ax2.set_xlim(t_lo, max(pic.t_end_s, pic.t_s[-1] if pic.t_s else 0.0))
    ax2.set_xlabel("time since the mission start (s)")
    ax2.set_ylabel("altitude above home (m)")
    ax2.set_title("altitude over time (bands: mission state)", fontsize=9)
    ax2.grid(alpha=0.25)
