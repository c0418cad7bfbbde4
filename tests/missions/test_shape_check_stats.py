"""benchmarks/shape_check_stats.py on a hand-written campaign folder: candidates split on
``views == 1``, judged true by their estimates' distance to the target, margins and
rejections counted per group."""
from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "shape_check_stats.py"


def _load():
    spec = importlib.util.spec_from_file_location("shape_check_stats", SCRIPT)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _heading(views: int, iou: float, median: float | None) -> dict:
    return {"kind": "heading", "views": views, "silhouette_iou": iou, "median_iou": median}


def _estimate(north: float, east: float) -> dict:
    return {"kind": "estimate", "ok": True, "position_ned_m": [north, east, -0.15]}


def _write_run(folder: Path, run: int, records: list[dict], error_m: float) -> None:
    sim = {"target_north_m": 20.0, "target_east_m": 1.0}
    result = {"run": run, "result": {"sim": sim, "reached_grasp_ready": True,
                                     "horizontal_error_m": error_m}}
    (folder / f"run_{run:03d}.result.json").write_text(json.dumps(result))
    lines = [json.dumps(r) for r in records] + ['{"kind": "cut']  # a cut last line is skipped
    (folder / f"run_{run:03d}.jsonl").write_text("\n".join(lines))


def test_a_box_rejected_then_the_target_is_counted_apart(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]):
    box = [_estimate(9.0, 5.0)] + [_heading(v, 0.75, 0.75 if v >= 2 else None)
                                   for v in (1, 2, 3)]
    box.append({"kind": "event", "text": "candidate near north 9.0 m east 5.0 m rejected: "
                "its outline does not fit the target's shape (...)"})
    target = [_estimate(20.1, 1.0)] + [_heading(v, 0.95, 0.95 if v >= 2 else None)
                                       for v in (1, 2, 3)]
    _write_run(tmp_path, 0, box + target, error_m=0.01)
    _write_run(tmp_path, 1, [_estimate(9.0, 5.0), _heading(1, 0.8, 0.8)], error_m=11.2)
    assert _load().main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "true targets: 1 candidates, 1 with a running median" in out
    assert "lowest running median: min 0.950" in out
    assert "other candidates: 2 candidates, 2 with a running median" in out
    assert "below 0.86: 2 [0, 1]; rejected by the shape check: 1 [0]" in out
    assert "GRASP_READY away from the target: 1" in out and "run 1: GRASP_READY 11.20 m" in out


def test_an_empty_folder_is_an_error(tmp_path: Path) -> None:
    assert _load().main([str(tmp_path)]) == 2
