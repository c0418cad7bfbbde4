"""Fault harness of the closed-loop fault tests: faults injected when the mission enters a
state. A camera dropout or occlusion wraps the assembled cameras (:class:`FaultyCamera`, painted
over from the world's truth); link, GPS, battery and pilot faults call the simulated vehicle's
injection methods. Flown through :func:`fly_with_faults` = ``run_simulation`` + its hooks.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from eaglemission.missions.mission import ApproachOutcome
from eaglemission.missions.sim import run_simulation

from eaglemission import errors
from eaglemission.assembly import Assembly
from eaglemission.config import MissionFile
from eaglemission.context import WORLD
from eaglemission.types import FlightMode, Frame


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


def fly_with_faults(cfg: MissionFile, faults: list[Fault], **kw: Any) -> ApproachOutcome:
    """:func:`run_simulation` with ``faults`` injected; evaluated against their safe action."""
    box: list[Assembly] = []

    def prepare(asm: Assembly) -> None:
        box.append(asm)
        world = asm.shared.get(WORLD)
        for cid in list(asm.cameras):
            asm.cameras[cid] = FaultyCamera(asm.cameras[cid], world, asm.clock)

    return run_simulation(cfg, prepare=prepare, side_tasks=(_fault_task(faults, box),),
                          expected_action=expected_action(cfg, faults), **kw)
