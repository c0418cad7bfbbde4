"""Plugin registry: discovery through entry points, conformance checks, clear errors."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import pytest

from eaglemission import registry
from eaglemission.config import validate_mapping
from eaglemission.errors import ConfigError, PluginError

FAKE_MODULE = '''
from pydantic import BaseModel, ConfigDict

from eaglemission.types import DetectionResult
import numpy as np


class FakeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    gain: float = 1.0


class FakeDetector:
    """A third-party detector: constant saliency times gain."""

    Config = FakeConfig
    description = "third-party test detector"

    def __init__(self, config=None, **context):
        self.config = config or FakeConfig()
        self.resets = 0

    def detect(self, frame, prior=None):
        sal = np.full(frame.image.shape[:2], min(1.0, 0.1 * self.config.gain), np.float32)
        return DetectionResult(sal, (), frame.timestamp_ns, frame.camera_id, frame.seq)

    def reset(self):
        self.resets += 1


class BrokenDetector:
    """Lacks reset() and makes detect async: must be rejected at load."""

    Config = FakeConfig
    description = "broken"

    def __init__(self, config=None, **context):
        pass

    async def detect(self, frame, prior=None):
        return None


class NoConfigDetector:
    description = "no Config"

    def detect(self, frame, prior=None):
        return None

    def reset(self):
        pass
'''


@pytest.fixture
def third_party(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Install a third-party distribution (a module + dist-info with entry points) on sys.path."""
    (tmp_path / "thirdparty_eagle.py").write_text(FAKE_MODULE)
    dist = tmp_path / "thirdparty_eagle-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-eagle\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(textwrap.dedent("""
        [eaglemission.detectors]
        fake = thirdparty_eagle:FakeDetector
        broken = thirdparty_eagle:BrokenDetector
        noconfig = thirdparty_eagle:NoConfigDetector
        missing = thirdparty_eagle_nonexistent:Thing
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("thirdparty_eagle", None)


def test_third_party_plugin_found_and_loaded_with_params(third_party: Path) -> None:
    assert "fake" in registry.available("detectors")
    det = registry.load("detectors", "fake", {"gain": 3.0})
    assert det.config.gain == 3.0
    det.reset()
    assert det.resets == 1


def test_third_party_params_validated_with_its_own_model(third_party: Path) -> None:
    with pytest.raises(ConfigError) as exc:
        registry.load("detectors", "fake", {"gian": 3.0})
    assert "detectors.fake.params.gian: unknown key; did you mean 'gain'?" in str(exc.value)


def test_non_conforming_plugin_rejected_naming_the_problem(third_party: Path) -> None:
    with pytest.raises(PluginError) as exc:
        registry.get("detectors", "broken")
    msg = str(exc.value)
    assert "missing method `reset`" in msg
    assert "`detect` must be a plain (sync) method" in msg


def test_plugin_without_config_model_rejected(third_party: Path) -> None:
    with pytest.raises(PluginError, match="must declare `Config`"):
        registry.get("detectors", "noconfig")


def test_unimportable_plugin_is_a_plugin_error(third_party: Path) -> None:
    with pytest.raises(PluginError, match="cannot be imported"):
        registry.get("detectors", "missing")


def test_unknown_name_lists_available_and_closest(third_party: Path) -> None:
    with pytest.raises(PluginError) as exc:
        registry.get("detectors", "fakee")
    msg = str(exc.value)
    assert "Did you mean 'fake'?" in msg
    assert "Available:" in msg and "fake" in msg


def test_unknown_role() -> None:
    with pytest.raises(PluginError, match="unknown plugin role"):
        registry.available("gizmos")


def test_describe_reports_broken_plugins_instead_of_raising(third_party: Path) -> None:
    infos = {i.name: i for i in registry.describe("detectors")}
    assert infos["fake"].error is None and infos["fake"].description
    assert infos["broken"].error is not None


def test_config_can_select_third_party_plugin(third_party: Path, sitl_config) -> None:
    data = sitl_config.model_dump(mode="json")
    data["detector"] = {"type": "fake", "params": {"gain": 2}}
    # Other sections name built-ins; only check the detector here.
    cfg = validate_mapping(data, check_plugins=False)
    model = registry.validate_params("detectors", cfg.detector.type, cfg.detector.params,
                                     path="detector.params")
    assert model.gain == 2.0


def test_config_cannot_name_an_import_path(sitl_config) -> None:
    data = sitl_config.model_dump(mode="json")
    data["detector"] = {"type": "os.path:join", "params": {}}
    with pytest.raises(ConfigError) as exc:
        validate_mapping(data)
    assert "detector.type: no detector plugin named 'os.path:join'" in str(exc.value)


def test_builtin_entry_points_declared_for_every_role() -> None:
    for role in ("cameras", "vehicles", "detectors", "estimators", "missions"):
        assert registry.available(role), role
    assert {"synthetic", "replay", "genicam"} <= set(registry.available("cameras"))
    assert {"simulated", "mavsdk"} <= set(registry.available("vehicles"))
    assert {"dtdmi", "rpnp", "pixel_offset", "approach"} <= (
        set(registry.available("detectors")) | set(registry.available("estimators"))
        | set(registry.available("missions")))


@pytest.mark.parametrize("role", ["cameras", "vehicles", "detectors", "estimators", "missions"])
def test_every_builtin_plugin_loads_and_conforms(role: str) -> None:
    """Every built-in entry point imports and passes the Protocol check."""
    problems = {i.name: i.error for i in registry.describe(role) if i.error}
    assert not problems, problems
