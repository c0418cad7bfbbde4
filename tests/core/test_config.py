"""Mission configuration: every malformed input gets a path-qualified message, never a crash."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from eaglemission.config import (
    DEFAULT_CONFIG,
    MissionFile,
    load_config,
    parse_yaml,
    resolve_relative_paths,
    validate_mapping,
)
from eaglemission.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
SHIPPED = sorted((REPO / "configs").glob("*.yaml"))


def shipped_data(name: str = DEFAULT_CONFIG) -> dict[str, Any]:
    return yaml.safe_load((REPO / "configs" / name).read_text())


def mutate(data: dict[str, Any], path: str, value: Any = ..., *, delete: bool = False) -> dict[str, Any]:
    out = copy.deepcopy(data)
    node: Any = out
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    last: Any = int(keys[-1]) if isinstance(node, list) else keys[-1]
    if delete:
        del node[last]
    else:
        node[last] = value
    return out


def errors_of(data: Any) -> str:
    with pytest.raises(ConfigError) as exc:
        validate_mapping(data, check_plugins=False)
    return str(exc.value)


@pytest.mark.parametrize("name", [p.name for p in SHIPPED])
def test_shipped_configs_pass_the_schema(name: str) -> None:
    cfg = validate_mapping(shipped_data(name), check_plugins=False)
    assert isinstance(cfg, MissionFile)


def test_embedded_default_is_the_shipped_sitl_config() -> None:
    # the embedded file's relative paths (the target's image) resolve against the configs package
    assert load_config(check_plugins=False) == resolve_relative_paths(
        validate_mapping(shipped_data(), check_plugins=False), None)


def test_models_are_frozen_and_loading_does_not_mutate_input() -> None:
    data = shipped_data()
    before = copy.deepcopy(data)
    cfg = validate_mapping(data, check_plugins=False)
    assert data == before
    with pytest.raises(ValidationError):
        cfg.mission.cruise_altitude_m = 3.0  # type: ignore[misc]


# (mutation path, value or DELETE, expected fragment of the message)
DELETE = object()
MUTATIONS: list[tuple[str, Any, str]] = [
    ("cameras.narrow.focal_length_mm", -12, "cameras.narrow.focal_length_mm: must be > 0, got -12"),
    ("cameras.wide.focal_length_mm", 0, "cameras.wide.focal_length_mm: must be > 0, got 0"),
    ("cameras.wide.focal_length_mm", "abc", "cameras.wide.focal_length_mm: must be a number, got 'abc'"),
    ("cameras.wide.focal_length_mm", float("nan"), "cameras.wide.focal_length_mm: must be a finite number"),
    ("cameras.wide.pixel_size_um", float("inf"), "cameras.wide.pixel_size_um: must be a finite number"),
    ("cameras.wide.resolution_px", [1280], "cameras.wide.resolution_px"),
    ("cameras.wide.resolution_px", [1280, -960], "cameras.wide.resolution_px[1]: must be > 0, got -960"),
    ("cameras.wide.shutter", "diagonal", "cameras.wide.shutter: must be one of 'global' or 'rolling'"),
    ("cameras.wide.mount.pitch_deg", -120, "cameras.wide.mount.pitch_deg: must be >= -90, got -120"),
    ("cameras.wide.mount.lever_arm_m", [0.1, 0.2], "cameras.wide.mount.lever_arm_m"),
    ("cameras.wide.mount.pich_deg", -30, "cameras.wide.mount.pich_deg: unknown key; did you mean 'pitch_deg'?"),
    ("cameras.wide.distortion", [0.1, 0.2, 0.3], "distortion: OpenCV takes 4, 5, 8, 12 or 14 coefficients, got 3"),
    ("cameras.narrow", DELETE, "cameras.narrow: required key is missing"),
    ("cameras.wide.type", DELETE, "cameras.wide.type: required key is missing"),
    ("cameras.wide", "a string", "cameras.wide: must be a mapping"),
    ("vehicle", DELETE, "vehicle: required key is missing"),
    ("vehicle.params", [1, 2], "vehicle.params"),
    ("vehicel", {"type": "simulated"}, "vehicel: unknown key; did you mean 'vehicle'?"),
    ("target.length_m", -0.4, "target.length_m: must be > 0, got -0.4"),
    ("target.height_m", -1, "target.height_m: must be >= 0, got -1"),
    ("target.color_bgr", [0, 0, 300], "target.color_bgr[2]: must be <= 255, got 300"),
    ("target.color_bgr", [0, 0], "color_bgr: needs 3 values"),
    ("tool_point_m", [0, 0, "x"], "tool_point_m[2]: must be a number, got 'x'"),
    ("mission.route", [], "mission.route: list should have at least 1 item"),
    ("mission.route.0.north_m", None, "mission.route[0].north_m: must be a number, got None"),
    ("mission.route.0.up_m", 3, "mission.route[0].up_m: unknown key"),
    ("mission.cruise_altitude_m", -5, "mission.cruise_altitude_m: must be > 0, got -5"),
    ("mission.route_frame", "lla", "mission.route_frame: must be one of 'ned_home'"),
    ("safety.max_altitude_m", 0, "safety.max_altitude_m: must be > 0, got 0"),
    ("safety.min_altitude_m", 25, "min_altitude_m (25.0) must be below max_altitude_m (20.0)"),
    ("safety.geofence.polygon_ned_m", [[0, 0], [1, 1]], "polygon_ned_m: needs at least 3 vertices"),
    ("safety.low_battery_fraction", 1.5, "safety.low_battery_fraction: must be <= 1, got 1.5"),
    ("safety.link_loss_action", "panic", "safety.link_loss_action: must be one of 'hold', 'return' or 'land'"),
    ("safety.on_violation", True, "safety.on_violation: must be one of 'clamp' or 'refuse'"),
    ("estimators.fine", DELETE, "estimators.fine: required key is missing"),
    ("estimators.coarse.kind", "bearing", "estimators.coarse.kind: unknown key; allowed keys: type, params"),
    ("detector", None, "detector: must be a mapping"),
]


@pytest.mark.parametrize(("path", "value", "expected"), MUTATIONS, ids=[m[0] + "=" + repr(m[1])[:20] for m in MUTATIONS])
def test_malformed_variant_of_shipped_config(path: str, value: Any, expected: str) -> None:
    data = shipped_data()
    data = mutate(data, path, delete=True) if value is DELETE else mutate(data, path, value)
    msg = errors_of(data)
    assert expected in msg, msg


MISSION_PARAM_MUTATIONS = [
    ("world.params.mount_error_deg", 45, "world.params.mount_error_deg: must be <= 10, got 45"),
    ("world.params.seed", "seven", "world.params.seed: must be an integer, got 'seven'"),
    ("mission.params.grasp.distance_m", 5, "mission.params.grasp.distance_m: must be <= 2, got 5"),
    ("mission.params.tracking.confirm_frames", 2.5,
     "mission.params.tracking.confirm_frames: must be an integer, got 2.5"),
    ("mission.params.timeouts.fine_approach_s", -1,
     "mission.params.timeouts.fine_approach_s: must be > 0, got -1"),
    ("mission.params.actions.on_done", "crash",
     "mission.params.actions.on_done: must be one of 'land', 'return' or 'hold'"),
    ("mission.params.confirm_frames", 3,
     "mission.params.confirm_frames: unknown key"),
]


@pytest.mark.parametrize(("path", "value", "expected"), MISSION_PARAM_MUTATIONS,
                         ids=[m[0] + "=" + repr(m[1])[:20] for m in MISSION_PARAM_MUTATIONS])
def test_malformed_mission_params_name_their_path(path: str, value: Any, expected: str) -> None:
    """The approach mission's own keys are checked by its params model, at load time."""
    data = mutate(shipped_data(), path, value)
    with pytest.raises(ConfigError) as exc:
        validate_mapping(data)
    assert expected in str(exc.value), str(exc.value)


def test_every_error_is_reported_at_once() -> None:
    data = mutate(shipped_data(), "mission.cruise_altitude_m", -5)
    data = mutate(data, "target.width_m", 0)
    msg = errors_of(data)
    assert "mission.cruise_altitude_m" in msg and "target.width_m" in msg and "2 problems" in msg


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "empty file"),
        ("# only a comment\n", "empty file"),
        ("- a\n- b\n", "<top level>: must be a mapping of sections, got list"),
        ("42\n", "<top level>: must be a mapping of sections, got int"),
        ("vehicle: {type: simulated\n", "YAML error"),
        ("a: b\n  c: d\n", "line 2"),
        ("vehicle: !!python/object/apply:os.system ['echo hi']\n", "python/object tags are not allowed"),
        ("vehicle: !!python/name:os.system ''\n", "python/object tags are not allowed"),
        ("vehicle: {type: simulated}\nvehicle: {type: mavsdk}\n", "duplicate key 'vehicle'"),
        ("1: {type: x}\n", "section names must be strings"),
        ("\t- tab\n", "YAML error"),
        ("&a [*a]\n", "<top level>"),
    ],
)
def test_malformed_text(text: str, expected: str) -> None:
    with pytest.raises(ConfigError) as exc:
        validate_mapping(parse_yaml(text), check_plugins=False)
    assert expected in str(exc.value), str(exc.value)


def test_missing_binary_and_directory_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.yaml")
    (tmp_path / "bin.yaml").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    with pytest.raises(ConfigError, match="binary file"):
        load_config(tmp_path / "bin.yaml")
    (tmp_path / "latin.yaml").write_bytes("vehicle: caf\xe9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_config(tmp_path / "latin.yaml")
    with pytest.raises(ConfigError, match="is a directory"):
        load_config(tmp_path)


# -- property test: random YAML never produces an unhandled exception -------------------------
scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
)
yaml_values = st.recursive(
    scalars,
    lambda children: st.one_of(
        st.lists(children, max_size=4),
        st.dictionaries(st.one_of(st.text(max_size=10), st.sampled_from(
            ["vehicle", "cameras", "wide", "narrow", "type", "params", "mission", "route",
             "target", "safety", "focal_length_mm", "length_m", "estimators", "detector"])),
            children, max_size=5),
    ),
    max_leaves=25,
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(yaml_values)
def test_random_documents_never_crash(doc: Any) -> None:
    try:
        text = yaml.safe_dump(doc)
    except yaml.YAMLError:
        return
    try:
        validate_mapping(parse_yaml(text), check_plugins=False)
    except ConfigError as exc:
        assert str(exc)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=200))
def test_random_text_never_crashes(text: str) -> None:
    try:
        validate_mapping(parse_yaml(text), check_plugins=False)
    except ConfigError as exc:
        assert str(exc)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from([m[0] for m in MUTATIONS if "." in m[0]]), scalars)
def test_random_mutations_of_shipped_config(path: str, value: Any) -> None:
    try:
        data = mutate(shipped_data(), path, value)
    except (KeyError, IndexError, TypeError, ValueError):
        return
    try:
        validate_mapping(data, check_plugins=False)
    except ConfigError as exc:
        # the message names the mutated key (or the section that lost its shape)
        assert path.split(".")[-1] in str(exc) or path.split(".")[0] in str(exc), str(exc)


# -- the CLI: exit codes and no tracebacks ----------------------------------------------------
def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "eaglemission.cli", *args],
                          capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize(
    "text",
    ["", "[1, 2]", "vehicle: !!python/object/apply:os.system ['echo pwned']",
     "cameras: {wide: {focal_length_mm: -1}}", "\x00\x01binary"],
)
def test_validate_cli_rejects_without_traceback(tmp_path: Path, text: str) -> None:
    f = tmp_path / "bad.yaml"
    f.write_bytes(text.encode("utf-8"))
    r = run_cli("validate", str(f))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "invalid:" in r.stderr
    assert "pwned" not in r.stdout


def test_validate_cli_names_the_path_and_value(tmp_path: Path) -> None:
    data = mutate(shipped_data(), "cameras.narrow.focal_length_mm", -12)
    f = tmp_path / "m.yaml"
    f.write_text(yaml.safe_dump(data))
    r = run_cli("validate", str(f))
    assert r.returncode == 2
    assert "cameras.narrow.focal_length_mm: must be > 0, got -12" in r.stderr


@pytest.mark.parametrize("name", [p.name for p in SHIPPED])
def test_validate_cli_accepts_every_shipped_config(name: str, tmp_path: Path) -> None:
    cwd = None
    if name == "replay.yaml":  # it names a recording relative to the working directory
        from eaglemission.recording.folder import RunRecorder
        from eaglemission.types import VehicleState

        with RunRecorder(tmp_path / "recordings" / "run1") as rec:
            rec.write_state(VehicleState(1_000_000_000, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                                         (1.0, 0.0, 0.0, 0.0)))
        cwd = tmp_path
    r = run_cli("validate", str(REPO / "configs" / name), cwd=cwd)
    assert r.returncode == 0, r.stderr


def test_validate_cli_refuses_a_replay_without_its_recording(tmp_path: Path) -> None:
    r = run_cli("validate", str(REPO / "configs" / "replay.yaml"), cwd=tmp_path)
    assert r.returncode == 2
    assert "vehicle.params.path: 'recordings/run1' holds no recorded run" in r.stderr


def test_validate_cli_refuses_synthetic_cameras_without_a_world(tmp_path: Path) -> None:
    data = shipped_data()
    del data["world"]
    f = tmp_path / "m.yaml"
    f.write_text(yaml.safe_dump(data))
    r = run_cli("validate", str(f))
    assert r.returncode == 2
    assert "cameras.wide.type: a synthetic camera renders the simulated world" in r.stderr
    assert "cameras.narrow.type: a synthetic camera renders the simulated world" in r.stderr


def test_validate_cli_refuses_a_resolution_that_disagrees_with_the_calibration(
        tmp_path: Path) -> None:
    data = yaml.safe_load((REPO / "configs" / "field_basler_px4.yaml").read_text())
    for cid in ("wide", "narrow"):
        data["cameras"][cid]["calibration_file"] = str(
            REPO / "configs" / data["cameras"][cid]["calibration_file"])
    data["target"]["appearance_image"] = str(REPO / "configs" / data["target"]["appearance_image"])
    data["cameras"]["narrow"]["resolution_px"] = [800, 600]
    f = tmp_path / "m.yaml"
    f.write_text(yaml.safe_dump(data))
    r = run_cli("validate", str(f))
    assert r.returncode == 2
    assert ("cameras.narrow.resolution_px: [800, 600] disagrees with the calibration file "
            "(1280x960)") in r.stderr


def test_validate_cli_embedded_default() -> None:
    r = run_cli("validate")
    assert r.returncode == 0, r.stderr


def test_validate_cli_cross_checks(tmp_path: Path) -> None:
    data = mutate(shipped_data(), "mission.route.1.north_m", 500.0)
    data = mutate(data, "mission.cruise_speed_mps", 9.0)
    f = tmp_path / "m.yaml"
    f.write_text(yaml.safe_dump(data))
    r = run_cli("validate", str(f))
    assert r.returncode == 2
    assert "mission.route[1]: (500.0, 0.0) lies outside safety.geofence" in r.stderr
    assert "mission.cruise_speed_mps: exceeds safety.max_horizontal_speed_mps" in r.stderr


def test_configuration_reference_is_up_to_date() -> None:
    from eaglemission.config.doc import schema_markdown

    doc = (REPO / "docs" / "configuration.md").read_text()
    assert doc.strip() == schema_markdown().strip(), (
        "docs/configuration.md is stale: run `python -m eaglemission.config.doc > docs/configuration.md`")


def test_calibration_paths_resolve_relative_to_the_mission_file(tmp_path: Path) -> None:
    cfg = load_config(REPO / "configs" / "field_basler_px4.yaml", check_plugins=False)
    assert Path(cfg.cameras.wide.calibration_file).is_absolute()
    model = cfg.cameras.narrow.to_model("narrow")
    assert model.fx == pytest.approx(12.0e3 / 3.75)
    # the same file copied elsewhere without its calib/ folder names the missing file
    f = tmp_path / "field.yaml"
    f.write_text((REPO / "configs" / "field_basler_px4.yaml").read_text())
    cfg = load_config(f, check_plugins=False)
    with pytest.raises(ConfigError, match="calibration file not found"):
        cfg.cameras.wide.to_model("wide")


def test_keys_of_an_older_layout_are_refused_with_their_path() -> None:
    """No migration before 1.0: a key in an older place is an unknown key, named."""
    data = shipped_data()
    data["mission"]["grasp_distance_m"] = 0.2
    with pytest.raises(ConfigError, match=r"mission\.grasp_distance_m"):
        validate_mapping(data)
    data = shipped_data()
    data["simulation"] = data.pop("world")["params"]
    with pytest.raises(ConfigError, match="simulation"):
        validate_mapping(data)
