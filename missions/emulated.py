"""``eaglemission run --vehicle emulator``: the same mission through the MAVSDK driver and the
PX4-like MAVLink emulator (in-process ``raw://`` link), in real time.

The synthetic cameras render from the emulator's TRUE pose (a camera sees the world from where
the vehicle is, not from the autopilot's drifting estimate); on a real PX4 SITL (``url``), whose
truth is not exposed, they render from the pose the driver reports (telemetry ``state_at``).
The evaluator's truth is the emulator's true position, sampled by the runner's telemetry task.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from eaglemission.missions.approach import ApproachConfig
from eaglemission.missions.evaluator import evaluate
from eaglemission.missions.log import MissionLog
from eaglemission.missions.runner import MissionRunner
from eaglemission.missions.sim import (
    FaultyCamera,
    SimOutcome,
    _make_recorder,
    build_detector,
    report_state_changes,
    vehicle_params,
)

from eaglemission import errors, registry
from eaglemission.clock import MonotonicClock
from eaglemission.config import MissionFile
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.types import VehicleState

log = logging.getLogger(__name__)


async def fly_emulated(cfg: MissionFile, *, log_path: str | Path | None = None,
                       record_dir: str | Path | None = None,
                       on_state: Callable[[float, str, str, str], None] | None = None,
                       connect_timeout_s: float = 20.0, url: str | None = None) -> SimOutcome:
    """Fly ``cfg`` through the MAVSDK driver: against the in-process emulator, or against a
    real autopilot at ``url`` (e.g. a PX4 SITL; then the "truth" for the evaluator is the
    autopilot's own telemetry, the only thing available)."""
    from eaglemission.drivers.cameras.synthetic import make_synthetic_rig
    from eaglemission.drivers.vehicles.dynamics import DynamicsParams, RangefinderParams
    from eaglemission.drivers.vehicles.mavlink_emulator import EmulatorConfig, Px4Emulator
    from eaglemission.drivers.vehicles.mavsdk_vehicle import MavsdkVehicle

    from eaglemission.safety import SafeVehicle

    if cfg.simulation is None:
        raise errors.ConfigError("simulation: the emulator flight needs the `simulation` section")
    params = ApproachConfig.model_validate(dict(cfg.mission.params))
    clock = MonotonicClock()
    mlog = MissionLog(log_path, now_ns=clock.now_ns)
    sim = cfg.simulation
    dyn = DynamicsParams.model_validate(vehicle_params(cfg).get("dynamics", {}))
    # the same downward rangefinder as the simulated vehicle (DISTANCE_SENSOR through MAVSDK)
    rf = RangefinderParams.model_validate(vehicle_params(cfg).get("rangefinder", {}))
    emu = None if url else Px4Emulator(EmulatorConfig(
        seed=sim.seed, wind_ne_mps=tuple(sim.wind_ne_mps), dynamics=dyn, rangefinder=rf,
        params={"RTL_RETURN_ALT": float(vehicle_params(cfg)["rtl_return_altitude_m"])}))
    inner = MavsdkVehicle(MavsdkVehicle.Config(url=url or "raw://",
                                               connect_timeout_s=connect_timeout_s),
                          clock=clock, mavlink_peer=emu, safety=cfg.safety)
    vehicle = SafeVehicle(inner, cfg.safety, clock=clock)

    def pose_from_telemetry(t_ns: int) -> Any:
        if emu is not None:
            # the cameras see the world from where the vehicle IS: the emulator's truth
            # (extrapolated from its latest step to the exposure time), not the drifting
            # estimate the driver reports
            snap = emu.snapshot()
            dt = (t_ns - clock.now_ns()) * 1e-9
            p, v = snap.true_position_ned_m, snap.velocity_ned_mps
            return ((p[0] + v[0] * dt, p[1] + v[1] * dt, p[2] + v[2] * dt),
                    snap.true_attitude_q)
        st = inner.state_at(t_ns)  # a real PX4 SITL: only its telemetry is known
        return None if st is None else (st.position_ned_m, st.attitude_q)

    rig = make_synthetic_rig(cfg, pose_from_telemetry, clock)
    cams = {CAMERA_WIDE: FaultyCamera(rig.wide, rig.world, clock),
            CAMERA_NARROW: FaultyCamera(rig.narrow, rig.world, clock)}
    models = {c: cam.model for c, cam in cams.items()}
    detectors = {c: build_detector(cfg, params, c) for c in cams}
    coarse = registry.load("estimators", cfg.estimators.coarse.type, cfg.estimators.coarse.params,
                           target=cfg.target)
    fine = registry.load("estimators", cfg.estimators.fine.type, cfg.estimators.fine.params,
                         target=cfg.target)
    recorder = _make_recorder(record_dir, models) if record_dir is not None else None
    truth: list[VehicleState] = []

    def on_telemetry(vs: VehicleState) -> None:
        if truth and vs.timestamp_ns - truth[-1].timestamp_ns < 20_000_000:
            pass
        elif emu is None:
            truth.append(vs)  # a real autopilot: its telemetry is all we have
        else:
            snap = emu.snapshot()
            truth.append(VehicleState(vs.timestamp_ns, snap.true_position_ned_m,
                                      snap.velocity_ned_mps, vs.attitude_q,
                                      in_air=snap.landed_state not in (0, 1), armed=snap.armed))
        if recorder is not None:
            recorder.telemetry(vs)

    if emu is not None:
        emu.start()
    wall0 = time.perf_counter()
    t0_ns = clock.now_ns()
    try:
        await asyncio.wait_for(vehicle.connect(), timeout=connect_timeout_s + 5.0)
        for c in cams.values():
            c.open()
        runner = MissionRunner(cfg, params, vehicle=vehicle, cameras=cams, models=models,
                               detectors=detectors, coarse=coarse, fine=fine, clock=clock,
                               mission_log=mlog, on_telemetry=on_telemetry,
                               on_frame=None if recorder is None else recorder.frame,
                               record_all=recorder is not None)
        if on_state is not None:
            report_state_changes(runner, on_state, clock, t0_ns)
        result = await runner.run()
    finally:
        for c in cams.values():
            c.close()
        await vehicle.close()
        if emu is not None:
            emu.stop()
        if recorder is not None:
            recorder.close()
    wall = time.perf_counter() - wall0
    target = tuple(float(v) for v in rig.world.target_position_ned_m)
    ev = evaluate(result, truth, cfg, target, t0_ns=t0_ns)
    mlog.write("evaluation", **ev.as_dict())
    mlog.close()
    return SimOutcome(result, ev, truth, target, mlog, wall, (clock.now_ns() - t0_ns) * 1e-9,
                      [], rig.world, t0_ns)


def run_emulated(cfg: MissionFile, **kwargs: Any) -> SimOutcome:
    return asyncio.run(fly_emulated(cfg, **kwargs))
