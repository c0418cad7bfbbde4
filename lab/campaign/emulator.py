"""``campaign --vehicle emulator``: each run flown in real time through MAVSDK against its own
``eaglemission sitl-vehicle`` process (the MAVLink emulator on the run's world), as
``eaglemission run --vehicle emulator`` flies one; the ``faults:`` link kinds then travel the
real UDP path through the mavsdk vehicle's fault relay (:mod:`.link_relay`).

The kinds this path carries: the link ones (the relay), the camera, detector and estimator
ones (in the mission's process). The emulator's own world faults (GPS, battery, gusts, a
pilot, a denied command) have no control channel into the ``sitl-vehicle`` process.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from eaglemission.lab.faults.config import FAULT_KINDS
from eaglemission.lab.faults.injection import (
    CAMERA_KINDS,
    DETECTOR_KINDS,
    ESTIMATOR_KINDS,
    LINK_KINDS,
)

from eaglemission.config import MissionFile

VEHICLES = ("simulated", "emulator")
EMULATOR_KINDS = tuple(k for k in FAULT_KINDS
                       if k in LINK_KINDS | CAMERA_KINDS | DETECTOR_KINDS | ESTIMATOR_KINDS)
"""The fault kinds a run on the emulator can carry (``--faults all`` means these there)."""


def emulator_kinds(kinds: list[str]) -> list[str]:
    """``kinds`` for the emulator; ValueError naming those it cannot carry."""
    bad = [k for k in kinds if k not in EMULATOR_KINDS]
    if bad:
        raise ValueError(f"--faults: {', '.join(bad)} cannot be injected with --vehicle "
                         f"emulator (no control channel into its process); it carries: "
                         f"{', '.join(EMULATOR_KINDS)}")
    return kinds


def fly_on_emulator(cfg: MissionFile, *, log_path: Path | None, keep_log: bool) -> Any:
    """Fly ``cfg`` (a simulated-vehicle mission with its world) through MAVSDK against a
    ``sitl-vehicle`` process started for it, in real time; returns the mission's outcome."""
    from eaglemission.lab.campaign.sim import run_simulation

    from eaglemission.commands.run import emulator_process

    doc = cfg.model_dump(mode="json")
    # the mission goes to the emulator through its stdin: a killed worker leaves no file
    with emulator_process(None, mission_yaml=yaml.safe_dump(doc)) as url:
        flown = MissionFile.model_validate({**doc, "vehicle": {
            "type": "mavsdk", "params": {"url": url, "connect_timeout_s": 30}}})
        return run_simulation(flown, realtime=True, log_path=log_path, keep_log=keep_log)
