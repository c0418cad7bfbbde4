"""Fault harness of the closed-loop fault tests: a mission file's ``faults:`` section, flown
through the same assembly as ``eaglemission run`` (the injection lives in the real plugins:
lab/faults/faulty_camera.py, lab/faults/wrappers.py, the simulated vehicle)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.lab.faults.outcomes import COMPLETE, expected_action
from eaglemission.missions.mission import ApproachOutcome

from eaglemission.config import MissionFile

# the tests' names for some kinds (the section's names on the right)
_ALIASES = {"camera_dropout": "camera_drop", "battery_low": "battery_drain"}


@dataclass(frozen=True)
class Fault:
    """A fault injected when the mission enters ``at_state`` (+ ``delay_s``); ``value``: its
    size (kinds with a size, docs/faults.md)."""

    kind: str
    at_state: str = "FINE_APPROACH"
    delay_s: float = 0.5
    duration_s: float = 1.0
    value: float | None = None

    def spec(self) -> dict[str, Any]:
        kind = _ALIASES.get(self.kind, self.kind)
        out: dict[str, Any] = {"kind": kind, "at_state": self.at_state, "delay_s": self.delay_s,
                               # a battery level lasts: a duration of 0 means a step change
                               "duration_s": self.duration_s if self.duration_s > 0 else 1.0}
        if self.value is not None:
            out["size"] = self.value
        return out


def with_faults(cfg: MissionFile, faults: list[Fault]) -> MissionFile:
    """``cfg`` with a ``faults:`` section injecting ``faults``."""
    return MissionFile.model_validate(
        {**cfg.model_dump(), "faults": {"inject": [f.spec() for f in faults]}})


def fly_with_faults(cfg: MissionFile, faults: list[Fault], **kw: Any) -> ApproachOutcome:
    """:func:`run_simulation` with ``faults`` injected; evaluated against the safe action the
    first fault's expected outcome prescribes (docs/faults.md)."""
    cfg = with_faults(cfg, faults)
    action = None
    if faults:
        exp = expected_action(_ALIASES.get(faults[0].kind, faults[0].kind), cfg)
        action = None if exp == COMPLETE else exp
    return run_simulation(cfg, expected_action=action, **kw)
