"""docs/plugins.md's example package, taken from the page as written, installed as a
distribution (module + dist-info with its entry points on sys.path) and flown: the docs are
enough to write a detector and an estimator, and swapping them by config changes the flight."""

from __future__ import annotations

import re
import sys
import textwrap
from pathlib import Path

import pytest

from eaglemission import registry
from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import FlightOptions, fly_sync
from eaglemission.interfaces import MissionHooks

DOC = Path(__file__).resolve().parents[2] / "docs" / "plugins.md"


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(), flags=re.S)


@pytest.fixture
def eagle_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "eagle_extra.py").write_text(_blocks("python")[0])
    toml = _blocks("toml")[0]
    dist = tmp_path / "eagle_extra-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: eagle-extra\nVersion: 0.1\n")
    eps = re.sub(r'^\[project\.entry-points\."(.+?)"\]', r"[\1]", toml, flags=re.M)
    eps = "\n".join(line for line in eps.splitlines() if not line.startswith("#"))
    (dist / "entry_points.txt").write_text(textwrap.dedent(eps).replace('"', ""))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("eagle_extra", None)


def test_the_documented_plugins_load(eagle_extra: Path) -> None:
    assert registry.get("detectors", "redness").__name__ == "RednessDetector"
    assert registry.get("estimators", "ground_hit").__name__ == "GroundHitEstimator"
    det = registry.load("detectors", "redness", {"gain": 3.0}, camera_id="wide")
    assert det.config.gain == 3.0


def test_a_mission_flies_on_the_documented_plugins(eagle_extra: Path, tmp_path: Path) -> None:
    import yaml

    yaml_block = _blocks("yaml")[0]
    sections = yaml.safe_load(yaml_block)
    data = load_config().model_dump()
    data.update(sections)
    cfg = MissionFile.model_validate(data)
    log = tmp_path / "flight.jsonl"
    res = fly_sync(cfg, FlightOptions(hooks=MissionHooks(log_path=log)))
    assert res.outcome is not None, res.error
    recs = res.outcome.log.records
    sources = {r.get("source") for r in recs if r["kind"] == "estimate" and r.get("ok")}
    assert sources == {"ground_hit"}  # the example estimator's own positions were flown
    assert "detector: redness" in "\n".join(res.header)
    assert res.outcome.final_state in ("DONE", "FAILSAFE")
