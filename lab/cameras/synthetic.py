"""``synthetic`` camera plugin: renders :class:`SyntheticWorld` from the TRUE vehicle pose.

Time convention (``SyntheticWorldConfig.camera_time_offset_s`` = ``dt``): ``grab`` stamps the frame
with the clock's current time ``t`` (taken as mid-exposure) but renders the world and the
vehicle pose at ``t - dt``. The camera's stamps are therefore *late* by ``dt`` with respect to
the telemetry, like an uncompensated USB/driver latency on a real rig: a pipeline that looks up
the pose at the frame's stamp is off by ``dt``. Frame pacing is the caller's job.

Motion blur (``SyntheticWorldConfig.motion_blur``): the camera works out the pose at the start
of the exposure (``t - dt - exposure_s / 2``) from the true velocity and angular velocity at the
rendered time when the pose source offers them (``motion_at``: the simulated vehicle's truth
log), else asks the pose source for that pose; the world smears the frame along the image
motion between the two, doubled (the whole exposure at constant velocity and angular rate).
The end of the exposure is not asked for: it may lie past the clock's now, and the simulated
vehicle's pose source holds its last row there (so two poses near now can be equal).
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from eaglemission.lab.world.render import GroundTruth, SyntheticWorld
from eaglemission.lab.world.synthetic import SyntheticWorldConfig, world_config
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from eaglemission.clock import Clock, MonotonicClock
from eaglemission.config import MissionFile, TargetConfig
from eaglemission.errors import ConfigError, GrabTimeout
from eaglemission.flight.context import MANIPULATOR, WORLD, SharedContext
from eaglemission.geometry import CameraModel, R_to_quat, quat_to_R, rotation_from_vector
from eaglemission.types import XYZ, Frame, Quat

log = logging.getLogger(__name__)

PoseSource = Callable[[int], "tuple[XYZ, Quat] | None"]


class SyntheticCamera:
    """Renders the synthetic world for one camera of the rig (ground truth in
    ``world.truth(camera_id, seq)``)."""

    description = "Synthetic camera: renders the simulated world from the true vehicle pose"

    class Config(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        exposure_s: float | None = Field(
            default=None, gt=0, le=1.0,
            description="exposure reported in Frame.exposure_s (default: the camera model's)")

    needs_pose = True  # renders from a pose source: the truth, else the vehicle's estimate

    def __init__(self, config: Config | None = None, *, model: CameraModel,
                 clock: Clock | None = None, world: SyntheticWorld | None = None,
                 pose_source: PoseSource | None = None, camera_id: str | None = None,
                 simulation: SyntheticWorldConfig | None = None, target: TargetConfig | None = None,
                 shared: SharedContext | None = None, safety: Any = None,
                 **_context: Any) -> None:
        self.config = config or self.Config()
        self.model = model
        self.camera_id = camera_id or model.camera_id
        self.clock: Clock = clock or MonotonicClock()
        if world is None:
            if simulation is None or target is None:
                raise ConfigError(
                    f"cameras.{self.camera_id}.type: a synthetic camera renders the simulated "
                    "world: add a `world:` section (type: synthetic) to the mission file")
            world = shared_world(shared, simulation, target, safety)
        if pose_source is None:
            raise ConfigError(
                f"cameras.{self.camera_id}: the synthetic camera needs `pose_source`, a "
                "callable host-time -> (position_ned_m, attitude_q) of the TRUE vehicle pose")
        self.world = world
        self.pose_source = pose_source
        self._shared = shared
        self.time_offset_ns = int(round(world.simulation.camera_time_offset_s * 1e9))
        self.seq = 0
        self._open = False
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._remember_loop()
        self.stats = {"frames": 0, "no_pose": 0}

    # -- lifetime --------------------------------------------------------------------------
    def open(self) -> None:
        self._open = True
        self._remember_loop()

    def _remember_loop(self) -> None:
        try:
            self._loop = asyncio.get_running_loop()
        except RuntimeError:
            pass

    def _now_ns(self) -> int:
        """The clock's time; from a worker thread, a loop clock (``LoopClock`` under
        ``VirtualTimeLoop``) is read through the loop captured at construction/open."""
        try:
            return int(self.clock.now_ns())
        except RuntimeError:
            if self._loop is None:
                raise RuntimeError(
                    f"camera {self.camera_id!r}: the clock needs a running event loop; "
                    "construct or open() the camera inside the loop, or use grab_at()"
                ) from None
            return int(round(self._loop.time() * 1e9))

    def close(self) -> None:
        self._open = False

    def __enter__(self) -> SyntheticCamera:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- acquisition -----------------------------------------------------------------------
    def grab(self, *, timeout_s: float) -> Frame:
        """Render a frame stamped now (mid-exposure) from the pose ``camera_time_offset_s``
        earlier. Raises :class:`GrabTimeout` when the pose source has no pose for that time."""
        return self.grab_at(self._now_ns(), timeout_s=timeout_s)

    def grab_at(self, timestamp_ns: int, *, timeout_s: float) -> Frame:
        """Render the frame whose mid-exposure stamp is ``timestamp_ns`` (for callers that
        pace frames themselves, e.g. from a worker thread)."""
        if not timeout_s > 0 or not math.isfinite(timeout_s):
            raise ValueError(f"timeout_s: must be a finite number > 0, got {timeout_s}")
        t_ns = int(timestamp_ns)
        render_ns = t_ns - self.time_offset_ns
        pose = self.pose_source(render_ns)
        if pose is None:
            self.stats["no_pose"] += 1
            raise GrabTimeout(self.camera_id, timeout_s)
        position, attitude = pose
        exposure = self.config.exposure_s if self.config.exposure_s is not None \
            else self.model.exposure_s
        start = None
        if self.world.simulation.motion_blur:
            start = self._exposure_start_pose(render_ns, position, attitude, float(exposure))
        arm = None if self._shared is None else self._shared.get(MANIPULATOR)
        tool = None if arm is None else arm.tool_body_at(render_ns)
        image, truth = self.world.render(self.model, position, attitude, render_ns,
                                         exposure_start_pose=start, tool_body_m=tool,
                                         tool_marker=getattr(arm, "marker", None))
        with self._lock:
            self.seq += 1
            seq = self.seq
        truth = replace(truth, timestamp_ns=t_ns, render_time_ns=render_ns)
        self.world.record_truth(self.camera_id, seq, truth)
        self.stats["frames"] += 1
        return Frame(image, t_ns, self.camera_id, seq, exposure_s=float(exposure))

    def _exposure_start_pose(self, render_ns: int, position: XYZ, attitude: Quat,
                             exposure_s: float) -> tuple[XYZ, Quat] | None:
        """The vehicle pose half an exposure before ``render_ns``: from the true velocity and
        angular velocity when the pose source offers them (``motion_at``), else the pose
        source's own pose then (None: no blur)."""
        motion_at = getattr(self.pose_source, "motion_at", None)
        motion = motion_at(render_ns) if callable(motion_at) else None
        if motion is None:
            return self.pose_source(render_ns - int(round(exposure_s * 0.5e9)))
        return pose_moved_back(position, attitude, motion[0], motion[1], 0.5 * exposure_s)

    def truth(self, seq: int) -> GroundTruth:
        """Ground truth of this camera's frame ``seq`` (side channel)."""
        return self.world.truth(self.camera_id, seq)

    def health(self) -> dict[str, Any]:
        return {"camera_id": self.camera_id, "open": self._open, **self.stats}

    @property
    def frame_rate_hz(self) -> float:
        """The simulated sensor's frame rate (``simulation.frame_rate_hz``)."""
        return float(self.world.simulation.frame_rate_hz)

    def summary(self) -> str:
        return f"renders the simulated world at up to {self.frame_rate_hz:g} fps"

    @classmethod
    def config_problems(cls, mission: MissionFile, path: str) -> list[str]:
        """``validate``: a synthetic camera needs the world it renders."""
        try:
            world = world_config(mission)
        except ValidationError:
            return []  # the world's own params check names what is wrong there
        if world is None:
            return [f"{path}.type: a synthetic camera renders the simulated world: add a "
                    "`world:` section (type: synthetic), or use a real camera (genicam) or "
                    "replay"]
        return []


def pose_moved_back(position_ned_m: XYZ, attitude_q: Quat, velocity_ned_mps: XYZ,
                    angular_velocity_ned_radps: XYZ, dt_s: float) -> tuple[XYZ, Quat]:
    """The pose ``dt_s`` earlier at constant velocity and angular velocity (NED):
    ``p - v dt`` and ``exp(-[w]x dt) R``."""
    p = np.asarray(position_ned_m, np.float64) - np.asarray(velocity_ned_mps, np.float64) * dt_s
    R = rotation_from_vector(-np.asarray(angular_velocity_ned_radps, np.float64) * dt_s) \
        @ quat_to_R(attitude_q)
    return (float(p[0]), float(p[1]), float(p[2])), R_to_quat(R)


def shared_world(shared: SharedContext | None, simulation: SyntheticWorldConfig,
                 target: TargetConfig, safety: Any = None) -> SyntheticWorld:
    """The flight's one world (both cameras render the same; the evaluator reads its target),
    built on first use and kept in the assembly's shared context."""
    def build() -> SyntheticWorld:
        extent = min(1000.0, world_extent_m(simulation, safety))
        world = SyntheticWorld(simulation, target, extent_m=extent)
        world.warm_up()  # texture copies for the fast ground path, before the flight starts
        return world

    return build() if shared is None else shared.get_or_create(WORLD, build)


def world_extent_m(simulation: SyntheticWorldConfig, safety: Any = None) -> float:
    """Side of a square around home covering the geofence, the target and the distractors."""
    reach = [math.hypot(simulation.target_north_m, simulation.target_east_m)]
    reach += [math.hypot(d.north_m, d.east_m) for d in simulation.distractors]
    fence = getattr(safety, "geofence", None)
    if fence is not None:
        reach.append(fence.radius_m or 0.0)
        if fence.polygon_ned_m:
            reach += [math.hypot(n, e) for n, e in fence.polygon_ned_m]
    return 2.0 * (max(reach) + 20.0)


def geofence_extent_m(config: MissionFile) -> float:
    """Side of a square around home covering the geofence, the target and the distractors."""
    return world_extent_m(world_config(config) or SyntheticWorldConfig(), config.safety)


def make_synthetic_rig(config: MissionFile, pose_source: PoseSource, clock: Clock, *,
                       world: SyntheticWorld | None = None) -> Any:
    """The world and both synthetic cameras of a mission file, as a
    :class:`~eaglemission.lab.cameras.rig.CameraRig` (``rig.world`` is the world).

    The cameras use the NOMINAL models of ``config.cameras``; the world renders them with
    the realism knobs of the config's ``world`` applied.
    """
    from eaglemission.lab.cameras.rig import CameraRig

    if world is None:
        world = shared_world(None, world_config(config) or SyntheticWorldConfig(), config.target,
                             config.safety)
    cams = {}
    for cid in ("wide", "narrow"):
        section = getattr(config.cameras, cid)
        params = section.params if section.type == "synthetic" else {}
        cams[cid] = SyntheticCamera(SyntheticCamera.Config(**params),
                                    model=section.to_model(cid), clock=clock, world=world,
                                    pose_source=pose_source, camera_id=cid)
    rig = CameraRig(cams["wide"], cams["narrow"])
    rig.world = world
    return rig
