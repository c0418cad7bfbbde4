"""The ``approach`` mission plugin: flies the approach-to-grasp mission on the parts the
assembly built (:mod:`eaglemission.assembly`) and judges the flight.

``run`` builds the :class:`~eaglemission.missions.runner.MissionRunner` on the given parts,
flies, and evaluates: against ground truth when the vehicle has it (the simulated vehicle, or
HIL_STATE_QUATERNION from a SITL autopilot or the emulator) and the world knows the target
(synthetic cameras); otherwise on the autopilot's own estimate, and says so.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from eaglemission.missions.approach import MissionState
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.evaluator import Evaluation, evaluate
from eaglemission.missions.log import MissionLog
from eaglemission.missions.result import MissionResult
from eaglemission.missions.runner import MissionRunner

from eaglemission.config import MissionFile
from eaglemission.context import WORLD
from eaglemission.interfaces import FlightParts, FlightRecorder, MissionHooks
from eaglemission.types import Frame, VehicleState


@dataclass
class ApproachOutcome:
    """A flown approach mission: what the mission reported, what the evaluator judged."""

    result: MissionResult
    evaluation: Evaluation
    trajectory: list[VehicleState]
    """TRUE states when ``judged_on == "truth"``, else the autopilot's reported states."""
    judged_on: str
    target_position_ned_m: tuple[float, float, float] | None
    log: MissionLog
    wall_s: float
    sim_s: float
    config: MissionFile
    estimated_trajectory: list[tuple[int, tuple[float, float, float]]] = field(
        default_factory=list)
    world: object | None = None
    t0_ns: int = 0

    @property
    def final_state(self) -> str:
        return self.result.final_state

    @property
    def reason(self) -> str:
        return self.result.reason

    @property
    def truth_success(self) -> bool | None:
        """The evaluator's verdict when it judged on ground truth, else None."""
        if self.judged_on != "truth" or self.target_position_ned_m is None:
            return None
        return self.evaluation.success

    @property
    def speedup(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.inf

    def reevaluate(self, *, expected_action: str | None) -> Evaluation:
        """Judge again with the safe action a fault prescribes (fault tests)."""
        self.evaluation = _evaluate(self.result, self.trajectory, self.config,
                                    self.target_position_ned_m, self.t0_ns, expected_action)
        return self.evaluation

    def report_lines(self) -> list[str]:
        r, ev = self.result, self.evaluation
        out = [f"final state: {r.final_state} ({r.reason}; action {r.action})",
               f"flew {self.sim_s:.1f} s in {self.wall_s:.1f} s wall ({self.speedup:.1f}x real "
               "time)"]
        if r.t_grasp_ready_s is not None:
            out.append(f"GRASP_READY at t = {r.t_grasp_ready_s:.2f} s")
        basis = ("true" if self.judged_on == "truth"
                 else "judged on the autopilot's estimate (no ground truth):")
        if ev.horizontal_error_m is not None:
            out.append(f"{basis} tool-point error: horizontal {ev.horizontal_error_m * 100:.1f} "
                       f"cm, grasp distance {ev.grasp_distance_m:.3f} m")
        if r.estimated_tool_errors_m is not None:
            h, d = r.estimated_tool_errors_m
            out.append(f"mission's own estimate: horizontal {h * 100:.1f} cm, grasp distance "
                       f"{d:.3f} m")
        if r.latencies_ms:
            out.append(f"frame-to-setpoint latency p50/p90: {np.percentile(r.latencies_ms, 50):.1f}"
                       f" / {np.percentile(r.latencies_ms, 90):.1f} ms (wall clock, "
                       f"{len(r.latencies_ms)} samples)")
        if r.failsafe_params:
            out.append("autopilot failsafe parameters: " + ", ".join(
                f"{k}={v:g}" for k, v in r.failsafe_params.items()))
        out += [f"  warning: {w}" for w in r.failsafe_warnings]
        out.append(f"frames processed: {r.frames_processed}, with a detection: {r.detections}")
        for cam, n in r.frame_counts.items():
            out.append(f"camera {cam}: {n['grabbed']} frames grabbed = {n['processed']} processed "
                       f"+ {n['skipped']} skipped + {n['dropped']} dropped")
        out.append(f"envelope violations ({'true' if self.judged_on == 'truth' else 'reported'}"
                   f" trajectory): {len(ev.violations)}" + "".join(
                       f"\n  {v.kind} at {v.t_s:.1f} s: {v.value:.2f} > {v.limit:.2f} for "
                       f"{v.duration_s:.1f} s" for v in ev.violations))
        verdict = "SUCCESS" if ev.success else "FAILURE"
        if self.truth_success is None:
            verdict += " (not judged on ground truth)"
        out.append(f"evaluator: {verdict}" + (f" -- {ev.explanation}" if ev.explanation else ""))
        return out

    def plot(self, path: Path) -> None:
        from eaglemission.missions.plot import plot_outcome

        plot_outcome(self, self.config, path)


def _evaluate(result: MissionResult, trajectory: list[VehicleState], cfg: MissionFile,
              target: tuple[float, float, float] | None, t0_ns: int,
              expected_action: str | None) -> Evaluation:
    return evaluate(result, trajectory, cfg, target, t0_ns=t0_ns,
                    expected_action=expected_action)


def _to_recorder(recorder: FlightRecorder) -> Callable[[Frame, Any], None]:
    """A processed frame and its saliency thumbnail, handed to the flight recorder."""
    def processed(frame: Frame, thumb: Any) -> None:
        recorder.frame(frame)
        recorder.saliency(frame, thumb)
    return processed


class ApproachMission:
    """Plugin ``approach``: the approach-to-grasp mission of paper Sec. 3.2 on assembled
    parts (``parts``: :class:`~eaglemission.interfaces.FlightParts`)."""

    Config = ApproachConfig
    description = ("approach-to-grasp: cruise, wide-camera coarse approach, narrow-camera "
                   "RPnP fine approach, grasp-ready hold (paper Sec. 3.2)")

    def __init__(self, config: ApproachConfig | None = None, *, parts: FlightParts,
                 hooks: MissionHooks | None = None, **_context: Any) -> None:
        self.config = config or ApproachConfig()
        self.parts = parts
        self.hooks = hooks or MissionHooks()
        self.runner: MissionRunner | None = None
        self._interrupt: tuple[str, str] | None = None

    @staticmethod
    def plot_recording(records: list[dict[str, Any]], cfg: MissionFile, path: Path) -> None:
        """``eaglemission log --plot``: the figure of ``run --plot`` from a recording."""
        from eaglemission.missions.plot import plot_recording

        plot_recording(records, cfg, path)

    @property
    def state(self) -> MissionState | None:
        return None if self.runner is None else self.runner.machine.state

    def log_record(self, kind: str, **fields: Any) -> None:
        """Write a record to this flight's mission log (the fault injector's
        ``fault_injected``); nothing before the mission runs."""
        if self.runner is not None:
            self.runner.log.write(kind, **fields)

    def interrupt(self, reason: str, action: str) -> None:
        if self.runner is None:
            self._interrupt = (reason, action)
        else:
            self.runner.interrupt(reason, action)

    async def run(self) -> ApproachOutcome:
        p, h = self.parts, self.hooks
        cfg = p.config
        clock = p.clock
        mlog = MissionLog(h.log_path, now_ns=clock.now_ns, keep=h.keep_log)
        if h.recorder is not None:
            h.recorder.bind(mlog.write)
            mlog.subscribe(h.recorder.record)
        estimated: list[tuple[int, tuple[float, float, float]]] = []
        reported: list[VehicleState] = []

        def on_telemetry(vs: VehicleState) -> None:
            if not reported or vs.timestamp_ns - reported[-1].timestamp_ns >= 20_000_000:
                reported.append(vs)
            if not estimated or vs.timestamp_ns - estimated[-1][0] >= 100_000_000:
                estimated.append((vs.timestamp_ns, vs.position_ned_m))
            if h.on_telemetry is not None:
                h.on_telemetry(vs)

        wall0 = time.perf_counter()
        t0_ns = clock.now_ns()
        models = {c: cam.model for c, cam in p.cameras.items()}
        runner = MissionRunner(cfg, self.config, vehicle=p.vehicle, cameras=dict(p.cameras),
                               models=models, detectors=dict(p.detectors), coarse=p.coarse,
                               fine=p.fine, fitter=p.fitter, tracker=p.tracker,
                               clock=clock, mission_log=mlog,
                               grasp_callback=h.grasp_callback, on_frame=h.on_frame,
                               on_telemetry=on_telemetry, record_all=h.record_all,
                               on_processed=None if h.recorder is None else _to_recorder(
                                   h.recorder),
                               on_state=h.on_state, autopilot_guard=p.autopilot_guard)
        self.runner = runner
        if self._interrupt is not None:
            runner.interrupt(*self._interrupt)
        side = [asyncio.ensure_future(fn(self)) for fn in h.side_tasks]
        try:
            result = await runner.run()
        finally:
            for t in side:
                t.cancel()
            for t in side:
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await t
        wall = time.perf_counter() - wall0
        world = p.shared.get(WORLD)
        target: tuple[float, float, float] | None = None
        truth_target = getattr(world, "target_position_ned_m", None)
        if truth_target is not None:
            target = (float(truth_target[0]), float(truth_target[1]), float(truth_target[2]))
        if p.truth is not None:
            trajectory, judged_on = list(p.truth.trajectory()), "truth"
        else:
            trajectory, judged_on = reported, "estimate"
        ev = _evaluate(result, trajectory, cfg, target, t0_ns, None)
        mlog.write("evaluation", judged_on=judged_on, **ev.as_dict())
        mlog.close()
        return ApproachOutcome(result, ev, trajectory, judged_on, target, mlog, wall,
                               (clock.now_ns() - t0_ns) * 1e-9, cfg, estimated, world, t0_ns)
