"""YAML mission configuration -> validated, frozen pydantic models.

``yaml.safe_load`` semantics only (no python object tags), duplicate keys rejected. Every error
names the YAML path, the bad value and the fix, e.g.
``cameras.narrow.focal_length_mm: must be > 0, got -12``. Plugin ``params`` are validated by the
plugin's own ``Config`` model, found through the registry.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from eaglemission.errors import ConfigError, PluginError
from eaglemission.geometry import CameraModel, CameraMount

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
                            tuple(self.mount.lever_arm_m))  # type: ignore[arg-type]
        if self.calibration_file is not None:
            from eaglemission.calibration import load_calibration

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


class EstimatorsSection(StrictModel):
    coarse: PluginSection
    fine: PluginSection


class TargetConfig(StrictModel):
    """The target is a box; its top face (length x width) is the PnP model. ``length_m`` runs
    along the target's heading. ``appearance_image`` (optional) is an example image of the
    target (a tight crop, or a photo on a plain background), relative to the mission file;
    detectors that use one get it as their ``appearance`` (docs/detectors.md)."""

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


class StandoffConfig(StrictModel):
    """Where the vehicle waits for the grasp, relative to the target's top-face centre: a
    horizontal offset (along the approach direction) and a height, so the fixed, tilted
    cameras still see the target."""

    horizontal_m: NonNegFloat = 1.0
    height_m: PosFloat = 1.0


class TimeoutsConfig(StrictModel):
    preflight_s: PosFloat = 30.0
    takeoff_s: PosFloat = 60.0
    cruise_s: PosFloat = 600.0
    coarse_approach_s: PosFloat = 120.0
    fine_approach_s: PosFloat = 120.0
    grasp_ready_s: PosFloat = 30.0
    target_lost_s: PosFloat = 20.0
    command_s: PosFloat = 10.0


SafeAction = Literal["hold", "return", "land"]


class MissionConfig(StrictModel):
    """The approach-to-grasp mission (paper Sec. 3.2)."""

    type: str = "approach"
    params: dict[str, Any] = Field(default_factory=dict)
    route_frame: Literal["ned_home"] = "ned_home"
    route: Annotated[list[RoutePoint], Field(min_length=1)]
    cruise_altitude_m: PosFloat = 6.0
    cruise_speed_mps: PosFloat = 2.0
    approach_speed_mps: PosFloat = 1.0
    confirm_frames: Annotated[int, Field(ge=1, le=1000)] = 3
    grasp_distance_m: Annotated[float, Field(gt=0, le=2.0)] = 0.175
    grasp_tolerance_m: Annotated[float, Field(gt=0, le=1.0)] = 0.05
    grasp_stable_frames: Annotated[int, Field(ge=1, le=1000)] = 5
    standoff: StandoffConfig = Field(default_factory=StandoffConfig)
    timeouts: TimeoutsConfig = Field(default_factory=TimeoutsConfig)
    on_target_lost: Literal["resume_cruise", "return", "land", "hold"] = "resume_cruise"
    on_done: Literal["land", "return", "hold"] = "land"
    grasp_action: Literal["gripper", "callback", "none"] = "gripper"
    setpoint_rate_hz: Annotated[float, Field(ge=10, le=100)] = 20.0


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
    link_loss_timeout_s: PosFloat = 1.5
    link_loss_action: SafeAction = "return"
    gps_loss_action: SafeAction = "land"
    low_battery_fraction: Fraction = 0.2
    low_battery_action: SafeAction = "return"
    offboard_watchdog_s: PosFloat = 0.5

    @model_validator(mode="after")
    def _band(self) -> SafetyConfig:
        if self.min_altitude_m >= self.max_altitude_m:
            raise ValueError(
                f"min_altitude_m ({self.min_altitude_m}) must be below max_altitude_m ({self.max_altitude_m})"
            )
        return self


class DistractorConfig(StrictModel):
    kind: Literal["box", "disc", "stripe", "moving_box"] = "box"
    north_m: Finite
    east_m: Finite
    size_m: PosFloat = 0.5
    height_m: NonNegFloat = 0.1
    color_bgr: tuple[int, int, int] = (40, 40, 200)
    velocity_ne_mps: tuple[Finite, Finite] = (0.0, 0.0)


class SimulationConfig(StrictModel):
    """The simulated world (ground truth). Only fake drivers and the evaluator read it."""

    seed: int = 0
    target_north_m: Finite = 20.0
    target_east_m: Finite = 5.0
    target_yaw_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    ground_texture: Literal["vegetation", "soil", "snow", "grass"] = "vegetation"
    distractors: list[DistractorConfig] = Field(default_factory=list)
    light_gain: Annotated[float, Field(gt=0, le=4)] = 1.0
    noise_sigma: Annotated[float, Field(ge=0, le=50)] = 2.0
    wind_ne_mps: tuple[Finite, Finite] = (0.0, 0.0)
    mount_error_deg: Annotated[float, Field(ge=0, le=10)] = 0.0
    focal_error_fraction: Annotated[float, Field(ge=0, le=0.2)] = 0.0
    camera_time_offset_s: Annotated[float, Field(ge=0, le=0.2)] = 0.0
    frame_rate_hz: Annotated[float, Field(gt=0, le=200)] = 30.0


class MissionFile(StrictModel):
    """A whole mission configuration file."""

    vehicle: PluginSection
    cameras: CamerasSection
    detector: PluginSection
    estimators: EstimatorsSection
    target: TargetConfig
    tool_point_m: XYZm = (0.0, 0.0, 0.3)
    mission: MissionConfig
    safety: SafetyConfig = Field(default_factory=SafetyConfig)
    simulation: SimulationConfig | None = None


# ---------------------------------------------------------------------------------------------
# Error formatting
# ---------------------------------------------------------------------------------------------
def _path(loc: tuple[Any, ...], prefix: str = "") -> str:
    parts: list[str] = [prefix] if prefix else []
    for item in loc:
        if isinstance(item, int):
            if parts:
                parts[-1] += f"[{item}]"
            else:
                parts.append(f"[{item}]")
        elif item in ("function-after", "function-before"):
            continue
        else:
            parts.append(str(item))
    return ".".join(parts) or "<top level>"


def _fields_at(model: type[BaseModel] | None, loc: tuple[Any, ...]) -> list[str]:
    """Field names of the (nested) model that owns ``loc[:-1]``, for suggestions."""
    current: Any = model
    for item in loc[:-1]:
        if isinstance(item, int) or current is None:
            continue
        fields = getattr(current, "model_fields", None)
        if not fields or item not in fields:
            return []
        ann = fields[item].annotation
        current = _model_in(ann)
    fields = getattr(current, "model_fields", None)
    return list(fields) if fields else []


def _model_in(ann: Any) -> Any:
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return ann
    for arg in getattr(ann, "__args__", ()) or ():
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _message(err: Mapping[str, Any], model: type[BaseModel] | None) -> str:
    kind = err["type"]
    ctx = err.get("ctx") or {}
    value = err.get("input")
    loc = tuple(err["loc"])
    if kind == "extra_forbidden":
        names = _fields_at(model, loc)
        close = difflib.get_close_matches(str(loc[-1]), names, n=1) if names else []
        hint = f"did you mean {close[0]!r}?" if close else (
            f"allowed keys: {', '.join(names)}" if names else "remove it")
        return f"unknown key; {hint}"
    if kind == "missing":
        return "required key is missing: add it"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<",
              "less_than_equal": "<="}[kind]
        bound = next(iter(ctx.values()), "?")
        if isinstance(bound, float):
            bound = f"{bound:g}"
        return f"must be {op} {bound}, got {_short(value)}"
    if kind == "finite_number":
        return f"must be a finite number, got {_short(value)}"
    if kind in ("float_type", "float_parsing", "int_type", "int_parsing", "int_from_float"):
        what = "an integer" if kind.startswith("int") else "a number"
        return f"must be {what}, got {_short(value)}"
    if kind in ("bool_type", "bool_parsing"):
        return f"must be true or false, got {_short(value)}"
    if kind in ("string_type",):
        return f"must be a string, got {_short(value)}"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected', '?')}, got {_short(value)}"
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        return f"must be a mapping (key: value), got {_short(value)}"
    if kind in ("list_type", "tuple_type"):
        return f"must be a list, got {_short(value)}"
    if kind in ("too_short", "too_long"):
        return f"{err['msg'].lower()}, got {_short(value)}"
    if kind == "value_error":
        return str(ctx.get("error", err["msg"]))
    return f"{err['msg']}, got {_short(value)}"


def format_validation_error(
    exc: ValidationError, *, prefix: str = "", model: type[BaseModel] | None = None
) -> list[str]:
    """One ``path: problem`` line per pydantic error."""
    lines = []
    for err in exc.errors(include_url=False):
        loc = tuple(err["loc"])
        lines.append(f"{_path(loc, prefix)}: {_message(err, model)}")
    return lines


# ---------------------------------------------------------------------------------------------
# YAML loading
# ---------------------------------------------------------------------------------------------
class _UniqueKeyLoader(yaml.SafeLoader):  # type: ignore[misc]
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


def validate_mapping(data: Any, *, source: str = "<config>", check_plugins: bool = True) -> MissionFile:
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
        ("estimators", "estimators.coarse", cfg.estimators.coarse.type, cfg.estimators.coarse.params),
        ("estimators", "estimators.fine", cfg.estimators.fine.type, cfg.estimators.fine.params),
        ("missions", "mission", cfg.mission.type, cfg.mission.params),
    ]


def plugin_problems(cfg: MissionFile) -> list[str]:
    from eaglemission import registry

    problems: list[str] = []
    for role, path, name, params in plugin_sections(cfg):
        try:
            registry.validate_params(role, name, params, path=f"{path}.params")
        except ConfigError as exc:
            problems.extend(exc.problems)
        except PluginError as exc:
            problems.append(f"{path}.type: {exc}")
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
    cfg = validate_mapping(parse_yaml(text, source=source), source=source, check_plugins=check_plugins)
    base = Path(path).resolve().parent if path is not None else None
    return resolve_relative_paths(cfg, base)


def resolve_relative_paths(cfg: MissionFile, base_dir: Path | None) -> MissionFile:
    """Make ``cameras.*.calibration_file`` and ``target.appearance_image`` absolute, relative to
    the mission file's folder (the embedded configs resolve against the installed
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
    return cfg.model_copy(update=update)

