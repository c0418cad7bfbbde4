"""Helpers of the mission tests."""

from __future__ import annotations

from typing import Any

from eaglemission.config import MissionFile


def variant(cfg: MissionFile, **sections: dict[str, Any]) -> MissionFile:
    """A copy of ``cfg`` with some sections' keys replaced (validated again); ``world_params``
    updates keys of ``world.params``."""
    data = cfg.model_dump()
    for name, updates in sections.items():
        if name == "world_params":
            data["world"]["params"] = {**data["world"]["params"], **updates}
        elif isinstance(data.get(name), dict):
            data[name] = {**data[name], **updates}
        else:
            data[name] = updates
    return MissionFile.model_validate(data)
