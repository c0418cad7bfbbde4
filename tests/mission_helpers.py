"""Helpers of the mission tests."""

from __future__ import annotations

from typing import Any

from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.log import MissionLog
from eaglemission.missions.tracking import TargetTracking

from eaglemission.config import MissionFile, load_config


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


def target_tracking(**tracking: object) -> TargetTracking:
    """The embedded mission's target tracking, with ``mission.params.tracking`` keys replaced."""
    cfg = load_config(check_plugins=False)
    if tracking:
        params = dict(cfg.mission.params)
        params["tracking"] = {**params.get("tracking", {}), **tracking}
        cfg = variant(cfg, mission={"params": params})
    p = ApproachConfig.of(cfg)
    models = {cid: getattr(cfg.cameras, cid).to_model(cid) for cid in ("wide", "narrow")}
    return TargetTracking(cfg, models, MissionLog(None, now_ns=lambda: 0), tracking=p.tracking,
                          perception=p.perception, plane=p.plane, grasp=p.grasp)
