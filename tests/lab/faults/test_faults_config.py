"""The ``faults:`` section: validation errors name the path and the problem; the expected
outcome table covers every kind and docs/faults.md prints it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from eaglemission.lab.faults.config import FAULT_KINDS, FaultsConfig
from eaglemission.lab.faults.outcomes import COMPLETE, OUTCOMES, expected_action, markdown_table

from eaglemission.config import load_config
from eaglemission.errors import ConfigError

REPO = Path(__file__).resolve().parents[3]


def _load(tmp_path: Path, faults: Any) -> Any:
    d = load_config(check_plugins=False).model_dump(mode="json")
    d["faults"] = faults
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(d))
    return load_config(path)  # the faults section plugin validates the section


@pytest.mark.parametrize("faults,path,problem", [
    ({"inject": [{"kind": "camera_dorp", "at_s": 1}]}, "faults.inject[0].kind", "camera_drop"),
    ({"inject": [{"kind": "camera_drop"}]}, "faults.inject[0]", "exactly one of at_s"),
    ({"inject": [{"kind": "camera_drop", "at_s": 1, "at_state": "CRUISE"}]}, "faults.inject[0]",
     "exactly one of at_s"),
    ({"inject": [{"kind": "camera_drop", "at_s": 1, "size": 2}]}, "faults.inject[0]",
     "camera_drop takes no size"),
    ({"inject": [{"kind": "exposure_jump", "at_s": 1, "size": -1}]}, "faults.inject[0]",
     "must be in (0, 20], got -1"),
    ({"inject": [{"kind": "link_loss", "at_state": "CRUSE"}]}, "faults.inject[0].at_state",
     "CRUISE"),
    ({"inject": [{"kind": "link_loss", "at_s": 1, "duration_s": 0}]},
     "faults.inject[0].duration_s", "must be > 0"),
    ({"inject": [{"kind": "command_denied", "at_s": 1, "command": "fly"}]}, "faults.inject[0]",
     "command: must be one of"),
    ({"inject": [{"kind": "wind_gust", "at_s": 1, "size": 0.8}]}, "faults",
     "inject[0].size: a gust of 0.8 of the vehicle's authority exceeds max_gust_fraction 0.5"),
    ({"inject": [], "bogus": 1}, "faults.bogus", ""),
])
def test_bad_faults_name_path_and_problem(tmp_path: Path, faults: Any, path: str,
                                          problem: str) -> None:
    with pytest.raises(ConfigError) as err:
        _load(tmp_path, faults)
    assert any(p.startswith(path) and problem in p for p in err.value.problems), \
        err.value.problems


def test_a_valid_section_loads(tmp_path: Path) -> None:
    cfg = _load(tmp_path, {"max_gust_fraction": 0.6, "inject": [
        {"kind": "wind_gust", "at_state": "FINE_APPROACH", "delay_s": 1, "size": 0.6},
        {"kind": "exposure_jump", "at_s": 12.5, "duration_s": 0.4}]})
    assert cfg.faults is not None
    gust, jump = FaultsConfig.model_validate(cfg.faults).inject
    assert gust.value == 0.6 and jump.value == 3.0  # the kind's default size


def test_every_kind_has_an_outcome_and_a_valid_campaign_range() -> None:
    assert set(OUTCOMES) == set(FAULT_KINDS)
    cfg = load_config(check_plugins=False)
    for kind, o in OUTCOMES.items():
        exp = expected_action(kind, cfg)
        assert exp == COMPLETE or exp in ("return", "land", "hold", "release"), (kind, exp)
        assert o.delay_s[0] <= o.delay_s[1] and 0 < o.duration_s[0] <= o.duration_s[1]
    for kind in ("camera_drop", "slow_frame", "wind_gust", "corrupted_frame"):  # tolerable by requirement
        assert OUTCOMES[kind].tolerable
    assert expected_action("link_loss", cfg) == cfg.safety.link_loss_action


def test_docs_print_the_table_of_the_code() -> None:
    doc = (REPO / "docs" / "faults.md").read_text()
    assert markdown_table() in doc, "docs/faults.md: regenerate the table with " \
        "`python -c 'from eaglemission.lab.faults.outcomes import markdown_table as m; print(m())'`"
