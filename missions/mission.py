"""The ``approach`` mission plugin: flies the approach-to-grasp mission on the parts the
assembly built (:mod:`eaglemission.flight.assembly`).

``run`` builds the :class:`~eaglemission.missions.runner.MissionRunner` on the given parts and
flies; at the end it hands its report to the flight's judge when it has one
(:mod:`eaglemission.interfaces.judge`: in simulation, against ground truth), and logs and
prints the verdict.
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
from eaglemission.missions.log import MissionLog
from eaglemission.missions.perception import Tools
from eaglemission.missions.result import MissionResult
from eaglemission.missions.runner import MissionRunner

from eaglemission.config import MissionFile
from eaglemission.interfaces import FlightParts, FlightRecorder, Judge, MissionHooks, Verdict
from eaglemission.types import Frame, VehicleState


@dataclass
class ApproachOutcome:
    """A flown approach mission: what the mission reported and, when the flight had a judge,
    its verdict (``evaluation``)."""

    result: MissionResult
    reported: list[VehicleState]
    """The autopilot's reported states (50 Hz)."""
    log: MissionLog
    wall_s: float
    sim_s: float
    config: MissionFile
    estimated_trajectory: list[tuple[int, tuple[float, float, float]]] = field(
        default_factory=list)
    t0_ns: int = 0
    evaluation: Any = None
    """The judge's :class:`~eaglemission.interfaces.Verdict`; None: not judged."""
    judge: Judge | None = None

    @property
    def final_state(self) -> str:
        return self.result.final_state

    @property
    def reason(self) -> str:
        return self.result.reason

    @property
    def judged_on(self) -> str:
        """``"truth"``, ``"estimate"`` or ``"none"`` (no judge)."""
        return "none" if self.evaluation is None else str(self.evaluation.judged_on)

    @property
    def trajectory(self) -> list[VehicleState]:
        """The states judged (TRUE ones when ``judged_on == "truth"``), else the reported."""
        traj = getattr(self.evaluation, "trajectory", None)
        return list(traj) if traj else self.reported

    @property
    def target_position_ned_m(self) -> tuple[float, float, float] | None:
        target: tuple[float, float, float] | None = getattr(
            self.evaluation, "target_position_ned_m", None)
        return target

    @property
    def truth_success(self) -> bool | None:
        """The judge's verdict when it judged on ground truth, else None."""
        if self.judged_on != "truth" or self.target_position_ned_m is None:
            return None
        return bool(self.evaluation.success)

    @property
    def speedup(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else math.inf

    def reevaluate(self, *, expected_action: str | None) -> Verdict | None:
        """Judge again with the safe action a fault prescribes (fault campaigns)."""
        if self.judge is not None:
            self.evaluation = self.judge.judge(self.result, self.reported, t0_ns=self.t0_ns,
                                               expected_action=expected_action)
        verdict: Verdict | None = self.evaluation
        return verdict

    def report_lines(self) -> list[str]:
        r = self.result
        out = [f"final state: {r.final_state} ({r.reason}; action {r.action})",
               f"flew {self.sim_s:.1f} s in {self.wall_s:.1f} s wall ({self.speedup:.1f}x real "
               "time)"]
        if r.t_grasp_ready_s is not None:
            out.append(f"GRASP_READY at t = {r.t_grasp_ready_s:.2f} s")
        lines = [] if self.evaluation is None else list(self.evaluation.report_lines())
        judged = [line for line in lines if "tool-point error" in line]
        out += judged
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
        out += [line for line in lines if line not in judged]
        if self.evaluation is None:
            out.append("not judged (no judge for this flight: docs/mission.md)")
        return out

    def plot(self, path: Path) -> None:
        from eaglemission.missions.plot import plot_outcome

        plot_outcome(self, self.config, path)


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

    @staticmethod
    def recorded_rate_hz(config: ApproachConfig) -> float:
        """Frames a camera records per second, at most: its loop's processing rate."""
        return float(config.perception.process_rate_hz)

    @staticmethod
    def max_flight_s(config: ApproachConfig) -> float:
        """The longest flight the state timeouts allow (each state to its timeout, then the
        settle time): the bound of the recording's expected size."""
        t = config.timeouts
        return float(t.preflight_s + t.takeoff_s + t.cruise_s + t.coarse_approach_s
                     + t.fine_approach_s + t.grasp_ready_s + t.target_lost_s
                     + t.settle_s)

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
        tools = {c: Tools(p.detectors[c], p.coarse, p.fine, p.fitter, p.appearance,
                          p.keepers.get(c)) for c in p.cameras}
        runner = MissionRunner(cfg, self.config, vehicle=p.vehicle, cameras=dict(p.cameras),
                               models=models, tools=tools, clock=clock, mission_log=mlog,
                               grasp_callback=h.grasp_callback, on_frame=h.on_frame,
                               on_telemetry=on_telemetry, record_all=h.record_all,
                               on_processed=None if h.recorder is None else _to_recorder(
                                   h.recorder),
                               on_state=h.on_state, autopilot_guard=p.autopilot_guard,
                               manipulator=p.manipulator)
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
        verdict = None if p.judge is None else p.judge.judge(result, reported, t0_ns=t0_ns)
        if verdict is not None:
            mlog.write("evaluation", **verdict.as_dict())
        mlog.close()
        return ApproachOutcome(result, reported, mlog, wall, (clock.now_ns() - t0_ns) * 1e-9,
                               cfg, estimated, t0_ns, verdict, p.judge)
