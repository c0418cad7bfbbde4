"""The one assembly path: a validated :class:`~eaglemission.config.MissionFile` -> plugins ->
a flight.

Every flight goes through here (``eaglemission run``, ``campaign``, the tests and the library
API): the vehicle by its ``type`` and params, both cameras by their ``type``, one detector per
camera, the coarse and fine estimators and the mission, all through
:mod:`eaglemission.registry`. A deployment is a config, not a code path (docs/architecture.md):

* simulation: ``synthetic`` cameras + the ``simulated`` vehicle, virtual time;
* emulator / autopilot SITL: the ``mavsdk`` vehicle at a URL, ``synthetic`` cameras rendering
  from the autopilot's ground truth (HIL_STATE_QUATERNION) when it streams it;
* replay: ``replay`` cameras + the ``replay`` vehicle, a recording played open loop;
* field: ``genicam`` cameras + the ``mavsdk`` vehicle, nothing simulated.

Plugin classes may declare (all optional): ``wall_clock = True`` (needs host time: MAVSDK,
GenICam), ``simulated = True`` (no real aircraft behind it: no arming confirmation),
``start_time_ns(config) -> int | None`` (a recording's first stamp: a virtual-time replay
starts its clock there), ``config_problems(mission_file, path) -> list[str]`` (cross-section
checks for ``validate``), and on instances ``summary() -> str`` (the run header) and, for
vehicles, ``ground_truth() -> GroundTruth | None``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

from eaglemission import registry
from eaglemission.clock import Clock
from eaglemission.config import MissionFile, merge_params
from eaglemission.config.models import SECTIONS
from eaglemission.flight.context import WORLD, SharedContext
from eaglemission.interfaces import (
    FlightParts,
    GroundTruth,
    Judge,
    Manipulator,
    PlaneFitter,
    Section,
    Tracker,
    World,
)
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.perception.appearance import TargetAppearance
from eaglemission.perception.keep import TargetKeeper
from eaglemission.recording.vehicle_tap import VehicleTap
from eaglemission.safety.autopilot_guard import AutopilotGuard
from eaglemission.safety.envelope import SafeVehicle
from eaglemission.types import XYZ, Quat

log = logging.getLogger(__name__)

CAMERAS = (CAMERA_WIDE, CAMERA_NARROW)

# ---------------------------------------------------------------------------------------------
# What a mission file flies (no construction)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlightPlan:
    """Facts about a mission file's parts, from their classes alone."""

    wall_clock: bool
    """Some part needs host time (a real or SITL autopilot, GenICam cameras)."""
    simulated_vehicle: bool
    """The vehicle plugin flies nothing real (no arming confirmation)."""
    start_ns: int | None
    """Where a virtual-time clock starts (a replayed recording's first stamp), None: 1 s."""


def _plugin_classes(cfg: MissionFile) -> dict[str, type]:
    out = {"vehicle": registry.get("vehicles", cfg.vehicle.type)}
    for cid in CAMERAS:
        out[f"cameras.{cid}"] = registry.get("cameras", getattr(cfg.cameras, cid).type)
    return out


def part_classes(cfg: MissionFile) -> list[tuple[str, type]]:
    """``("vehicle.type mavsdk", plugin class)`` of the vehicle and each camera: what
    :func:`eaglemission.extras.require_for` checks before anything is built."""
    names = {"vehicle": cfg.vehicle.type}
    names.update({f"cameras.{cid}": getattr(cfg.cameras, cid).type for cid in CAMERAS})
    return [(f"{k}.type {names[k]}", c) for k, c in _plugin_classes(cfg).items()]


def plan(cfg: MissionFile) -> FlightPlan:
    classes = _plugin_classes(cfg)
    wall = any(bool(getattr(c, "wall_clock", False)) for c in classes.values())
    vcls = classes["vehicle"]
    start = None
    fn = getattr(vcls, "start_time_ns", None)
    if callable(fn):
        start = fn(registry.validate_params("vehicles", cfg.vehicle.type, cfg.vehicle.params,
                                            path="vehicle.params"))
    return FlightPlan(wall_clock=wall, simulated_vehicle=bool(getattr(vcls, "simulated", False)),
                      start_ns=start)


# ---------------------------------------------------------------------------------------------
# Building
# ---------------------------------------------------------------------------------------------
class PoseSource:
    """Where fake sensors see the world from: the vehicle's ground truth when it has one, else
    its own telemetry (a real autopilot that streams no truth; the header says so). Callable
    from any thread."""

    def __init__(self, vehicle: Any) -> None:
        self._vehicle = vehicle
        self.truth: GroundTruth | None = None

    def __call__(self, timestamp_ns: int) -> tuple[XYZ, Quat] | None:
        if self.truth is not None:
            return self.truth.pose_at(timestamp_ns)
        st = self._vehicle.state_at(timestamp_ns)
        return None if st is None else (st.position_ned_m, st.attitude_q)

    def motion_at(self, timestamp_ns: int) -> tuple[XYZ, XYZ] | None:
        """True velocity (NED, m/s) and angular velocity (NED, rad/s) at a time, when the
        truth offers them (the simulated vehicle's does); None otherwise (a synthetic camera
        then differences two poses for its motion blur)."""
        fn = getattr(self.truth, "motion_at", None)
        motion: tuple[XYZ, XYZ] | None = fn(timestamp_ns) if callable(fn) else None
        return motion


@dataclass
class Assembly:
    """The built (not yet connected) plugins of one flight."""

    config: MissionFile
    clock: Clock
    driver: Any
    vehicle: SafeVehicle
    cameras: dict[str, Any]
    detectors: dict[str, Any]
    coarse: Any
    fine: Any
    shared: SharedContext
    pose_source: PoseSource
    truth: GroundTruth | None = None
    fitter: PlaneFitter | None = None
    appearance: TargetAppearance | None = None
    keepers: dict[str, TargetKeeper] = field(default_factory=dict)
    guard: AutopilotGuard | None = None
    manipulator: Manipulator | None = None
    sections: list[Section] = field(default_factory=list)
    """The section plugins of the mission file's extra sections (``faults``), attached."""

    def parts(self, *, realtime: bool) -> FlightParts:
        return FlightParts(config=self.config, clock=self.clock, vehicle=self.vehicle,
                           cameras=self.cameras, detectors=self.detectors, coarse=self.coarse,
                           fine=self.fine, fitter=self.fitter, appearance=self.appearance,
                           keepers=self.keepers, judge=self.judge(),
                           manipulator=self.manipulator, realtime=realtime,
                           autopilot_guard=self.guard)

    def judge(self) -> Judge | None:
        """The judge of the mission's type (:mod:`eaglemission.interfaces.judge`) with the
        world and the ground truth as they are now; None when none is installed."""
        if self.config.mission.type not in registry.available("judges"):
            return None
        judge: Judge = registry.load("judges", self.config.mission.type,
                                     mission_file=self.config, world=self.shared.get(WORLD),
                                     truth=self.truth)
        return judge


def target_appearance(cfg: MissionFile) -> TargetAppearance | None:
    """The target's appearance from ``cfg.target`` and ``cfg.appearance`` (the example image
    read from disk), built once per flight; None when the target section gives neither a
    colour nor an image."""
    if cfg.target.color_bgr is None and not cfg.target.appearance_image:
        return None
    return TargetAppearance.of_target(cfg.target, cfg.appearance)


def build_detector(cfg: MissionFile, camera_id: str,
                   appearance: TargetAppearance | None) -> Any:
    """One camera's detector (``detector.type`` with :func:`detector_params`), followed by the
    appearance prior (``appearance.prior``) when the target has an example image."""
    detector = registry.load("detectors", cfg.detector.type, detector_params(cfg, camera_id),
                             camera_id=camera_id)
    return detector if appearance is None else appearance.with_prior(detector,
                                                                       cfg.appearance.prior)


def build_keeper(cfg: MissionFile, camera_id: str) -> TargetKeeper:
    """One camera's keeper: the ``tracker`` section's plugin and its ``keep`` settings."""
    assert cfg.tracker is not None
    tracker: Tracker = registry.load("trackers", cfg.tracker.type, cfg.tracker.params,
                                     camera_id=camera_id)
    return TargetKeeper(tracker, cfg.tracker.keep)


def detector_params(cfg: MissionFile, camera_id: str) -> dict[str, Any]:
    """The detector params of one camera: ``detector.params`` with that camera's
    ``detector.per_camera`` overrides merged in (nested mappings merge key by key)."""
    over = next((v for k, v in cfg.detector.per_camera.items() if k == camera_id), {})
    return merge_params(cfg.detector.params, over)


def build_world(cfg: MissionFile) -> World | None:
    """The simulated world of ``cfg`` (``world.type``), None when nothing is simulated."""
    if cfg.world is None:
        return None
    world: World = registry.load("worlds", cfg.world.type, cfg.world.params)
    return world


def world_config(cfg: MissionFile) -> Any:
    """The validated world params the fake drivers read (``simulation=`` in their context)."""
    world = build_world(cfg)
    return None if world is None else world.config


def load_sections(cfg: MissionFile) -> list[Section]:
    """The section plugins of ``cfg``'s extra sections (``faults``: the lab's fault
    injection), built in :data:`~eaglemission.config.models.SECTIONS` order."""
    return [registry.load("sections", name, getattr(cfg, name)) for name in SECTIONS
            if getattr(cfg, name) is not None]


def prepared(cfg: MissionFile, sections: list[Section]) -> MissionFile:
    """``cfg`` as the section plugins change it before the vehicle is built (a relay's URL)."""
    for section in sections:
        cfg = section.prepare(cfg)
    return cfg


def close_sections(sections: list[Section]) -> None:
    for section in sections:
        try:
            section.close()
        except Exception as exc:  # noqa: BLE001 - closing must go on
            log.warning("section %s: close failed: %s", type(section).__name__, exc)


def build_vehicle(cfg: MissionFile, clock: Clock, shared: SharedContext, *,
                  tap: bool = False) -> tuple[Any, SafeVehicle]:
    """The vehicle plugin of ``cfg`` and its envelope wrapper (not connected); ``tap``: a
    :class:`~eaglemission.recording.vehicle_tap.VehicleTap` between them (a recorded flight)."""
    driver = registry.load("vehicles", cfg.vehicle.type, cfg.vehicle.params, clock=clock,
                           safety=cfg.safety, simulation=world_config(cfg), shared=shared)
    inner = VehicleTap(driver, clock) if tap else driver
    return driver, SafeVehicle(inner, cfg.safety, clock=clock,
                               logger=logging.getLogger("eaglemission.safety.envelope"))


def assemble(cfg: MissionFile, clock: Clock, *,
             vehicle: tuple[Any, SafeVehicle, SharedContext] | None = None,
             sections: list[Section] | None = None) -> Assembly:
    """Build every plugin of ``cfg`` through the registry (no I/O: nothing connects or opens;
    ``vehicle`` passes one already built by :func:`build_vehicle`, ``sections`` the section
    plugins :func:`load_sections` built and :func:`prepared` applied to ``cfg``).

    Raises :class:`ConfigError` / :class:`PluginError` with the YAML path of the part."""
    if sections is None:
        sections = load_sections(cfg)
        cfg = prepared(cfg, sections)
    if vehicle is None:
        shared = SharedContext()
        driver, safe = build_vehicle(cfg, clock, shared)
    else:
        driver, safe, shared = vehicle
    pose = PoseSource(driver)
    simulation = world_config(cfg)
    cameras: dict[str, Any] = {}
    for cid in CAMERAS:
        section = getattr(cfg.cameras, cid)
        cameras[cid] = registry.load(
            "cameras", section.type, section.params, model=section.to_model(cid), clock=clock,
            camera_id=cid, target=cfg.target, simulation=simulation, safety=cfg.safety,
            shared=shared, pose_source=pose)
    appearance = target_appearance(cfg)
    detectors = {cid: build_detector(cfg, cid, appearance) for cid in CAMERAS}
    keepers = {cid: build_keeper(cfg, cid) for cid in CAMERAS} if cfg.tracker else {}
    coarse = registry.load("estimators", cfg.estimators.coarse.type,
                           cfg.estimators.coarse.params, target=cfg.target)
    fine = registry.load("estimators", cfg.estimators.fine.type, cfg.estimators.fine.params,
                         target=cfg.target)
    fs = cfg.estimators.fitter
    fitter = None if fs is None else registry.load("fitters", fs.type, fs.params,
                                                   target=cfg.target)
    manipulator: Manipulator = registry.load(
        "manipulators", cfg.manipulator.type, cfg.manipulator.params, vehicle=safe, clock=clock,
        tool_point_m=cfg.tool_point_m, shared=shared)
    asm = Assembly(cfg, clock, driver, safe, cameras, detectors, coarse, fine, shared, pose,
                   fitter=fitter, appearance=appearance, keepers=keepers,
                   manipulator=manipulator,
                   sections=sections)
    for section in sections:
        section.attach(asm)  # e.g. wraps the parts injected faults live in
    return asm


def describe_part(obj: Any, name: str) -> str:
    fn = getattr(obj, "summary", None)
    extra = ""
    if callable(fn):
        try:
            extra = str(fn())
        except Exception as exc:  # noqa: BLE001 - a header line must not stop a flight
            extra = f"(summary failed: {exc})"
    return f"{name} ({extra})" if extra else name


def header_lines(asm: Assembly, *, virtual: bool) -> list[str]:
    cfg = asm.config
    lines = [f"vehicle: {describe_part(asm.driver, cfg.vehicle.type)}"]
    for cid in CAMERAS:
        cam = asm.cameras[cid]
        m = cam.model
        lines.append(f"camera {cid}: {describe_part(cam, getattr(cfg.cameras, cid).type)}, "
                     f"{m.width_px}x{m.height_px} px, fx {m.fx:.0f} px")
    lines.append(f"detector: {cfg.detector.type} {dict(cfg.detector.params) or ''}".rstrip())
    lines.append(f"estimators: coarse {cfg.estimators.coarse.type}, "
                 f"fine {cfg.estimators.fine.type}")
    if asm.manipulator is not None:
        lines.append(f"manipulator: {describe_part(asm.manipulator, cfg.manipulator.type)}")
    lines.append(f"mission: {cfg.mission.type}")
    lines.append("clock: " + ("virtual time (faster than real time)" if virtual
                              else "wall clock (real time)"))
    if asm.truth is not None:
        lines.append(f"ground truth: {asm.truth.description} (fake sensors render from it; "
                     "the evaluator judges on it)")
    elif any(getattr(c, "needs_pose", False) for c in asm.cameras.values()):
        lines.append("ground truth: none: the synthetic cameras render from the autopilot's "
                     "own estimate and the evaluator judges on it")
    else:
        lines.append("ground truth: none")
    return lines
