"""The ``faults:`` section flown: the assembly wraps the parts each fault lives in, and a task
beside the mission injects each fault at its time and writes a ``fault_injected`` record.

Camera faults go to the ``faulty`` camera plugin wrapped around the configured cameras;
detector and estimator faults to :mod:`eaglemission.lab.faults.wrappers`; vehicle and world faults to
the vehicle's own injection methods (the ``simulated`` vehicle has them all); the link kinds of
a ``mavsdk`` vehicle travel a loopback UDP relay (:mod:`.link_relay`) that
:class:`FaultInjection` puts between MAVSDK and the autopilot before the vehicle connects. A
vehicle that can carry neither is refused with the fault's path. Nothing here touches the
mission's code: the mission only sees what a real failure would show it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any

from eaglemission.lab.faults.config import FaultsConfig, FaultSpec
from eaglemission.lab.faults.link_relay import LinkFaultRelay
from eaglemission.lab.faults.outcomes import OUTCOMES
from eaglemission.lab.faults.schedule import ActiveFaults
from eaglemission.lab.faults.wrappers import FaultyDetector, FaultyEstimator

from eaglemission import registry
from eaglemission.config import MissionFile
from eaglemission.errors import ConfigError
from eaglemission.flight.context import WORLD
from eaglemission.interfaces import MissionHooks
from eaglemission.types import FlightMode

log = logging.getLogger(__name__)

CAMERA_KINDS = frozenset({"camera_drop", "camera_freeze", "corrupted_frame", "truncated_frame",
                          "exposure_jump", "camera_device_loss", "camera_clock_jump",
                          "occlusion"})
DETECTOR_KINDS = frozenset({"detector_exception", "nan_map", "slow_frame"})
ESTIMATOR_KINDS = frozenset({"degenerate_corners", "pose_flip"})
VEHICLE_METHODS = {"link_loss": "inject_link_loss", "gps_loss": "inject_gps_loss",
                   "battery_drain": "set_battery_fraction", "pilot_mode": "pilot_take_control",
                   "command_denied": "deny_next_command", "wind_gust": "inject_wind_gust",
                   "link_delay": "inject_link_delay", "link_duplicate": "inject_link_duplicate",
                   "link_reorder": "inject_link_reorder",
                   "autopilot_clock_jump": "inject_autopilot_clock_jump"}
POLL_S = 0.02
LINK_KINDS = frozenset({"link_loss", "link_delay", "link_duplicate", "link_reorder",
                        "autopilot_clock_jump"})


def injector_of(driver: Any, kind: str, link: Any = None) -> Any:
    """The callable injecting ``kind`` into ``driver`` (its own method, else its ``link``
    relay's), or None."""
    name = VEHICLE_METHODS[kind]
    for owner in (driver, link):
        fn = getattr(owner, name, None) if owner is not None else None
        if callable(fn):
            return fn
    return None


class FaultInjector:
    """Injects ``specs`` into the parts of one flight (see :func:`attach`)."""

    def __init__(self, specs: list[FaultSpec], active: ActiveFaults, clock: Any, driver: Any,
                 max_speed_mps: float, link: Any = None) -> None:
        self.specs, self.active, self.clock, self.driver = specs, active, clock, driver
        self.link = link
        self.max_speed_mps = max_speed_mps
        self.injected: list[tuple[int, FaultSpec]] = []

    def _vehicle(self, spec: FaultSpec) -> dict[str, Any]:
        fn = injector_of(self.driver, spec.kind, self.link)
        if spec.kind in ("link_loss", "gps_loss", "link_duplicate", "link_reorder"):
            fn(spec.duration_s)
            return {}
        if spec.kind == "link_delay":
            fn(spec.value, spec.duration_s)
            return {"delay_s": spec.value}
        if spec.kind == "autopilot_clock_jump":
            fn(spec.value)
            return {"jump_s": spec.value}
        if spec.kind == "battery_drain":
            fn(spec.value)
            return {"fraction": spec.value}
        if spec.kind == "pilot_mode":
            fn(FlightMode.POSCTL)
            return {"mode": FlightMode.POSCTL.value}
        if spec.kind == "command_denied":
            fn(spec.command)
            return {"command": spec.command}
        speed = spec.value * self.max_speed_mps  # wind_gust
        rad = math.radians(spec.direction_deg)
        fn(speed * math.cos(rad), speed * math.sin(rad), spec.duration_s)
        return {"speed_mps": round(speed, 3), "direction_deg": spec.direction_deg}

    def fire(self, spec: FaultSpec, now_ns: int) -> dict[str, Any]:
        """Inject one fault now; returns the fields of its ``fault_injected`` record."""
        self.active.activate(spec, now_ns)
        extra = self._vehicle(spec) if spec.kind in VEHICLE_METHODS else {}
        self.injected.append((now_ns, spec))
        return {"fault": spec.kind, "where": OUTCOMES[spec.kind].where,
                "duration_s": spec.duration_s, "size": spec.value, "camera": spec.camera,
                "at_state": spec.at_state, **extra}

    async def run(self, mission: Any) -> None:
        """Beside the mission: fire each fault when its time or state comes."""
        t0 = self.clock.now_ns()
        due: dict[int, int] = {i: t0 + int(f.at_s * 1e9) for i, f in enumerate(self.specs)
                               if f.at_s is not None}
        pending = set(range(len(self.specs)))
        write = getattr(mission, "log_record", None)
        while pending:
            now = self.clock.now_ns()
            state = getattr(getattr(mission, "state", None), "value", None)
            for i in sorted(pending):
                f = self.specs[i]
                if i not in due and f.at_state is not None and state == f.at_state:
                    due[i] = now + int(f.delay_s * 1e9)
                if i in due and now >= due[i]:
                    pending.discard(i)
                    fields = self.fire(f, now)
                    if callable(write):
                        write("fault_injected", **fields)
                    else:
                        log.warning("fault injected: %s", fields)
            await self.clock.sleep(POLL_S)


def attach(asm: Any, section: FaultsConfig, link: Any = None) -> FaultInjector | None:
    """Wrap ``asm``'s parts for a ``faults:`` section (None: nothing to inject); ``link``: the
    relay carrying the link kinds. Raises :class:`ConfigError` naming the fault when its part
    cannot carry it."""
    if not section.inject:
        return None
    specs = list(section.inject)
    kinds = {f.kind for f in specs}
    problems = [f"faults.inject.{i}.kind: the {asm.config.vehicle.type!r} vehicle cannot "
                f"inject {f.kind} (no {VEHICLE_METHODS[f.kind]}(); the `simulated` vehicle "
                "can" + (", and the `mavsdk` one at a udpin:// URL, through a relay)"
                         if f.kind in LINK_KINDS else ")")
                for i, f in enumerate(specs)
                if f.kind in VEHICLE_METHODS and injector_of(asm.driver, f.kind, link) is None]
    if problems:
        raise ConfigError(problems)
    active = ActiveFaults()
    if kinds & CAMERA_KINDS:
        cls = registry.get("cameras", "faulty")
        world = asm.shared.get(WORLD)
        for cid in list(asm.cameras):
            asm.cameras[cid] = cls(cls.Config(), inner=asm.cameras[cid], faults=active,
                                   clock=asm.clock, world=world)
    if kinds & DETECTOR_KINDS:
        asm.detectors = {c: FaultyDetector(d, active, asm.clock) for c, d in asm.detectors.items()}
    if kinds & ESTIMATOR_KINDS:  # both: the mission falls back on the coarse one
        asm.fine = FaultyEstimator(asm.fine, active, asm.clock)
        asm.coarse = FaultyEstimator(asm.coarse, active, asm.clock)
    return FaultInjector(specs, active, asm.clock, asm.driver,
                         asm.config.safety.max_horizontal_speed_mps, link)


def with_hooks(injector: FaultInjector | None, hooks: MissionHooks) -> MissionHooks:
    """``hooks`` plus the injector's task beside the mission."""
    if injector is None:
        return hooks
    return replace(hooks, side_tasks=(*hooks.side_tasks, injector.run))


class FaultInjection:
    """Section plugin ``faults``: the mission file's ``faults:`` section flown
    (:class:`~eaglemission.interfaces.Section`)."""

    Config = FaultsConfig
    description = ("faults injected where they happen: cameras, detector, estimators, the "
                   "vehicle's link, autopilot, GPS, battery, wind (docs/faults.md)")

    def __init__(self, config: FaultsConfig | None = None, **_context: Any) -> None:
        self.config = config or FaultsConfig()
        self.injector: FaultInjector | None = None
        self.relay: LinkFaultRelay | None = None

    def prepare(self, config: MissionFile) -> MissionFile:
        """With a link kind and the ``mavsdk`` vehicle: start the relay on the vehicle's
        ``udpin://`` address and point MAVSDK at it."""
        kinds = {f.kind for f in self.config.inject}
        if not kinds & LINK_KINDS or config.vehicle.type != "mavsdk" or self.relay is not None:
            return config
        params = registry.validate_params("vehicles", "mavsdk", config.vehicle.params,
                                          path="vehicle.params")
        url = str(params.model_dump()["url"])
        if not url.startswith("udpin://"):
            raise ConfigError(f"faults: the link kinds travel a UDP relay, which needs "
                              f"vehicle.params.url = udpin://HOST:PORT, got {url!r}")
        self.relay = LinkFaultRelay(url)
        client = self.relay.start()
        vehicle = config.vehicle.model_copy(
            update={"params": {**config.vehicle.params, "url": client}})
        return config.model_copy(update={"vehicle": vehicle})

    def attach(self, assembly: Any) -> None:
        self.injector = attach(assembly, self.config, self.relay)

    def mission_hooks(self, hooks: MissionHooks) -> MissionHooks:
        return with_hooks(self.injector, hooks)

    def close(self) -> None:
        if self.relay is not None:
            self.relay.stop()
