"""Mission files: YAML -> validated, frozen pydantic models (:mod:`.models`), with errors that
name the YAML path (:mod:`.errors`) and the generated reference (:mod:`.doc`)."""

from eaglemission.config.models import (
    DEFAULT_CONFIG,
    CameraSection,
    Finite,
    GeofenceConfig,
    MissionFile,
    NonNegFloat,
    PosFloat,
    RecordingConfig,
    SafeAction,
    SafetyConfig,
    StrictModel,
    TargetConfig,
    load_config,
    merge_params,
    parse_yaml,
    plugin_problems,
    read_config_text,
    resolve_relative_paths,
    validate_mapping,
)

__all__ = [
    "DEFAULT_CONFIG", "CameraSection", "Finite", "GeofenceConfig", "MissionFile", "NonNegFloat",
    "PosFloat", "RecordingConfig", "SafeAction", "SafetyConfig", "StrictModel", "TargetConfig",
    "load_config", "merge_params", "parse_yaml", "plugin_problems", "read_config_text",
    "resolve_relative_paths", "validate_mapping",
]
