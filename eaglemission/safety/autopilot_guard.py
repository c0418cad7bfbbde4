"""The autopilot's own behaviour inside the mission's envelope (``safety.autopilot_params``).

PX4 flies RTL, takeoff and landing by its own parameters: out of the box it returns at
RTL_RETURN_ALT = 30 m and climbs at MPC_Z_V_AUTO_UP = 3 m/s, whatever the mission's envelope
says. Before the flight :class:`AutopilotGuard` reads every parameter of
:data:`~eaglemission.names.PX4_FAILSAFE_PARAMS` once (a parameter the autopilot does not
have is reported, not retried), and for each one that would take the vehicle outside the
envelope (:func:`plan`) either sets it inside (``set``: logged old -> new, restored after the
flight) or refuses the flight (``refuse``: the reason names the parameter and the envelope
key). The autopilot's version and git hash are read when the vehicle reports them.
"""

from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass, field
from typing import Any

from eaglemission.config import SafetyConfig
from eaglemission.names import PX4_FAILSAFE_PARAMS

log = logging.getLogger(__name__)

SPEED_MARGIN = 0.9
"""Autopilot speeds are set to this fraction of the envelope's limit (PX4 overshoots its own
limits a little: recorded climb 2.09 m/s peak for a 1.15 m/s mean)."""

_VERTICAL = ("MPC_Z_V_AUTO_UP", "MPC_Z_V_AUTO_DN", "MPC_TKO_SPEED", "MPC_LAND_SPEED",
             "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN")
_HORIZONTAL = ("MPC_XY_CRUISE", "MPC_XY_VEL_MAX")
REPORTED_ONLY = {
    "RTL_CONE_ANG": "only lowers the return height near home",
    "COM_OF_LOSS_T": "offboard-loss delay (the mission's watchdog acts first)",
    "COM_OBL_RC_ACT": "offboard-loss action: lands or returns inside the envelope",
    "NAV_DLL_ACT": "data-link-loss action: lands or returns inside the envelope",
    "COM_DL_LOSS_T": "data-link-loss delay",
    "COM_DISARM_LAND": "auto-disarm after landing",
}
"""Parameters read and logged whose value cannot take the vehicle out of the envelope."""


@dataclass(frozen=True)
class ParamChange:
    """One parameter outside the envelope: its value, the value inside, why."""

    name: str
    old: float
    new: float
    envelope_key: str
    reason: str


def return_altitude_m(cruise_altitude_m: float, safety: SafetyConfig) -> float:
    """The return height inside the envelope: the cruise altitude, clamped into the band."""
    return max(safety.min_altitude_m + 1.0, min(cruise_altitude_m, safety.max_altitude_m - 1.0))


def plan(values: dict[str, float], safety: SafetyConfig, cruise_altitude_m: float,
         *, align_return: bool = True) -> list[ParamChange]:
    """The parameters of ``values`` that leave the envelope and their values inside it (pure).

    RTL_RETURN_ALT outside ``[min_altitude_m, max_altitude_m]`` (with ``align_return`` any
    value other than the mission's return height, :func:`return_altitude_m`); RTL_DESCEND_ALT
    above that height (PX4 returns at least at RTL_DESCEND_ALT); vertical autopilot speeds
    above ``max_vertical_speed_mps``, MPC_XY_CRUISE (the return leg) and MPC_XY_VEL_MAX (every
    horizontal move, offboard included) above ``max_horizontal_speed_mps``: set to
    :data:`SPEED_MARGIN` of the limit."""
    out: list[ParamChange] = []
    s = safety
    rtl_want = return_altitude_m(cruise_altitude_m, s)
    rtl = values.get("RTL_RETURN_ALT")
    if rtl is not None:
        outside = not (s.min_altitude_m <= rtl <= s.max_altitude_m)
        if outside or (align_return and abs(rtl - rtl_want) > 1e-3):
            out.append(ParamChange(
                "RTL_RETURN_ALT", rtl, rtl_want, "safety.max_altitude_m",
                f"RTL_RETURN_ALT={rtl:g} m: a PX4 return would climb to it, outside "
                f"safety.min_altitude_m..max_altitude_m={s.min_altitude_m:g}..{s.max_altitude_m:g}"
                if outside else f"RTL_RETURN_ALT={rtl:g} m: the mission returns at {rtl_want:g} m"))
    descend = values.get("RTL_DESCEND_ALT")
    if descend is not None and descend > min(rtl_want, s.max_altitude_m) + 1e-3:
        out.append(ParamChange(
            "RTL_DESCEND_ALT", descend, min(descend, rtl_want), "safety.max_altitude_m",
            f"RTL_DESCEND_ALT={descend:g} m: PX4 returns at least this high, above the return "
            f"height {rtl_want:g} m inside safety.max_altitude_m={s.max_altitude_m:g}"))
    for names, limit, key in ((_VERTICAL, s.max_vertical_speed_mps,
                               "safety.max_vertical_speed_mps"),
                              (_HORIZONTAL, s.max_horizontal_speed_mps,
                               "safety.max_horizontal_speed_mps")):
        for name in names:
            v = values.get(name)
            if v is not None and v > limit + 1e-6:
                out.append(ParamChange(
                    name, v, round(SPEED_MARGIN * limit, 3), key,
                    f"{name}={v:g} m/s: autopilot-flown moves would exceed {key}={limit:g}"))
    return out


@dataclass
class GuardReport:
    """What the guard read, set, refused (logged as one ``autopilot_params`` record)."""

    mode: str
    available: bool = True
    version: dict[str, Any] = field(default_factory=dict)
    values: dict[str, float] = field(default_factory=dict)
    missing: dict[str, str] = field(default_factory=dict)
    changes: list[ParamChange] = field(default_factory=list)
    set_ok: list[ParamChange] = field(default_factory=list)
    refused: str = ""
    restored: list[str] = field(default_factory=list)
    restore_errors: dict[str, str] = field(default_factory=dict)

    def record(self) -> dict[str, Any]:
        def ch(c: ParamChange) -> dict[str, Any]:
            return {"name": c.name, "old": c.old, "new": c.new, "envelope_key": c.envelope_key,
                    "reason": c.reason}
        return {"mode": self.mode, "available": self.available, "version": self.version,
                "values": self.values, "missing": self.missing,
                "outside_envelope": [ch(c) for c in self.changes],
                "set": [ch(c) for c in self.set_ok], "refused": self.refused,
                "reported_only": {k: v for k, v in REPORTED_ONLY.items() if k in self.values}}


class AutopilotGuard:
    """Reads, sets (or refuses) and restores the autopilot's envelope parameters.

    ``driver`` is the vehicle driver (under the safety envelope); without ``get_param`` it
    has no parameters and the guard does nothing. :meth:`apply` and :meth:`restore` are
    idempotent: the mission's actuator and the assembly's teardown may both call them."""

    def __init__(self, driver: Any, safety: SafetyConfig, cruise_altitude_m: float, *,
                 timeout_s: float = 5.0) -> None:
        self.driver, self.safety = driver, safety
        self.cruise_altitude_m = float(cruise_altitude_m)
        self.timeout_s = timeout_s
        self.report: GuardReport | None = None
        self._restore: dict[str, float] = {}
        self._lock = asyncio.Lock()

    @property
    def mode(self) -> str:
        return self.safety.autopilot_params

    async def _call(self, fn: Any, *args: Any) -> Any:
        async with asyncio.timeout(self.timeout_s):
            return await fn(*args)

    async def apply(self) -> GuardReport:
        """Read, then set or refuse (once; later calls return the same report)."""
        async with self._lock:
            if self.report is None:
                self.report = await self._apply()
            return self.report

    async def read(self) -> GuardReport:
        """The version and the parameters (each asked once), with what is outside the
        envelope; nothing is written (``eaglemission run --dry-run``)."""
        rep = GuardReport(self.mode)
        get = getattr(self.driver, "get_param", None)
        if get is None:
            rep.available = False
            return rep
        version = getattr(self.driver, "autopilot_version", None)
        if version is not None:
            try:
                rep.version = dict(await self._call(version))
            except Exception as exc:  # noqa: BLE001 - the version is informative
                rep.version = {"error": f"{type(exc).__name__}: {exc}"}
        for name in PX4_FAILSAFE_PARAMS:
            try:  # once each: a missing parameter is reported, not retried
                value = float(await self._call(get, name))
            except Exception as exc:  # noqa: BLE001 - reported below
                rep.missing[name] = f"{type(exc).__name__}: {exc}"
                continue
            if math.isfinite(value):
                rep.values[name] = value
        align = self.mode == "set"
        rep.changes = plan(rep.values, self.safety, self.cruise_altitude_m, align_return=align)
        return rep

    async def _apply(self) -> GuardReport:
        rep = await self.read()
        put = getattr(self.driver, "set_param", None)
        if not rep.available:
            return rep
        if self.mode == "refuse":
            if rep.changes:
                rep.refused = "; ".join(
                    f"safety.autopilot_params=refuse: {c.reason} (envelope key {c.envelope_key}; "
                    f"set {c.name} <= {c.new:g} on the autopilot or use autopilot_params: set)"
                    for c in rep.changes)
            return rep
        for c in rep.changes:
            try:
                if put is None:
                    raise NotImplementedError("the vehicle cannot set parameters")
                await self._call(put, c.name, c.new)
            except Exception as exc:  # noqa: BLE001 - a failed set refuses the flight
                rep.refused = (f"safety.autopilot_params=set: {c.name} could not be set "
                               f"{c.old:g} -> {c.new:g} ({type(exc).__name__}: {exc}); "
                               f"{c.reason} (envelope key {c.envelope_key})")
                break
            self._restore[c.name] = c.old
            rep.set_ok.append(c)
            log.info("autopilot parameter %s: %g -> %g (%s)", c.name, c.old, c.new, c.reason)
        return rep

    async def restore(self, *, in_air: bool = False) -> list[dict[str, Any]]:
        """Put back every value :meth:`apply` changed (bounded per parameter; once). In the air
        nothing is restored: PX4's own values could take the vehicle out of the envelope
        (a return at RTL_RETURN_ALT) while it is still flying; they stay set and are reported."""
        out: list[dict[str, Any]] = []
        put = getattr(self.driver, "set_param", None)
        async with self._lock:
            if not self._restore or put is None:
                return out
            if in_air:
                return [{"name": n, "now": None, "restored": False,
                         "error": "the vehicle is still in the air: left inside the envelope"}
                        for n in self._restore]
            for name, old in list(self._restore.items()):
                try:
                    await self._call(put, name, old)
                except Exception as exc:  # noqa: BLE001 - reported, the next one still tried
                    out.append({"name": name, "now": old, "restored": False,
                                "error": f"{type(exc).__name__}: {exc}"})
                    if self.report is not None:
                        self.report.restore_errors[name] = str(exc)
                    continue
                del self._restore[name]
                out.append({"name": name, "now": old, "restored": True})
                if self.report is not None:
                    self.report.restored.append(name)
        return out

    @property
    def pending_restore(self) -> dict[str, float]:
        """Parameters set and not yet restored (name -> the value to restore)."""
        return dict(self._restore)


async def before_flight(guard: AutopilotGuard, say: Any) -> str:
    """The assembly's step before the mission: apply; the refusal ('' to fly), each set said."""
    rep = await guard.apply()
    for c in rep.set_ok:
        say(f"autopilot parameter {c.name}: {c.old:g} -> {c.new:g} ({c.envelope_key}; "
            "restored after the flight)")
    if rep.missing:
        say(f"autopilot parameters not on this autopilot: {', '.join(sorted(rep.missing))}")
    return f"autopilot parameters: {rep.refused}" if rep.refused else ""


async def after_flight(guard: AutopilotGuard | None, vehicle: Any, say: Any,
                       timeout_s: float = 30.0) -> None:
    """The assembly's teardown (also after a failsafe or an interrupt): restore, bounded."""
    if guard is None or not guard.pending_restore:
        return
    try:
        async with asyncio.timeout(timeout_s):
            done = await guard.restore(in_air=bool(vehicle.state().in_air))
    except TimeoutError:
        done = [{"name": n, "restored": False, "error": f"no answer within {timeout_s:g} s"}
                for n in guard.pending_restore]
    for r in done:
        if r["restored"]:
            say(f"autopilot parameter {r['name']} restored to {r['now']:g}")
        else:
            say(f"autopilot parameter {r['name']} NOT restored: {r['error']}")
            log.warning("autopilot parameter %s not restored: %s", r["name"], r["error"])
