"""Config check for ``eaglemission validate`` (entry-point group ``eaglemission.checks``):
reject a standoff, altitude band or geofence that puts the target outside the fixed cameras'
view.

The cameras are fixed to the body, tilted (``mount.pitch_deg``); at the standoff the vehicle
is level and faces the target, so whether the target is in view is plain geometry.
"""

from __future__ import annotations

import math

import numpy as np
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.guidance import grasp_position, standoff_position, yaw_towards_deg
from pydantic import ValidationError

from eaglemission.commands.checks import simulated_world
from eaglemission.config import MissionFile
from eaglemission.geometry import CameraModel, camera_pose_ned, euler_to_quat
from eaglemission.safety.envelope import Envelope, braking_distance_m

VERTICAL_MARGIN_M = 0.5
"""SafeVehicle's default vertical margin inside the altitude band."""


def envelope_of(cfg: MissionFile) -> Envelope:
    """The envelope the runner's SafeVehicle enforces (its default margins)."""
    s = cfg.safety
    margin = 1.0 + 0.5 * braking_distance_m(s.max_horizontal_speed_mps, 3.0)
    return Envelope(s, margin_m=margin, vertical_margin_m=VERTICAL_MARGIN_M)

MIN_TARGET_PX_AT_CRUISE = 10.0
"""The target's long side must span at least this many wide-camera pixels where the wide
camera's optical axis meets the ground at cruise altitude, or cruise cannot find it."""


def _footprint_in_view(model: CameraModel, vehicle_ned: tuple[float, float, float],
                       yaw_deg: float, target_ned: tuple[float, float, float],
                       half_diag_m: float) -> tuple[bool, float]:
    """(whole target footprint in the image, depression angle of the target below the
    optical axis in degrees)."""
    q = euler_to_quat(0.0, 0.0, yaw_deg)
    pose = camera_pose_ned(model, vehicle_ned, q).inverse()
    pts = [target_ned]
    for a in range(0, 360, 45):
        pts.append((target_ned[0] + half_diag_m * math.cos(math.radians(a)),
                    target_ned[1] + half_diag_m * math.sin(math.radians(a)), target_ned[2]))
    cam = pose.apply(np.asarray(pts))
    px = model.project(cam)
    ok = bool(np.isfinite(px).all() and model.in_image(px).all())
    c = cam[0]
    angle = math.degrees(math.atan2(c[1], c[2])) if c[2] > 0 else 90.0
    return ok, angle


def check_mission_geometry(cfg: MissionFile) -> list[str]:
    """Path-qualified problems (empty when the geometry works)."""
    problems: list[str] = []
    if cfg.mission.type != "approach":
        return problems
    try:
        a = ApproachConfig.of(cfg)
    except ValidationError:
        return problems  # the params' own errors are reported by the plugin check
    m, s, t = cfg.mission, cfg.safety, cfg.target
    wide = cfg.cameras.wide.to_model("wide")
    narrow = cfg.cameras.narrow.to_model("narrow")
    half_diag = 0.5 * math.hypot(t.length_m, t.width_m)
    target_top = (0.0, 0.0, -t.height_m)  # a target at the origin; the geometry is relative
    # 1. standoff: both cameras must see the whole target
    yaw = 0.0
    so = a.guidance.standoff
    standoff = standoff_position(target_top, yaw, so.horizontal_m, so.height_m)
    for name, model in (("narrow", narrow), ("wide", wide)):
        ok, angle = _footprint_in_view(model, standoff, yaw, target_top, half_diag)
        if not ok:
            half_v = model.fov_deg[1] / 2
            depression = math.degrees(math.atan2(so.height_m, so.horizontal_m))
            tilt = -model.mount.pitch_deg
            hint = (f"for this camera's {tilt:g} deg tilt use height_m ~ "
                    f"{so.horizontal_m * math.tan(math.radians(tilt)):.2f} for "
                    f"horizontal_m={so.horizontal_m:g}")
            problems.append(
                f"mission.params.guidance.standoff: from the standoff (horizontal_m="
                f"{so.horizontal_m:g}, height_m={so.height_m:g}) the target is "
                f"{depression:.1f} deg below the horizon, {angle:+.1f} deg off the {name} "
                f"camera's axis, outside its "
                f"+-{half_v:.1f} deg vertical view (whole target footprint needed): {hint}")
    # 2. altitude band: standoff and grasp pose altitudes (above home) inside the band
    alt_standoff = t.height_m + so.height_m
    grasp = grasp_position(target_top, yaw, cfg.tool_point_m, a.grasp.distance_m)
    alt_grasp = -grasp[2]
    for name, alt in (("standoff", alt_standoff), ("grasp pose", alt_grasp)):
        if not (s.min_altitude_m + VERTICAL_MARGIN_M <= alt <= s.max_altitude_m - VERTICAL_MARGIN_M):
            problems.append(
                f"safety.min_altitude_m/max_altitude_m: the {name} is {alt:.2f} m above home "
                f"(target height + mission geometry), outside the band "
                f"[{s.min_altitude_m:g}, {s.max_altitude_m:g}] less the envelope's "
                f"{VERTICAL_MARGIN_M:g} m margin: widen the band or change "
                f"mission.params.guidance.standoff / grasp.distance_m")
    tilt_w = math.radians(-wide.mount.pitch_deg)
    if tilt_w > 0:
        axis_range = m.cruise_altitude_m / math.sin(tilt_w)
        span_px = wide.fx * max(t.length_m, t.width_m) / axis_range
        if span_px < MIN_TARGET_PX_AT_CRUISE:
            problems.append(
                f"mission.cruise_altitude_m: at {m.cruise_altitude_m:g} m the target spans "
                f"{span_px:.1f} wide-camera px where the optical axis meets the ground "
                f"({axis_range:.1f} m away), below {MIN_TARGET_PX_AT_CRUISE:g} px: fly lower")
    # 3. geofence: standoff and grasp pose around the simulated target must be inside
    world = simulated_world(cfg)
    if world is not None and m.route:
        tn, te = world.target_ne_m()
        start = min(((w.north_m, w.east_m) for w in m.route),
                    key=lambda p: math.dist(p, (tn, te)))
        yaw = yaw_towards_deg(start, (tn, te)) if math.dist(start, (tn, te)) > 1e-6 else 0.0
        tgt = (tn, te, -t.height_m)
        env = envelope_of(cfg)
        for name, p in (("standoff", standoff_position(tgt, yaw, so.horizontal_m, so.height_m)),
                        ("grasp pose", grasp_position(tgt, yaw, cfg.tool_point_m,
                                                      a.grasp.distance_m))):
            if not env.safe_h(p[0], p[1]):
                problems.append(
                    f"safety.geofence: the {name} for the simulated target "
                    f"({p[0]:.1f}, {p[1]:.1f}) lies outside the fence less the envelope's "
                    f"{env.margin_m:.1f} m margin: the target could not be approached with the "
                    f"cameras on it; enlarge the fence or move the target")
    if a.guidance.approach_speed_mps > s.max_horizontal_speed_mps:
        problems.append(f"mission.params.guidance.approach_speed_mps: exceeds "
                        f"safety.max_horizontal_speed_mps ({s.max_horizontal_speed_mps}), got "
                        f"{a.guidance.approach_speed_mps}")
    return problems
