"""``eaglemission run --dry-run``: everything short of arming, checked and reported.

Each check is ``(name, passed, detail)``. Cameras: one frame grabbed from each (bounded) and
compared with its calibration (resolution). Vehicle: link, home, position/GPS, armable, on the
ground, battery, downward rangefinder; the autopilot's version and failsafe parameters when it
has any, and which of them the flight would set inside the envelope or refuse for.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from typing import Any

from eaglemission.clock import run_blocking
from eaglemission.config import SafetyConfig
from eaglemission.safety.autopilot_guard import AutopilotGuard

Check = tuple[str, bool, str]
"""``(name, passed, detail)``; a passed check whose detail starts with ``warning:`` is a
warning (flies, but read it); a failed one's detail ends with the remedy."""

WARNING = "warning: "


def status(check: Check) -> str:
    """``ok``, ``warn`` or ``FAIL``: how the check's line is marked."""
    _, passed, detail = check
    if not passed:
        return "FAIL"
    return "warn" if detail.startswith(WARNING) else "ok"


def check_line(check: Check) -> str:
    """The check as the dry run prints it: ``  [ok] name: detail``."""
    name, _, detail = check
    mark = status(check)
    return f"  [{mark}] {name}: {detail.removeprefix(WARNING) if mark == 'warn' else detail}"


def verdict_line(checks: list[Check]) -> str:
    """The dry run's last line: how many checks passed, warned, failed; nothing armed."""
    marks = [status(c) for c in checks]
    n_fail, n_warn = marks.count("FAIL"), marks.count("warn")
    head = "dry run passed" if not n_fail else f"dry run FAILED: {n_fail} of {len(checks)} " \
                                               "checks failed"
    return (f"{head} ({marks.count('ok')} ok, {n_warn} warning{'' if n_warn == 1 else 's'}, "
            f"{n_fail} failed); nothing was armed")


async def _grab(cam: Any, timeout_s: float) -> Any:
    async with asyncio.timeout(timeout_s + 5.0):
        return await run_blocking(lambda: cam.grab(timeout_s=timeout_s))


async def camera_checks(cameras: dict[str, Any], *, timeout_s: float = 5.0) -> list[Check]:
    out: list[Check] = []
    for cid, cam in cameras.items():
        m = cam.model
        try:
            frame = await _grab(cam, timeout_s)
        except Exception as exc:  # noqa: BLE001 - every failure is a failed check
            out.append((f"camera {cid}: frame", False, f"{type(exc).__name__}: {exc}"))
            continue
        h, w = frame.image.shape[:2]
        same = (w, h) == (m.width_px, m.height_px)
        out.append((f"camera {cid}: frame", same,
                    f"{w}x{h} px, calibration {m.width_px}x{m.height_px} px"
                    + ("" if same else ": fix the device's Width/Height or the calibration")))
    return out


def vehicle_checks(state: Any) -> list[Check]:
    s = state
    rng = s.distance_to_ground_m
    battery_ok = bool(math.isfinite(s.battery_remaining) and s.battery_remaining > 0.3)
    return [
        ("vehicle: link", bool(s.link_ok), "telemetry flowing" if s.link_ok
         else "no telemetry: check the link (cable, radio, URL)"),
        ("vehicle: home", s.home is not None,
         "home known" if s.home is not None
         else "no home position yet: wait for a GPS fix (outdoors, clear sky)"),
        ("vehicle: position", bool(s.position_valid and s.gps_fix),
         f"position valid {s.position_valid}, GPS fix {s.gps_fix}"
         + ("" if s.position_valid and s.gps_fix else ": wait for the estimator and a GPS fix")),
        ("vehicle: armable", bool(s.armable), "pre-arm checks pass" if s.armable
         else "the autopilot reports not armable: see its pre-arm messages (QGroundControl)"),
        ("vehicle: on the ground", not s.in_air, "landed" if not s.in_air
         else "in the air: land before a mission starts"),
        ("vehicle: battery", battery_ok, f"{s.battery_remaining:.0%}"
         + ("" if battery_ok else ": charge or change the battery (needs more than 30 %)")),
        ("vehicle: downward rangefinder", True,
         f"{rng:.2f} m" if rng is not None else WARNING + "no reading (normal on the ground, "
         "below the sensor's minimum range; in the air the mission warns again and the grasp "
         "height then follows the altitude estimate)"),
    ]


VEHICLE_CHECKS = ("link", "home", "position", "armable", "on the ground", "battery",
                  "downward rangefinder", "autopilot parameters")


def unconnected_checks(reason: str) -> list[Check]:
    """The vehicle's checks when it could not be connected: one failed line naming them."""
    return [("vehicle: connection", False, reason),
            ("vehicle: " + ", ".join(VEHICLE_CHECKS), False, "not checked: no connection")]


async def parameter_check(driver: Any, safety: Any = None, cruise_altitude_m: float = 5.0,
                          timeout_s: float = 5.0) -> list[Check]:
    """The autopilot's version and failsafe parameters (each read once) and, with ``safety``,
    what the flight would set inside the envelope or refuse (``safety.autopilot_params``)."""
    guard = AutopilotGuard(driver, safety or SafetyConfig(), cruise_altitude_m,
                           timeout_s=timeout_s)
    rep = await guard.read()
    if not rep.available:
        return [("autopilot parameters", True, "this vehicle has no parameters to read")]
    text = ", ".join(f"{k}={v:g}" for k, v in rep.values.items())
    if rep.missing:
        text += f"; not on this autopilot: {', '.join(rep.missing)}"
    out: list[Check] = [("autopilot parameters", bool(rep.values), text or "none answered")]
    if rep.version:
        out.append(("autopilot version", "error" not in rep.version,
                    ", ".join(f"{k}={v}" for k, v in rep.version.items())))
    if safety is not None:
        refuse = guard.mode == "refuse"
        out += [(f"autopilot parameter {c.name}", not refuse,
                 f"{c.reason}: " + (f"refused ({c.envelope_key}; autopilot_params: refuse)"
                                    if refuse else f"the flight sets {c.old:g} -> {c.new:g} "
                                    "and restores it after")) for c in rep.changes]
    return out


async def dry_run_checks(asm: Any, say: Callable[[str], None], *, cameras: dict[str, Any],
                         connected: bool = True) -> list[Check]:
    """Every check of the dry run, each said as it is done; none stops the others. Only the
    ``cameras`` that opened are grabbed from; an unconnected vehicle is one failed line."""
    out: list[Check] = []

    def said(checks: list[Check]) -> None:
        for c in checks:
            say(check_line(c))
        out.extend(checks)

    said(await camera_checks(cameras))
    if not connected:
        return out
    said(vehicle_checks(asm.vehicle.state()))
    cfg = asm.config
    said(await parameter_check(asm.driver, cfg.safety, cfg.mission.cruise_altitude_m))
    return out
