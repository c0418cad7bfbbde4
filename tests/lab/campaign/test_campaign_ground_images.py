"""``campaign --ground-images DIR``: bad folders exit 2 naming the file; runs draw a photo."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from eaglemission.lab.campaign.campaign import randomise

from eaglemission.cli import main
from eaglemission.config import load_config


def _image(folder: Path, name: str, yaml_text: str | None) -> Path:
    path = folder / f"{name}.png"
    cv2.imwrite(str(path), np.full((80, 80, 3), 90, np.uint8))
    if yaml_text is not None:
        path.with_suffix(".yaml").write_text(yaml_text)
    return path


def test_missing_or_invalid_yaml_exits_2_naming_the_file(tmp_path, capsys):
    _image(tmp_path, "a", "m_per_px: 0.05\n")
    _image(tmp_path, "b", None)
    assert main(["campaign", "--runs", "1", "--ground-images", str(tmp_path)]) == 2
    assert "b.yaml: missing" in capsys.readouterr().err
    (tmp_path / "b.yaml").write_text("m_per_px: lots\n")
    assert main(["campaign", "--runs", "1", "--ground-images", str(tmp_path)]) == 2
    assert "b.yaml: m_per_px must be" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["campaign", "--runs", "1", "--ground-images", str(empty)]) == 2
    assert "no NAME.jpg or NAME.png" in capsys.readouterr().err


def test_each_run_draws_one_of_the_photos_and_keeps_the_other_draws(tmp_path):
    photos = [_image(tmp_path, n, "m_per_px: 0.05\n") for n in ("a", "b", "c")]
    base = load_config(None)
    chosen = set()
    for k in range(12):
        plain = randomise(base, np.random.RandomState(k))
        cfg = randomise(base, np.random.RandomState(k), photos)
        assert cfg.world is not None and plain.world is not None
        params = dict(cfg.world.params)
        chosen.add(Path(params.pop("ground_image")["path"]).name)
        assert params == {key: v for key, v in plain.world.params.items()
                          if key != "ground_image"}
    assert chosen == {"a.png", "b.png", "c.png"}
