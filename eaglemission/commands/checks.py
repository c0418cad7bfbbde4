"""Cross-section checks run by ``validate`` after the schema: hooks for geometry checks.

A check is a function ``(MissionFile) -> list[str]`` of path-qualified problems. Plugins add
checks through the ``eaglemission.checks`` entry-point group (the mission plugin checks that the
standoff keeps the target in the fixed cameras' view).
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points

from eaglemission import registry
from eaglemission.config import MissionFile
from eaglemission.errors import ConfigError, PluginError
from eaglemission.interfaces import World

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
