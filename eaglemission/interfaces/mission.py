"""Mission role (entry-point group ``eaglemission.missions``)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from eaglemission.clock import Clock
from eaglemission.interfaces.camera import Camera
from eaglemission.interfaces.detector import Detector
from eaglemission.interfaces.estimator import Estimator
from eaglemission.interfaces.fitter import PlaneFitter
from eaglemission.interfaces.judge import Judge
from eaglemission.interfaces.manipulator import Manipulator
from eaglemission.interfaces.vehicle import Vehicle

if TYPE_CHECKING:
    from eaglemission.config import MissionFile
    from eaglemission.perception.appearance import TargetAppearance
    from eaglemission.perception.keep import TargetKeeper


@dataclass(frozen=True)
class FlightParts:
    """Everything the assembly built for one flight (:mod:`eaglemission.flight.assembly`).

    ``vehicle`` is already wrapped in :class:`eaglemission.safety.envelope.SafeVehicle` and
    connected when the mission runs; the cameras are open. ``judge`` (None: nothing judges this
    flight) is the only holder of ground truth: the mission hands it its report at the end and
    never steers by it.
    """

    config: MissionFile
    clock: Clock
    vehicle: Vehicle
    cameras: Mapping[str, Camera]
    detectors: Mapping[str, Detector]
    coarse: Estimator
    fine: Estimator
    fitter: PlaneFitter | None = None
    appearance: TargetAppearance | None = None
    """The target's appearance, modelled once (None: nothing known of it)."""
    keepers: Mapping[str, TargetKeeper] = field(default_factory=dict)
    """Per camera, what keeps the confirmed target between the detector's frames (empty: the
    detector on every frame alone)."""
    judge: Judge | None = None
    manipulator: Manipulator | None = None
    """The tool (``manipulator`` section); None: a fixed tool at ``tool_point_m`` and the
    vehicle's gripper."""
    realtime: bool = False
    autopilot_guard: Any = None
    """The assembly's :class:`~eaglemission.safety.autopilot_guard.AutopilotGuard` (already applied:
    the mission logs its report and restores after landing); None: the mission makes its own."""


@runtime_checkable
class FlightRecorder(Protocol):
    """Where a mission sends what it logged and what it saw (a flight recording).

    ``bind`` is called once with the mission log's ``write(kind, **fields)``, so the recorder
    reports its own problems (write errors, dropped frames) in the log; ``record`` with every
    record the log gets and the exact JSON line written to the ``--log`` file (one source of
    truth); ``frame`` with every frame the mission processed, on the loop thread, and
    ``saliency`` with it and its detector's map shrunk (uint8; None: no usable map). None of
    them may block for long or raise: a recording never stops a mission.
    """

    def bind(self, write: Callable[..., Any]) -> None: ...

    def record(self, record: Mapping[str, Any], line: str) -> None: ...

    def frame(self, frame: Any) -> None: ...

    def saliency(self, frame: Any, thumb: Any) -> None: ...


@dataclass(frozen=True)
class MissionHooks:
    """Optional observers a caller (CLI, campaign, tests) gives a mission."""

    log_path: Path | None = None
    keep_log: bool = True
    """Keep the log's records in memory too (summaries, tests); campaigns turn it off."""
    on_state: Callable[[float, str, str, str], None] | None = None
    """Called with (t_s, new state, reason, failsafe action) on every state change."""
    on_frame: Callable[[Any], None] | None = None
    """Called with every grabbed frame (recording)."""
    on_telemetry: Callable[[Any], None] | None = None
    """Called with every telemetry snapshot the mission reads (recording)."""
    recorder: FlightRecorder | None = None
    """Gets every mission-log record and every processed frame (``run --record FILE.mcap``:
    :class:`eaglemission.recording.mcap_writer.McapRecorder`, opened by the assembly)."""
    record_all: bool = False
    """Grab both cameras whenever airborne (so a recording has both streams)."""
    grasp_callback: Callable[[], Any] | None = None
    side_tasks: tuple[Callable[[Any], Any], ...] = field(default_factory=tuple)
    """Coroutine functions ``f(mission)`` run beside the mission and cancelled at its end
    (test harnesses: fault injection)."""


@runtime_checkable
class MissionOutcome(Protocol):
    """What a mission run returns (the CLI prints ``report_lines()``)."""

    final_state: str
    reason: str
    truth_success: bool | None
    """The evaluator's verdict against ground truth; None when nothing was judged on truth."""

    def report_lines(self) -> list[str]: ...


@runtime_checkable
class Mission(Protocol):
    """A mission drives a vehicle from perception.

    Construction: ``cls(config=<cls.Config instance>, parts=FlightParts, hooks=MissionHooks)``.
    ``run`` flies until the mission is over (it ends the flight safely itself: land, return or
    hold) and returns a :class:`MissionOutcome`. ``interrupt`` (called from the event loop,
    e.g. on Ctrl-C) asks it to stop now with the given safe action ("hold", "land" or
    "return"), through the safety wrapper; ``run`` then returns as soon as that action is done.
    """

    async def run(self) -> Any: ...

    def interrupt(self, reason: str, action: str) -> None: ...
