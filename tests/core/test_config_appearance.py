"""``target.appearance_image`` resolves relative to the mission file."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import yaml

from eaglemission.config import load_config

REPO = Path(__file__).resolve().parents[2]


def test_appearance_image_resolves_relative_to_the_mission_file(tmp_path: Path) -> None:
    data = yaml.safe_load((REPO / "configs" / "sitl_synthetic.yaml").read_text())
    # the embedded default's image resolves against the installed configs package
    assert load_config(check_plugins=False).target.appearance_image == str(
        Path(str(resources.files("eaglemission.configs"))) / "targets" / "red_box.jpg")
    data["target"]["appearance_image"] = "images/box.png"
    (tmp_path / "sub").mkdir()
    f = tmp_path / "sub" / "m.yaml"
    f.write_text(yaml.safe_dump(data))
    cfg = load_config(f, check_plugins=False)
    assert cfg.target.appearance_image == str(tmp_path / "sub" / "images" / "box.png")
    data["target"]["appearance_image"] = "/abs/box.png"
    f.write_text(yaml.safe_dump(data))
    assert load_config(f, check_plugins=False).target.appearance_image == "/abs/box.png"
