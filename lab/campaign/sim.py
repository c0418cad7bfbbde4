"""Simulated flights through the assembly.

:func:`run_simulation` flies a mission file through :func:`eaglemission.flight.run.fly_sync`,
exactly as ``eaglemission run`` does, and returns the mission's
:class:`~eaglemission.missions.mission.ApproachOutcome`. A test harness reaches the assembled
parts through ``prepare`` (called once they are built, before the flight) and runs alongside
the mission through ``side_tasks`` (tests/missions/fault_harness.py injects faults that way).
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.mission import ApproachOutcome

from eaglemission import errors
from eaglemission.config import MissionFile
from eaglemission.flight.assembly import Assembly
from eaglemission.flight.run import FlightOptions, fly_sync
from eaglemission.interfaces import MissionHooks

log = logging.getLogger(__name__)


def effective_vehicle_config(cfg: MissionFile) -> Any:
    """The ``simulated`` vehicle's config as it flies ``cfg``: speeds inside the envelope
    (:func:`~eaglemission.lab.vehicles.multicopter.dynamics.speeds_within_envelope`) and the return
    height the mission sets before the flight (cruise altitude clamped into the band)."""
    from eaglemission import registry

    cls = registry.get("vehicles", "simulated")
    v = cls(cls.Config.model_validate(dict(cfg.vehicle.params)), safety=cfg.safety)
    s = cfg.safety
    rtl = max(s.min_altitude_m + 1.0, min(cfg.mission.cruise_altitude_m, s.max_altitude_m - 1.0))
    return v.config.model_copy(update={"rtl_return_altitude_m": rtl})


def run_simulation(cfg: MissionFile, *, realtime: bool = False,
                   params: ApproachConfig | None = None, log_path: str | Path | None = None,
                   record_dir: str | Path | None = None,
                   prepare: Callable[[Assembly], None] | None = None,
                   side_tasks: tuple[Callable[[Any], Awaitable[None]], ...] = (),
                   expected_action: str | None = None,
                   grasp_callback: Callable[[], Awaitable[None]] | None = None,
                   on_state: Callable[[float, str, str, str], None] | None = None,
                   keep_log: bool = True) -> ApproachOutcome:
    """Fly ``cfg`` through the assembly (virtual time unless ``realtime``) and return the
    mission's outcome; raise :class:`~eaglemission.errors.EagleMissionError` when the flight
    could not start (config, connection). ``expected_action``: the safe action a harness's
    injected failure should end in (the evaluation checks it)."""
    if params is not None:
        cfg = MissionFile.model_validate({**cfg.model_dump(),
                                          "mission": {**cfg.mission.model_dump(),
                                                      "params": params.model_dump()}})
    recorder = None
    hooks_kw: dict[str, Any] = {}
    if record_dir is not None:
        from eaglemission.recording.folder import RunRecorder

        recorder = RunRecorder(Path(record_dir), when_full="drop" if realtime else "wait")
        hooks_kw.update(on_frame=recorder.write_frame, on_telemetry=recorder.write_state,
                        record_all=True)

    def prepare_all(asm: Assembly) -> None:
        if recorder is not None:
            recorder.set_models({c: cam.model for c, cam in asm.cameras.items()})
        if prepare is not None:
            prepare(asm)

    hooks = MissionHooks(log_path=None if log_path is None else Path(log_path),
                         on_state=on_state, grasp_callback=grasp_callback,
                         side_tasks=side_tasks,
                         keep_log=keep_log, **hooks_kw)
    try:
        res = fly_sync(cfg, FlightOptions(realtime=realtime, hooks=hooks, prepare=prepare_all))
    finally:
        if recorder is not None:
            recorder.close()
    if res.outcome is None:
        raise errors.EagleMissionError(f"the flight did not happen (exit {res.exit_code}): "
                                       f"{res.error}")
    out = res.outcome
    if not isinstance(out, ApproachOutcome):
        raise errors.EagleMissionError(f"the mission plugin returned {type(out).__name__}, "
                                       "not the approach mission's outcome")
    if expected_action is not None:
        out.reevaluate(expected_action=expected_action)
    return out
