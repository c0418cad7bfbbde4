"""Mission execution of the shared autopilot model (:mod:`.autopilot`): items, climb, legs,
progress, the DO items run on arrival.

The simulated vehicle uploads :class:`~eaglemission.types.Waypoint` s (one :class:`MissionItem`
each); the MAVLink emulator converts PX4's MISSION_ITEM_INT list item by item, DO items included,
so MISSION_CURRENT and MISSION_ITEM_REACHED count what PX4 counts (recorded scenario c: reached
1, 3, 5 for WP, SPEED, WP, SPEED, WP, SPEED).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from eaglemission.types import Setpoint, Waypoint

if TYPE_CHECKING:  # the autopilot owns the executor; imported for the annotations only
    from eaglemission.lab.vehicles.autopilot.model import Autopilot

ItemKind = Literal["waypoint", "land", "return", "speed", "gripper", "other"]
NAV_KINDS: frozenset[str] = frozenset({"waypoint", "land", "return"})
"""Kinds that are flown; the others (DO items) run when the vehicle reaches the one before."""

MissionPhase = Literal["idle", "climb", "legs", "done"]


@dataclass(frozen=True, slots=True)
class MissionItem:
    """One mission item, relative to home.

    ``north_m`` / ``east_m`` None: where the vehicle is when the leg starts; ``altitude_m``
    (above home) None: its current altitude; ``acceptance_radius_m`` None: the autopilot's
    default (NAV_ACC_RAD); ``yaw_deg`` None: along the leg; ``speed_mps``: the leg's speed for a
    waypoint, the new mission speed for a ``speed`` item (DO_CHANGE_SPEED); ``grab``: a
    ``gripper`` item's action (DO_GRIPPER).
    """

    kind: ItemKind = "waypoint"
    north_m: float | None = None
    east_m: float | None = None
    altitude_m: float | None = None
    acceptance_radius_m: float | None = None
    yaw_deg: float | None = None
    speed_mps: float | None = None
    grab: bool | None = None

    @classmethod
    def from_waypoint(cls, w: Waypoint) -> MissionItem:
        return cls("waypoint", w.north_m, w.east_m, w.altitude_m, w.acceptance_radius_m,
                   None, w.speed_mps)


class MissionExecutor:
    """The autopilot's mission: which item is flown, which was reached, the climb first.

    ``current`` is the index of the item being flown (``len(items)`` once all are done: the
    number of items reached when every item is a waypoint, the simulated vehicle's progress);
    ``reached`` the index of the last item reached (-1: none since the start).
    """

    def __init__(self, autopilot: Autopilot) -> None:
        self._ap = autopilot
        self.items: tuple[MissionItem, ...] = ()
        self.current = 0
        self.reached = -1
        self.phase: MissionPhase = "idle"
        self.speed_mps: float | None = None  # set by a DO_CHANGE_SPEED (item or command)
        self._leg_started = False
        self._leg: tuple[float, float, float | None] = (0.0, 0.0, None)

    @property
    def finished(self) -> bool:
        return self.phase == "done"

    def load(self, items: Sequence[MissionItem]) -> None:
        """A new mission (replaces the old one; progress back to the start)."""
        self.items = tuple(items)
        self.current = 0
        self.reached = -1
        self.phase = "idle"

    def set_current(self, index: int) -> None:
        """MISSION_SET_CURRENT: fly item ``index`` next."""
        if 0 <= index < len(self.items):
            self.current = index
            if self.phase in ("legs", "done"):  # flying: go there now
                self.phase = "legs"
                self._leg_started = False

    def begin(self, first: int | None = None) -> None:
        """Before a (re)start: from ``first`` if given; back to item 0 when all were done."""
        if first is not None:
            self.current = first
        if self.current >= len(self.items):
            self.current = 0
        self.reached = -1
        if self.phase == "done":
            self.phase = "idle"

    # ------------------------------------------------------------------------------------------
    def start_logic(self) -> None:
        """Start flying from ``current``: climb first when on the ground or below its altitude
        (PX4: "Climb to X meters above home"), else the legs."""
        ap = self._ap
        dyn = ap.dyn
        first = self.items[min(self.current, len(self.items) - 1)]
        target = first.altitude_m
        alt = -dyn.estimated_position()[2]
        if target is not None and (dyn.on_ground or alt < target - ap.params.mission_vertical_acceptance_m):
            self.phase = "climb"
            ap.status(f"Climb to {target:.1f} meters above home")
            e = dyn.estimated_position()
            dyn.command_position(Setpoint(e[0], e[1], -target, dyn.yaw_deg),
                                 max_up_speed_mps=ap.params.takeoff_speed_mps, immediate=True)
            ap.climbing_from_ground()
        else:
            self.phase = "legs"
            self._leg_started = False

    def climbing(self) -> bool:
        return self.phase == "climb"

    def step(self) -> None:
        """After every model step in MISSION."""
        phase = self.phase
        if phase == "done" or phase == "idle":
            return
        ap = self._ap
        dyn = ap.dyn
        p = ap.params
        items = self.items
        e = dyn.estimated_position()
        if phase == "climb":
            target = items[min(self.current, len(items) - 1)].altitude_m
            if target is None or -e[2] >= target - p.mission_vertical_acceptance_m:
                self.phase = "legs"
                self._leg_started = False
                ap.climb_done()
            return
        i = self.current
        if i >= len(items):
            return
        item = items[i]
        if item.kind == "land":
            ap.land("autopilot")
            return
        if item.kind == "return":
            ap.start_rtl("autopilot")
            return
        if item.kind != "waypoint":  # a DO item to fly to: it is where we are
            self._reached(i)
            return
        if not self._leg_started:
            self._leg_started = True
            n = e[0] if item.north_m is None else item.north_m
            east = e[1] if item.east_m is None else item.east_m
            alt = -e[2] if item.altitude_m is None else item.altitude_m
            self._leg = (n, east, item.altitude_m)
            dn, de = n - e[0], east - e[1]
            if item.yaw_deg is not None:
                yaw = item.yaw_deg
            else:
                yaw = math.degrees(math.atan2(de, dn)) if math.hypot(dn, de) > 1.0 else dyn.yaw_deg
            speed = item.speed_mps if item.speed_mps is not None else self.speed_mps
            dyn.command_position(Setpoint(n, east, -alt, yaw), max_speed_mps=speed, immediate=True)
            return
        n, east, alt_or_none = self._leg
        radius = (item.acceptance_radius_m if item.acceptance_radius_m is not None
                  else p.mission_acceptance_radius_m)
        if (math.hypot(n - e[0], east - e[1]) <= radius
                and (alt_or_none is None
                     or abs(-e[2] - alt_or_none) <= p.mission_vertical_acceptance_m)):
            self._reached(i)

    def _reached(self, i: int) -> None:
        """PX4: the DO items after a reached item run at once, and MISSION_ITEM_REACHED
        reports the last of them."""
        ap = self._ap
        items = self.items
        j = i + 1
        while j < len(items) and items[j].kind not in NAV_KINDS:
            self._run(items[j])
            j += 1
        self.reached = j - 1
        self.current = j
        ap.listener.on_mission_item(self.reached, len(items))
        self._leg_started = False
        if self.current >= len(items):
            self.phase = "done"
            if ap.params.mission_end_brake:
                ap.dyn.command_hold(immediate=True)
            ap.status("Mission finished, loitering")

    def _run(self, item: MissionItem) -> None:
        if item.kind == "speed" and item.speed_mps is not None and item.speed_mps > 0:
            self.speed_mps = item.speed_mps
        elif item.kind == "gripper" and item.grab is not None:
            self._ap.gripper = "grab" if item.grab else "release"
