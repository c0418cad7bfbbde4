"""YAML mission configuration -> validated, frozen pydantic models.

``yaml.safe_load`` semantics only (no python object tags), duplicate keys rejected. Every error
names the YAML path, the bad value and the fix, e.g.
``cameras.narrow.focal_length_mm: must be > 0, got -12``. Plugin ``params`` are validated by the
plugin's own ``Config`` model, found through the registry.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from eaglemission import registry
from eaglemission.config.errors import format_validation_error
from eaglemission.errors import ConfigError, PluginError
from eaglemission.geometry import CameraModel, CameraMount
from eaglemission.perception.appearance import AppearanceConfig
from eaglemission.perception.keep import KeepConfig

DEFAULT_CONFIG = "sitl_synthetic.yaml"

PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
XYZm = tuple[Finite, Finite, Finite]


class StrictModel(BaseModel):
    """Frozen, rejects unknown keys and non-finite numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=False)


# ---------------------------------------------------------------------------------------------
# Sections
# ---------------------------------------------------------------------------------------------
class PluginSection(StrictModel):
    """``{type: <entry-point name>, params: {...}}``; params validated by the plugin's Config."""

    type: str
    params: dict[str, Any] = Field(default_factory=dict)


class MountConfig(StrictModel):
    """Camera mount on the body (docs/conventions.md): Euler angles of camera FRD w.r.t. body
    FRD; ``pitch_deg: -30`` = optical axis 30 deg below the horizontal. Lever arm in body FRD."""

    roll_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    pitch_deg: Annotated[float, Field(ge=-90, le=90)] = -30.0
    yaw_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    lever_arm_m: XYZm = (0.0, 0.0, 0.0)


class CameraSection(StrictModel):
    """One camera: plugin, intrinsics (lens or calibration file) and mount."""

    type: str
    params: dict[str, Any] = Field(default_factory=dict)
    focal_length_mm: PosFloat | None = None
    pixel_size_um: PosFloat = 3.75
    resolution_px: tuple[Annotated[int, Field(gt=0, le=20000)], Annotated[int, Field(gt=0, le=20000)]] = (1280, 960)
    distortion: tuple[Finite, ...] = ()
    calibration_file: str | None = None
    shutter: Literal["global", "rolling"] = "global"
    exposure_s: Annotated[float, Field(gt=0, le=1.0)] = 0.005
    mount: MountConfig = Field(default_factory=MountConfig)

    def to_model(self, camera_id: str) -> CameraModel:
        """The :class:`CameraModel` this section describes (lens or calibration file)."""
        mount = CameraMount(self.mount.roll_deg, self.mount.pitch_deg, self.mount.yaw_deg,
                            self.mount.lever_arm_m)
        if self.calibration_file is not None:
            from eaglemission.geometry.calibration import load_calibration

            cal = load_calibration(self.calibration_file)
            return CameraModel(camera_id, cal.width_px, cal.height_px, cal.K,
                               distortion=tuple(cal.distortion), pixel_size_um=self.pixel_size_um,
                               shutter=self.shutter, exposure_s=self.exposure_s, mount=mount)
        assert self.focal_length_mm is not None
        return CameraModel.from_lens(
            camera_id, focal_length_mm=self.focal_length_mm, pixel_size_um=self.pixel_size_um,
            resolution_px=self.resolution_px, mount=mount, distortion=tuple(self.distortion),
            shutter=self.shutter, exposure_s=self.exposure_s)

    @model_validator(mode="after")
    def _one_intrinsics_source(self) -> CameraSection:
        if self.focal_length_mm is None and self.calibration_file is None:
            raise ValueError("give focal_length_mm (with pixel_size_um, resolution_px) or calibration_file")
        if self.distortion and len(self.distortion) not in (4, 5, 8, 12, 14):
            raise ValueError(
                f"distortion: OpenCV takes 4, 5, 8, 12 or 14 coefficients, got {len(self.distortion)}"
            )
        return self


class CamerasSection(StrictModel):
    wide: CameraSection
    narrow: CameraSection


class DetectorSection(PluginSection):
    """The detector: one instance per camera, each built from ``params`` with that camera's
    ``per_camera`` overrides merged in (e.g. ``per_camera: {narrow: {regions: {threshold:
    otsu}}}``, the paper's adaptive threshold for the deep fovea)."""

    per_camera: dict[Literal["wide", "narrow"], dict[str, Any]] = Field(default_factory=dict)


class TrackerSection(PluginSection):
    """The tracker that keeps the target between the detector's frames (``type``: a
    ``trackers`` plugin, ``params`` its own) and how it keeps it (``keep``)."""

    keep: KeepConfig = Field(default_factory=KeepConfig)


class EstimatorsSection(StrictModel):
    """The coarse (wide camera) and fine (narrow camera) estimators, and the plane fitter that
    refines their detections on the plane of the target's top (``fitter: null``: none)."""

    coarse: PluginSection
    fine: PluginSection
    fitter: PluginSection | None = Field(
        default_factory=lambda: PluginSection(type="top_plane"))


class TargetConfig(StrictModel):
    """The target is a box; its top face (length x width) is the PnP model. ``length_m`` runs
    along the target's heading. ``color_bgr`` (optional): its colour. ``appearance_image``
    (optional): an example image of the target (a tight crop, or a photo on a plain
    background), relative to the mission file. What perception makes of either is the
    ``appearance`` section (docs/detectors.md)."""

    length_m: PosFloat
    width_m: PosFloat
    height_m: NonNegFloat = 0.0
    color_bgr: tuple[Annotated[int, Field(ge=0, le=255)], ...] | None = None
    appearance_image: str | None = None

    @model_validator(mode="after")
    def _colour(self) -> TargetConfig:
        if self.color_bgr is not None and len(self.color_bgr) != 3:
            raise ValueError(f"color_bgr: needs 3 values (B, G, R), got {len(self.color_bgr)}")
        return self

    @property
    def aspect_ratio(self) -> float:
        return max(self.length_m, self.width_m) / min(self.length_m, self.width_m)


class RoutePoint(StrictModel):
    """A cruise waypoint in local NED metres relative to home (``route_frame: ned_home``)."""

    north_m: Finite
    east_m: Finite


SafeAction = Literal["hold", "return", "land"]


class MissionConfig(StrictModel):
    """The mission: its plugin (``type``, ``params``: the approach's are in
    docs/configuration.md under ``ApproachConfig``) and the route it cruises."""

    type: str = "approach"
    params: dict[str, Any] = Field(default_factory=dict)
    route_frame: Literal["ned_home"] = "ned_home"
    route: Annotated[list[RoutePoint], Field(min_length=1)]
    cruise_altitude_m: PosFloat = 6.0
    cruise_speed_mps: PosFloat = 2.0


class GeofenceConfig(StrictModel):
    """A circle around home (``radius_m``) or a polygon of NED (north_m, east_m) vertices."""

    radius_m: PosFloat | None = 100.0
    polygon_ned_m: list[tuple[Finite, Finite]] | None = None

    @model_validator(mode="after")
    def _shape(self) -> GeofenceConfig:
        if self.polygon_ned_m is not None and len(self.polygon_ned_m) < 3:
            raise ValueError(f"polygon_ned_m: needs at least 3 vertices, got {len(self.polygon_ned_m)}")
        if self.radius_m is None and self.polygon_ned_m is None:
            raise ValueError("give radius_m or polygon_ned_m")
        return self


class SafetyConfig(StrictModel):
    """The envelope every setpoint goes through. Altitudes are relative to home (up)."""

    geofence: GeofenceConfig = Field(default_factory=GeofenceConfig)
    min_altitude_m: NonNegFloat = 0.0
    max_altitude_m: PosFloat = 30.0
    max_horizontal_speed_mps: PosFloat = 5.0
    max_vertical_speed_mps: PosFloat = 2.0
    on_violation: Literal["clamp", "refuse"] = "clamp"
    altitude_reference: Literal["estimate", "rangefinder"] = "rangefinder"
    """What the altitude band is held on. ``rangefinder``: while the vehicle reports a fresh
    downward range (tilt <= 30 deg), on the height above the ground under the vehicle (range x
    cos tilt), the altitude estimate otherwise. PX4's EKF is 0.2-0.5 m off vertically near the
    ground (recorded: a hold 0.7 m up by the estimate sat on the ground for 13 s), more than the
    band's margin. ``estimate``: always the altitude estimate (relative to home)."""
    rangefinder_max_correction_m: Annotated[float, Field(gt=0, le=10)] = 1.0
    """A range that disagrees with the altitude estimate by more than this is not trusted (the
    band falls back to the estimate and the event is logged)."""
    link_loss_timeout_s: PosFloat = 1.5
    max_telemetry_age_s: Annotated[float, Field(gt=0, le=10)] = 0.5
    """Telemetry older than this (by the autopilot's timestamps: a delayed link) counts as
    lost: after ``link_loss_timeout_s`` more the link-loss failsafe acts."""
    link_loss_action: SafeAction = "return"
    gps_loss_action: SafeAction = "land"
    low_battery_fraction: Fraction = 0.2
    low_battery_action: SafeAction = "return"
    offboard_watchdog_s: PosFloat = 0.5
    on_interrupt: SafeAction = "return"
    """What the first Ctrl-C / SIGTERM during ``eaglemission run`` commands (through the
    envelope); a second signal exits at once."""
    interrupt_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 120.0
    """How long ``run`` waits for that action (landed, or the mode confirmed) before giving up."""
    autopilot_params: Literal["set", "refuse"] = "set"
    """The autopilot's own parameters that would take the vehicle outside this envelope
    (RTL_RETURN_ALT above ``max_altitude_m``, MPC_Z_V_AUTO_UP above
    ``max_vertical_speed_mps``...; docs/vehicles.md): ``set`` puts them inside before the
    flight, logs each change and restores the old values after it; ``refuse`` does not fly
    and names the parameter and the envelope key. ``set`` is the default for every vehicle:
    PX4's defaults (a 30 m return at 3 m/s) are what left the envelope, and the values are
    restored after landing; choose ``refuse`` when the autopilot's parameters are managed
    elsewhere and must not be written."""

    @model_validator(mode="after")
    def _band(self) -> SafetyConfig:
        if self.min_altitude_m >= self.max_altitude_m:
            raise ValueError(
                f"min_altitude_m ({self.min_altitude_m}) must be below max_altitude_m ({self.max_altitude_m})"
            )
        return self


class RecordingConfig(StrictModel):
    """Record every flight of this file as MCAP (docs/recording.md); ``run --record FILE.mcap``
    replaces ``path``, ``run --no-record`` turns it off. ``path`` is relative to the mission
    file's folder; ``{utc}`` becomes the flight's start time, UTC (``20261201T101502Z``); an existing file
    is never overwritten (the flight is refused)."""

    path: Annotated[str, Field(min_length=1)] = "flights/{utc}.mcap"
    quality: Annotated[int, Field(ge=1, le=100)] = 75
    """JPEG quality of the images (``--record-quality`` overrides)."""
    split_mb: PosFloat | None = None
    """Close the file once it holds this many MB (a valid file, footer and index) and go on in
    ``NAME.001.mcap``, ``NAME.002.mcap``... (each readable alone); ``null``: one file."""
    min_free_mb: NonNegFloat = 1000.0
    """Refuse to take off (exit 5) when the recording's disk has less free space than this;
    ``run --dry-run`` reports the figure."""


class LiveConfig(StrictModel):
    """Serve every flight of this file live in Foxglove (docs/recording.md, "Live view in
    Foxglove"): the recording's channels over the Foxglove WebSocket protocol, thumbnails and
    telemetry throttled for a radio link. ``run --live HOST:PORT`` replaces ``listen``,
    ``run --no-live`` turns it off; needs ``pip install eaglemission[live]``."""

    listen: str = "127.0.0.1:8765"
    """``HOST:PORT`` to listen on; localhost unless told otherwise (``0.0.0.0:8765``: every
    interface, e.g. the radio's)."""
    image_hz: Annotated[float, Field(gt=0, le=100)] = 2.0
    """Thumbnails per camera and second of flight, at most."""
    image_width_px: Annotated[int, Field(ge=16, le=8192)] = 320
    jpeg_quality: Annotated[int, Field(ge=1, le=100)] = 60
    telemetry_hz: Annotated[float, Field(gt=0, le=1000)] = 10.0
    """``telemetry`` and ``setpoint`` records per second of flight, at most (the other
    records, rarer, are all sent)."""

    @model_validator(mode="after")
    def _listen(self) -> LiveConfig:
        from eaglemission.recording.live import parse_listen

        parse_listen(self.listen, where="listen")
        return self


class MissionFile(StrictModel):
    """A whole mission configuration file."""

    vehicle: PluginSection
    cameras: CamerasSection
    detector: DetectorSection
    tracker: TrackerSection | None = Field(
        default_factory=lambda: TrackerSection(type="csrt"))
    """Keeps the confirmed target between the detector's frames; ``null``: the detector on
    every frame alone."""
    appearance: AppearanceConfig = Field(default_factory=AppearanceConfig)
    """How the target's appearance (``target.color_bgr``, ``target.appearance_image``) is
    modelled, and the appearance prior stage after the detector."""
    estimators: EstimatorsSection
    target: TargetConfig
    tool_point_m: XYZm = (0.0, 0.0, 0.3)
    """The tool's home point in body FRD: a ``fixed`` tool is there, an arm's workspace is
    centred on it (docs/manipulators.md)."""
    manipulator: PluginSection = Field(default_factory=lambda: PluginSection(type="fixed"))
    """The tool under the vehicle (``eaglemission plugins`` lists the ``manipulators``):
    ``fixed`` (a rigid tool at ``tool_point_m``, the autopilot's gripper), an arm that closes
    the last centimetres itself (docs/manipulators.md)."""
    mission: MissionConfig
    safety: SafetyConfig = Field(default_factory=SafetyConfig)
    recording: RecordingConfig | None = None
    """Record every flight as MCAP (``null``: only with ``run --record``)."""
    live: LiveConfig | None = None
    """Serve every flight live in Foxglove (``null``: only with ``run --live``)."""
    world: PluginSection | None = None
    """The simulated world the fake drivers share (ground truth; ``eaglemission plugins``
    lists the ``worlds``); ``null`` for flights with nothing simulated."""
    faults: dict[str, Any] | None = None
    """Faults injected during the flight (docs/faults.md; the ``faults`` section plugin of the
    lab validates and injects them); ``null``: none."""


# ---------------------------------------------------------------------------------------------
# YAML loading
# ---------------------------------------------------------------------------------------------
class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys (yaml.safe_load keeps the last silently)."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    loader.flatten_mapping(node)
    out: dict[Any, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(
                None, None, "a mapping key must be a plain value", key_node.start_mark) from None
        if key in out:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark)
        out[key] = loader.construct_object(value_node, deep=deep)
    return out


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def parse_yaml(text: str, *, source: str = "<string>") -> Any:
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = exc.problem or exc.context or "invalid YAML"
        if "could not determine a constructor" in str(exc):
            problem += " (python/object tags are not allowed: write plain YAML values)"
        raise ConfigError(f"{where}YAML error: {problem}", source=source) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"YAML error: {exc}", source=source) from None
    except RecursionError:
        raise ConfigError("YAML error: nested too deeply", source=source) from None


def read_config_text(path: str | Path) -> str:
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"file not found: check the path {str(p)!r}", source=str(p))
    if p.is_dir():
        raise ConfigError("is a directory: give a YAML file", source=str(p))
    data = p.read_bytes()
    if b"\x00" in data:
        raise ConfigError("binary file, not YAML text: give a YAML mission file", source=str(p))
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"not UTF-8 text (byte {exc.start}): save the file as UTF-8",
                          source=str(p)) from None


def validate_mapping(data: Any, *, source: str = "<config>",
                     check_plugins: bool = True) -> MissionFile:
    """Validate a parsed YAML document; raise :class:`ConfigError` listing every problem."""
    if data is None:
        raise ConfigError("empty file: a mission needs the sections " + ", ".join(
            f for f, info in MissionFile.model_fields.items() if info.is_required()), source=source)
    if not isinstance(data, dict):
        raise ConfigError(
            f"<top level>: must be a mapping of sections, got {type(data).__name__}", source=source)
    bad_keys = [k for k in data if not isinstance(k, str)]
    if bad_keys:
        raise ConfigError(f"<top level>: section names must be strings, got {bad_keys[0]!r}",
                          source=source)
    try:
        cfg = MissionFile.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, model=MissionFile), source=source) from None
    except (RecursionError, TypeError, ValueError) as exc:
        raise ConfigError(f"<top level>: cannot validate: {exc}", source=source) from None
    if check_plugins:
        problems = plugin_problems(cfg)
        if problems:
            raise ConfigError(problems, source=source)
    return cfg


def plugin_sections(cfg: MissionFile) -> list[tuple[str, str, str, dict[str, Any]]]:
    """(role, yaml path, plugin name, params) for every plugin the config names."""
    return [
        ("vehicles", "vehicle", cfg.vehicle.type, cfg.vehicle.params),
        ("cameras", "cameras.wide", cfg.cameras.wide.type, cfg.cameras.wide.params),
        ("cameras", "cameras.narrow", cfg.cameras.narrow.type, cfg.cameras.narrow.params),
        ("detectors", "detector", cfg.detector.type, cfg.detector.params),
        *[("detectors", f"detector.per_camera.{cid}", cfg.detector.type,
           merge_params(cfg.detector.params, over))
          for cid, over in cfg.detector.per_camera.items()],
        ("estimators", "estimators.coarse", cfg.estimators.coarse.type, cfg.estimators.coarse.params),
        ("estimators", "estimators.fine", cfg.estimators.fine.type, cfg.estimators.fine.params),
        *([("fitters", "estimators.fitter", cfg.estimators.fitter.type,
            cfg.estimators.fitter.params)] if cfg.estimators.fitter is not None else []),
        ("missions", "mission", cfg.mission.type, cfg.mission.params),
        ("manipulators", "manipulator", cfg.manipulator.type, cfg.manipulator.params),
        *([("trackers", "tracker", cfg.tracker.type, cfg.tracker.params)]
          if cfg.tracker is not None else []),
        *([("worlds", "world", cfg.world.type, cfg.world.params)]
          if cfg.world is not None else []),
        *[("sections", name, name, getattr(cfg, name)) for name in SECTIONS
          if getattr(cfg, name) is not None],
    ]


#: Mission-file sections that a section plugin of the same name validates and flies
#: (:mod:`eaglemission.interfaces.section`); the core never reads them.
SECTIONS: tuple[str, ...] = ("faults",)


def params_path(role: str, path: str) -> str:
    """The YAML path of a plugin's params: ``<section>.params``, a section plugin's own
    section."""
    return path if role == "sections" else f"{path}.params"


def merge_params(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` merged in, nested mappings key by key (a new dict)."""
    out = dict(base)
    for k, v in over.items():
        cur = out.get(k)
        out[k] = merge_params(cur, v) if isinstance(v, Mapping) and isinstance(cur, Mapping) else v
    return out


def plugin_problems(cfg: MissionFile) -> list[str]:
    problems: list[str] = []
    for role, path, name, params in plugin_sections(cfg):
        try:
            registry.validate_params(role, name, params, path=params_path(role, path))
        except ConfigError as exc:
            problems.extend(exc.problems)
            continue
        except PluginError as exc:
            problems.append(f"{path}.type: {exc}")
            continue
        check = getattr(registry.get(role, name), "config_problems", None)
        if callable(check) and ".per_camera." not in path:
            try:
                problems.extend(check(cfg, path))
            except Exception as exc:  # a broken plugin check must not hide the others
                problems.append(f"{path}: the plugin's check failed: {type(exc).__name__}: {exc}")
    return problems


def load_config(path: str | Path | None = None, *, check_plugins: bool = True) -> MissionFile:
    """Load and validate a mission file; ``None`` loads the embedded default
    (``configs/sitl_synthetic.yaml``)."""
    if path is None:
        text = resources.files("eaglemission.configs").joinpath(DEFAULT_CONFIG).read_text("utf-8")
        source = f"<embedded {DEFAULT_CONFIG}>"
    else:
        text = read_config_text(path)
        source = str(path)
    cfg = validate_mapping(parse_yaml(text, source=source), source=source,
                           check_plugins=check_plugins)
    base = Path(path).resolve().parent if path is not None else None
    return resolve_relative_paths(cfg, base)


def resolve_relative_paths(cfg: MissionFile, base_dir: Path | None) -> MissionFile:
    """Make ``cameras.*.calibration_file``, ``target.appearance_image`` and ``recording.path``
    absolute, relative to the mission file's folder (the embedded configs resolve against the installed
    ``eaglemission.configs`` package)."""
    if base_dir is None:
        base_dir = Path(str(resources.files("eaglemission.configs")))
    cams = {}
    for name in ("wide", "narrow"):
        cam = getattr(cfg.cameras, name)
        if cam.calibration_file is not None and not Path(cam.calibration_file).is_absolute():
            cam = cam.model_copy(update={"calibration_file": str(base_dir / cam.calibration_file)})
        cams[name] = cam
    update: dict[str, Any] = {"cameras": cfg.cameras.model_copy(update=cams)}
    image = cfg.target.appearance_image
    if image is not None and not Path(image).is_absolute():
        update["target"] = cfg.target.model_copy(
            update={"appearance_image": str(base_dir / image)})
    rec = cfg.recording
    if rec is not None and not Path(rec.path).is_absolute():
        update["recording"] = rec.model_copy(update={"path": str(base_dir / rec.path)})
    return cfg.model_copy(update=update)

