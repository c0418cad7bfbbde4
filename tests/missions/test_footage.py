"""The mission's perception on footage (missions/footage.py): acquire from the example image,
keep with the tracker; ``eaglemission detect --config MISSION`` and ``bench --mission``."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from eaglemission.missions.footage import FootageOptions, FootagePerception
from saliency_datasets import make_box_dataset

from eaglemission.cli import main
from eaglemission.config import load_config
from eaglemission.perception.appearance import TargetAppearance
from eaglemission.types import Frame


def _scene(i: int, rng: np.random.RandomState) -> np.ndarray:
    """A textured target and a more saturated decoy of the same size, on noisy grass."""
    img = np.clip(rng.randn(360, 480, 3) * 6 + (60, 120, 70), 0, 255).astype(np.uint8)
    u = 100 + 4 * i
    img[150:180, u:u + 40] = (60, 80, 110)
    img[158:172, u + 10:u + 30] = (150, 170, 200)
    img[250:280, 330:370] = (255, 0, 255)
    return img


def test_the_target_is_acquired_from_the_example_and_kept(rng):
    crop = _scene(0, np.random.RandomState(1))[150:180, 100:140].copy()
    fp = FootagePerception(load_config(), FootageOptions(example_image=crop,
                                                         mission_colour=False))
    assert fp.keeper is not None
    out = []
    for i in range(10):
        m = fp.process(Frame(_scene(i, rng), 1_000_000_000 + i * 100_000_000, "wide", i))
        out.append(m)
    assert not out[0].kept  # the first frame gives a candidate, not yet the target
    kept = [m for m in out if m.kept]
    assert len(kept) >= 8 and any(m.from_tracker for m in kept)
    assert sum(not m.detector_ran for m in out) >= 4  # the tracker covers frames between checks
    for i, m in enumerate(out):
        if m.kept:
            assert m.detection is not None and abs(m.detection.center_px[0] - (119.5 + 4 * i)) < 8


def test_the_example_is_located_where_the_detector_has_nothing_like_it(rng):
    img = _scene(0, rng)
    crop = img[150:180, 100:140].copy()
    found = TargetAppearance(image=crop).locate_example(img)
    assert found is not None and found[1] > 0.95
    (u0, v0, u1, v1), _ = found
    assert abs(u0 - 99.5) <= 1 and abs(v0 - 149.5) <= 1 and abs(u1 - 139.5) <= 1
    assert TargetAppearance(image=crop).example_match(img, (120.0, 165.0)) > 0.95
    assert TargetAppearance(image=crop).example_match(img, (350.0, 265.0)) < 0.5


def test_detect_runs_the_missions_perception_and_writes_the_targets_box(tmp_path, rng):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(6):
        cv2.imwrite(str(frames / f"{i:04d}.png"), _scene(i, rng))
    crop = _scene(0, np.random.RandomState(3))[150:180, 100:140]
    cv2.imwrite(str(tmp_path / "crop.png"), crop)
    mission = tmp_path / "mission.yaml"
    cfg = load_config().model_dump(mode="json")
    cfg["target"].pop("color_bgr", None)  # this footage's target is described by its image
    import yaml
    mission.write_text(yaml.safe_dump(cfg))
    rc = main(["detect", str(frames), "--config", str(mission), "--target-image",
               str(tmp_path / "crop.png"), "--out", str(tmp_path / "out"), "--no-video"])
    assert rc == 0
    lines = [json.loads(x) for x in (tmp_path / "out" / "detections.jsonl").read_text()
             .splitlines()]
    assert len(lines) == 6 and lines[0]["target"] is None
    later = [x for x in lines[1:] if x["target"] is not None]
    assert len(later) >= 4
    for x in later:
        assert x["detections"][0]["center_px"] == x["target"]["center_px"]  # best first


def test_bench_mission_scores_acquire_keep_and_the_trackers(tmp_path, rng):
    data = make_box_dataset(tmp_path / "data", rng, n=10)
    rc = main(["bench", "--data", str(data), "--mission", str(Path("configs/sitl_synthetic.yaml")
                                                              .resolve()),
               "--fps", "10", "--out", str(tmp_path / "out")])
    assert rc == 0
    text = (tmp_path / "out" / "perception.md").read_text()
    for row in ("mission: acquire + keep", "keeping, from the confirmation on",
                "acquisition: detector + prior", "sr + regions", "csrt from the first box",
                "kcf from the first box"):
        assert row in text, row
