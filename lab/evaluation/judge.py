"""Judge plugin ``approach`` (role ``judges``): the approach mission judged after the flight,
on the simulator's ground truth when the vehicle has it (the simulated vehicle, or
HIL_STATE_QUATERNION from a SITL autopilot or the emulator) and the world knows the target;
otherwise on the autopilot's own reported states, and says so (:mod:`.evaluator`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from eaglemission.lab.evaluation.evaluator import Evaluation, evaluate
from pydantic import BaseModel, ConfigDict

from eaglemission.config import MissionFile
from eaglemission.interfaces import GroundTruth
from eaglemission.types import VehicleState


class JudgeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ApproachJudge:
    """Judges an ``approach`` mission's result (:class:`~eaglemission.interfaces.Judge`)."""

    Config = JudgeConfig
    description = ("the approach mission on ground truth: tool-point error at GRASP_READY, "
                   "envelope violations, the safe end (simulation)")

    def __init__(self, config: JudgeConfig | None = None, *, mission_file: MissionFile,
                 world: Any = None, truth: GroundTruth | None = None, **_context: Any) -> None:
        self.config = config or JudgeConfig()
        self.mission_file = mission_file
        self.world = world
        self.truth = truth

    def judge(self, result: Any, reported: Sequence[VehicleState], *, t0_ns: int,
              expected_action: str | None = None) -> Evaluation:
        target = getattr(self.world, "target_position_ned_m", None)
        if self.truth is not None:
            trajectory, judged_on = list(self.truth.trajectory()), "truth"
        else:
            trajectory, judged_on = list(reported), "estimate"
        return evaluate(result, trajectory, self.mission_file, target, t0_ns=t0_ns,
                        expected_action=expected_action, judged_on=judged_on)
