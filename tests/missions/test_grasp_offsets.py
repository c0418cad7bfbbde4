"""benchmarks/grasp_offsets.py on a hand-written flight log: the grasp point from the tool's
home in body axes (the telemetry's heading), only in the state asked for and after the skip."""
from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from eaglemission.config import MissionFile

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "grasp_offsets.py"


def _load():
    spec = importlib.util.spec_from_file_location("grasp_offsets", SCRIPT)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_offsets_in_body_axes_from_the_state_and_skip(sitl_config: MissionFile,
                                                      tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    home = np.asarray(sitl_config.tool_point_m)
    grasp_m = 0.175
    # the vehicle heads east (yaw 90): body x is east, body y is south
    vehicle = np.array([10.0, 5.0, -1.0])
    want = np.array([0.03, -0.04, 0.01])  # body FRD offset of the grasp point from home
    body = home + want
    ned = np.array([-body[1], body[0], body[2]])  # body -> NED at yaw 90
    target = vehicle + ned + np.array([0.0, 0.0, grasp_m])
    far = target + np.array([1.0, 0.0, 0.0])
    s = 1_000_000_000
    recs = [
        {"kind": "config", "t_ns": 0, "config": sitl_config.model_dump(mode="json")},
        {"kind": "state", "t_ns": 1 * s, "new": "FINE_APPROACH"},
        {"kind": "state", "t_ns": 2 * s, "new": "FINE_DESCENT"},
        {"kind": "telemetry", "t_ns": 2 * s, "position_ned_m": list(vehicle), "yaw_deg": 90.0},
        {"kind": "estimate", "t_ns": 1 * s + 5, "ok": True, "position_ned_m": list(far)},
        {"kind": "estimate", "t_ns": 2 * s + 5, "ok": True, "position_ned_m": list(far)},
        {"kind": "estimate", "t_ns": 5 * s, "ok": True, "position_ned_m": list(target)},
        {"kind": "estimate", "t_ns": 6 * s, "ok": False},
    ]
    log = tmp_path / "flight.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in recs))
    mod = _load()
    _, o = mod.offsets(log, 1.0, "FINE_DESCENT")
    assert o.shape == (1, 3) and o[0] == pytest.approx(want)
    assert mod.main([str(log), "--skip-s", "1"]) == 0
    out = capsys.readouterr().out
    assert f"horizontal offset median {math.hypot(0.03, 0.04) * 100:.1f} cm" in out
    assert "100 %" in out
