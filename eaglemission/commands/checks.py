"""Cross-section checks run by ``validate`` after the schema: hooks for geometry checks.

A check is a function ``(MissionFile) -> list[str]`` of path-qualified problems. Plugins add
checks through the ``eaglemission.checks`` entry-point group (the mission plugin checks that the
standoff keeps the target in the fixed cameras' view).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from importlib import resources
from importlib.metadata import entry_points
from pathlib import Path

from eaglemission import registry
from eaglemission.config import MissionFile
from eaglemission.errors import ConfigError, PluginError
from eaglemission.interfaces import World
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE

CAMERAS = (CAMERA_WIDE, CAMERA_NARROW)

Check = Callable[[MissionFile], list[str]]


def core_checks(cfg: MissionFile) -> list[str]:
    problems: list[str] = []
    s = cfg.safety
    m = cfg.mission
    if not (s.min_altitude_m <= m.cruise_altitude_m <= s.max_altitude_m):
        problems.append(
            f"mission.cruise_altitude_m: must lie in the safety altitude band "
            f"[{s.min_altitude_m}, {s.max_altitude_m}], got {m.cruise_altitude_m}")
    if m.cruise_speed_mps > s.max_horizontal_speed_mps:
        problems.append(f"mission.cruise_speed_mps: exceeds safety.max_horizontal_speed_mps "
                        f"({s.max_horizontal_speed_mps}), got {m.cruise_speed_mps}")
    from eaglemission.geometry.geofence import inside_geofence

    for i, wp in enumerate(m.route):
        if not inside_geofence(s.geofence, wp.north_m, wp.east_m):
            problems.append(f"mission.route[{i}]: ({wp.north_m}, {wp.east_m}) lies outside "
                            f"safety.geofence: move it inside or enlarge the fence")
    for cid in ("wide", "narrow"):
        cam = getattr(cfg.cameras, cid)
        if cam.calibration_file is None or "resolution_px" not in cam.model_fields_set:
            continue
        from eaglemission.geometry.calibration import load_calibration

        try:
            cal = load_calibration(cam.calibration_file)
        except Exception as exc:  # noqa: BLE001 - reported as a problem of the file
            problems.append(f"cameras.{cid}.calibration_file: {exc}")
            continue
        if tuple(cam.resolution_px) != (cal.width_px, cal.height_px):
            problems.append(
                f"cameras.{cid}.resolution_px: {list(cam.resolution_px)} disagrees with the "
                f"calibration file ({cal.width_px}x{cal.height_px}): calibrate at the "
                "resolution you fly, or drop resolution_px")
    world = simulated_world(cfg)
    if world is not None and not inside_geofence(s.geofence, *world.target_ne_m()):
        problems.append("world.params.target_north_m/target_east_m: the simulated target lies "
                        "outside safety.geofence")
    return problems


def simulated_world(cfg: MissionFile) -> World | None:
    """The world plugin of ``cfg`` for checks; None when there is none or its params are
    invalid (reported by the plugin check of ``world``)."""
    if cfg.world is None:
        return None
    try:
        world: World = registry.load("worlds", cfg.world.type, cfg.world.params)
        return world
    except (ConfigError, PluginError):
        return None  # reported by the plugin check of `world`


def run_checks(cfg: MissionFile) -> list[str]:
    problems = core_checks(cfg)
    for ep in entry_points(group="eaglemission.checks"):
        try:
            check: Check = ep.load()
            problems.extend(check(cfg))
        except Exception as exc:  # a broken check must not hide the others
            problems.append(f"<check {ep.name}>: failed: {type(exc).__name__}: {exc}")
    return problems


PLACEHOLDER_SERIAL = re.compile(r"^(4000000\d|0+|1234\d*|x+|serial.*|changeme)$", re.IGNORECASE)
"""Serial numbers that stand for "fill in yours" (the field template's 40000001/40000002)."""


def _shipped(path: str | None) -> bool:
    """True for a file shipped with eaglemission's example configs (the simulator's), where
    it is or copied next to a copy of the template (same name, same bytes)."""
    if not path:
        return False
    shipped = Path(str(resources.files("eaglemission.configs"))).resolve()
    p = Path(path)
    try:
        if p.resolve().is_relative_to(shipped):
            return True
        twin = shipped / p.parent.name / p.name
        return twin.is_file() and p.is_file() and twin.read_bytes() == p.read_bytes()
    except OSError:
        return False


def hardware_warnings(cfg: MissionFile) -> list[str]:
    """What a mission file for real cameras still has from the template (warnings, not
    problems: it is valid, but would fly with someone else's numbers): placeholder serial
    numbers, no or a missing or a shipped nominal calibration file, the simulator's example
    target image."""
    out: list[str] = []
    hardware = []
    for cid in CAMERAS:
        section = getattr(cfg.cameras, cid)
        try:
            cls = registry.get("cameras", section.type)
        except PluginError:
            continue  # reported by the plugin check
        if getattr(cls, "wall_clock", False) and not getattr(cls, "simulated", False):
            hardware.append((cid, section))
    for cid, cam in hardware:
        serial = cam.params.get("serial_number")
        if serial is not None and PLACEHOLDER_SERIAL.match(str(serial)):
            out.append(f"cameras.{cid}.params.serial_number: {serial!r} is a placeholder: put "
                       "your camera's serial number (its label, or pylon Viewer)")
        cal = cam.calibration_file
        if cal is None:
            out.append(f"cameras.{cid}.calibration_file: none: the lens' nominal intrinsics "
                       "are used; calibrate the camera")
        elif not Path(cal).is_file():
            out.append(f"cameras.{cid}.calibration_file: {cal} not found: calibrate the "
                       "camera and give its file")
        elif _shipped(cal):
            out.append(f"cameras.{cid}.calibration_file: {cal} is the nominal example shipped "
                       "with eaglemission: calibrate your camera")
    image = cfg.target.appearance_image
    if hardware and _shipped(image):
        out.append(f"target.appearance_image: {image} is the simulator's example target: use a "
                   "photo of your own target (or remove the key)")
    return out
