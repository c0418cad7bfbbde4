"""Simulated flights through the assembly, and the fault harness of the fault tests.

:func:`run_simulation` flies a mission file through :func:`eaglemission.assembly.fly_sync`,
exactly as ``eaglemission run`` does, and returns the mission's
:class:`~eaglemission.missions.mission.ApproachOutcome`. Faults (:class:`Fault`) are injected
by a side task when the mission enters a state: a camera dropout or occlusion wraps the
assembled cameras (:class:`FaultyCamera`); link, GPS, battery and pilot faults call the
simulated vehicle's injection methods.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from eaglemission.missions.approach import ApproachConfig
from eaglemission.missions.mission import ApproachOutcome

from eaglemission import errors
from eaglemission.assembly import Assembly, FlightOptions, fly_sync
from eaglemission.config import MissionFile
from eaglemission.context import WORLD
from eaglemission.interfaces import MissionHooks
from eaglemission.types import FlightMode, Frame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Fault:
    """A fault injected when the mission enters ``at_state`` (+ ``delay_s``).

    kind: ``camera_dropout`` | ``occlusion`` | ``link_loss`` | ``gps_loss`` | ``battery_low`` |
    ``pilot_mode``
    """

    kind: str
    at_state: str = "FINE_APPROACH"
    delay_s: float = 0.5
    duration_s: float = 1.0
    value: float = 0.1


class FaultyCamera:
    """Wraps a camera: raises :class:`GrabTimeout` during a dropout, hides the target during an
    occlusion (painted over from the world's truth: this is the test harness, not the
    mission)."""

    def __init__(self, inner: Any, world: Any, clock: Any) -> None:
        self.inner, self.world, self.clock = inner, world, clock
        self.camera_id = inner.camera_id
        self.model = inner.model
        self.dropout_until_ns = 0
        self.occluded_until_ns = 0

    @property
    def frame_rate_hz(self) -> float:
        return float(getattr(self.inner, "frame_rate_hz", float("inf")))

    def open(self) -> None:
        self.inner.open()

    def close(self) -> None:
        self.inner.close()

    def grab(self, *, timeout_s: float) -> Frame:
        now = self.clock.now_ns()
        if now < self.dropout_until_ns:
            raise errors.GrabTimeout(self.camera_id, timeout_s)
        frame: Frame = self.inner.grab(timeout_s=timeout_s)
        if now < self.occluded_until_ns and self.world is not None:
            truth = self.world.truth(self.camera_id, frame.seq)
            if truth.target_visible and len(truth.target_polygon_px) >= 3:
                img = frame.image.copy()
                poly = np.asarray(truth.target_polygon_px, dtype=np.float64)
                c = poly.mean(axis=0)
                big = c + (poly - c) * 1.6  # a grass-coloured cover larger than the target
                mask = np.zeros(img.shape[:2], np.uint8)
                cv2.fillPoly(mask, [np.round(big).astype(np.int32)], 255)
                ring = cv2.bitwise_and(cv2.dilate(mask, np.ones((15, 15), np.uint8)),
                                       cv2.bitwise_not(mask))
                colour = np.median(img[ring > 0], axis=0) if (ring > 0).any() else img.mean((0, 1))
                img[mask > 0] = colour.astype(np.uint8)
                frame = Frame(img, frame.timestamp_ns, frame.camera_id, frame.seq,
                              frame.exposure_s)
        return frame


def _fault_task(faults: list[Fault], asm_box: list[Assembly]) -> Callable[[Any], Awaitable[None]]:
    async def inject(mission: Any) -> None:
        asm = asm_box[0]
        clock, vehicle = asm.clock, asm.driver
        cams = [c for c in asm.cameras.values() if isinstance(c, FaultyCamera)]
        pending = list(faults)
        armed: dict[int, int] = {}
        while pending:
            runner = mission.runner
            if runner is None or runner.machine.final:
                await clock.sleep(0.05)
                if runner is not None:
                    return
                continue
            now = clock.now_ns()
            for f in list(pending):
                key = id(f)
                if key not in armed and runner.machine.state.value == f.at_state:
                    armed[key] = now + int(f.delay_s * 1e9)
                if key in armed and now >= armed[key]:
                    pending.remove(f)
                    until = now + int(f.duration_s * 1e9)
                    runner.log.write("event", source="fault", text=f"inject {f.kind}", fault=f)
                    if f.kind == "camera_dropout":
                        for c in cams:
                            c.dropout_until_ns = until
                    elif f.kind == "occlusion":
                        for c in cams:
                            c.occluded_until_ns = until
                    elif f.kind == "link_loss":
                        vehicle.inject_link_loss(f.duration_s)
                    elif f.kind == "gps_loss":
                        vehicle.inject_gps_loss(f.duration_s)
                    elif f.kind == "battery_low":
                        vehicle.set_battery_fraction(f.value)
                    elif f.kind == "pilot_mode":
                        vehicle.pilot_take_control(FlightMode.POSCTL)
                    else:
                        raise ValueError(f"fault kind: unknown {f.kind!r}")
            await clock.sleep(0.05)

    return inject


def expected_action(cfg: MissionFile, faults: list[Fault]) -> str | None:
    """The safe action the configuration prescribes for the first fault (for the evaluator)."""
    s = cfg.safety
    for f in faults:
        return {"link_loss": s.link_loss_action, "gps_loss": s.gps_loss_action,
                "battery_low": s.low_battery_action, "pilot_mode": "release",
                "camera_dropout": None, "occlusion": None}.get(f.kind)
    return None


def effective_vehicle_config(cfg: MissionFile) -> Any:
    """The ``simulated`` vehicle's config as it flies ``cfg``: speeds inside the envelope
    (:func:`~eaglemission.drivers.vehicles.dynamics.speeds_within_envelope`) and the return
    height the mission sets before the flight (cruise altitude clamped into the band)."""
    from eaglemission import registry

    cls = registry.get("vehicles", "simulated")
    v = cls(cls.Config.model_validate(dict(cfg.vehicle.params)), safety=cfg.safety)  # type: ignore[attr-defined]
    s = cfg.safety
    rtl = max(s.min_altitude_m + 1.0, min(cfg.mission.cruise_altitude_m, s.max_altitude_m - 1.0))
    return v.config.model_copy(update={"rtl_return_altitude_m": rtl})


def run_simulation(cfg: MissionFile, *, realtime: bool = False,
                   params: ApproachConfig | None = None, log_path: str | Path | None = None,
                   record_dir: str | Path | None = None, faults: list[Fault] | None = None,
                   grasp_callback: Callable[[], Awaitable[None]] | None = None,
                   on_state: Callable[[float, str, str, str], None] | None = None,
                   keep_log: bool = True) -> ApproachOutcome:
    """Fly ``cfg`` through the assembly (virtual time unless ``realtime``) and return the
    mission's outcome; raise :class:`~eaglemission.errors.EagleMissionError` when the flight
    could not start (config, connection)."""
    if params is not None:
        cfg = MissionFile.model_validate({**cfg.model_dump(),
                                          "mission": {**cfg.mission.model_dump(),
                                                      "params": params.model_dump()}})
    faults = list(faults or [])
    box: list[Assembly] = []
    recorder = None
    hooks_kw: dict[str, Any] = {}
    if record_dir is not None:
        from eaglemission.recording import RunRecorder

        recorder = RunRecorder(Path(record_dir), when_full="drop" if realtime else "wait")
        hooks_kw.update(on_frame=recorder.write_frame, on_telemetry=recorder.write_state,
                        record_all=True)

    def prepare(asm: Assembly) -> None:
        box.append(asm)
        if recorder is not None:
            recorder.set_models({c: cam.model for c, cam in asm.cameras.items()})
        if faults:
            world = asm.shared.get(WORLD)
            for cid in list(asm.cameras):
                asm.cameras[cid] = FaultyCamera(asm.cameras[cid], world, asm.clock)

    hooks = MissionHooks(log_path=None if log_path is None else Path(log_path),
                         on_state=on_state, grasp_callback=grasp_callback,
                         side_tasks=(_fault_task(faults, box),) if faults else (),
                         keep_log=keep_log, **hooks_kw)
    try:
        res = fly_sync(cfg, FlightOptions(realtime=realtime, hooks=hooks, prepare=prepare))
    finally:
        if recorder is not None:
            recorder.close()
    if res.outcome is None:
        raise errors.EagleMissionError(f"the flight did not happen (exit {res.exit_code}): "
                                       f"{res.error}")
    out: ApproachOutcome = res.outcome  # type: ignore[assignment]
    if faults:
        out.reevaluate(expected_action=expected_action(cfg, faults))
    return out
