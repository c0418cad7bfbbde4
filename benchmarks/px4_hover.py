"""Hover precision on ground truth at grasp height, against a real PX4 SITL (SIH or jMAVSim).

    EAGLEMISSION_PX4_URL=udpin://0.0.0.0:14540 python benchmarks/px4_hover.py \
        --config configs/px4_sitl.yaml --height-m 0.675 --hold-s 30       # SIH
    ... --config configs/px4_jmavsim.yaml                                # jMAVSim

The vehicle's params (the ground truth's altitude convention among them) come from the mission
file's ``vehicle`` section (a ``mavsdk`` vehicle); the URL from ``--url``, else
``EAGLEMISSION_PX4_URL``, else the file. One flight: take off, offboard to ``--height-m`` above
the ground, then up to two holds of ``--hold-s`` each at the same point:

* ``estimate``: the setpoint's altitude is the EKF's (relative to home), as a NED setpoint
  stream does;
* ``rangefinder``: the setpoint's altitude is corrected every cycle by the downward range
  (``altitude + (range x cos tilt - height)``, low-passed), as the mission's plane filter does
  with ``plane.drift_mps`` sized for PX4's EKF (reports/px4_sitl.md). Left out when no
  downward range arrived during the first hold (jMAVSim has no rangefinder).

Judged on HIL_STATE_QUATERNION (simulator truth; height = truth altitude above the take-off
point): horizontal wander about its own mean (RMS, max) and height error (mean, RMS, min), the
time in ground contact, and PX4's own tracking (estimate - setpoint, horizontal RMS). Every
setpoint goes through the safety envelope. Start a fresh PX4 for each run
(``python -m eaglemission.lab.px4 start``).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import statistics
import sys

from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle

from eaglemission.config import GeofenceConfig, SafetyConfig, load_config
from eaglemission.geometry import down_axis_cos_tilt
from eaglemission.names import ENV_PX4_URL
from eaglemission.safety.envelope import SafeVehicle
from eaglemission.types import FlightMode, Setpoint

SETPOINT_PERIOD_S = 0.05


async def _hold(safe: SafeVehicle, inner: MavsdkVehicle, mode: str, north_m: float,
                east_m: float, yaw_deg: float, height_m: float, hold_s: float,
                settle_s: float) -> dict[str, float]:
    truth = inner.ground_truth()
    assert truth is not None
    loop = asyncio.get_running_loop()
    t_end = loop.time() + settle_s + hold_s
    t_judge = loop.time() + settle_s
    correction_m = 0.0
    horiz: list[tuple[float, float]] = []
    heights: list[float] = []
    tracking: list[float] = []  # PX4's own: estimate - setpoint, horizontal
    range_samples = 0
    while loop.time() < t_end:
        s = safe.state()
        if s.flight_mode != FlightMode.OFFBOARD:
            raise RuntimeError(f"{mode}: left OFFBOARD ({s.flight_mode.value})")
        down = -height_m
        range_samples += s.distance_to_ground_m is not None
        if mode == "rangefinder" and s.distance_to_ground_m is not None:
            agl = s.distance_to_ground_m * down_axis_cos_tilt(s.attitude_q)
            measured = agl + s.position_ned_m[2]  # height above ground - altitude estimate
            correction_m += 0.2 * (measured - correction_m)  # ~0.25 s low-pass at 20 Hz
            down = -height_m + correction_m
        await safe.set_setpoint(Setpoint(north_m, east_m, down, yaw_deg))
        if loop.time() >= t_judge:
            pose = truth.pose_at(inner.clock.now_ns())
            if pose is not None:
                (n, e, d), _q = pose
                horiz.append((n, e))
                heights.append(-d)
                tracking.append(math.hypot(s.position_ned_m[0] - north_m,
                                           s.position_ned_m[1] - east_m))
        await asyncio.sleep(SETPOINT_PERIOD_S)
    if len(heights) < 10:
        raise RuntimeError(f"{mode}: no ground truth (HIL_STATE_QUATERNION) during the hold")
    mn = statistics.fmean(p[0] for p in horiz)
    me = statistics.fmean(p[1] for p in horiz)
    r = [math.hypot(n - mn, e - me) for n, e in horiz]
    err = [h - height_m for h in heights]
    return {"horizontal_rms_m": math.sqrt(statistics.fmean(x * x for x in r)),
            "horizontal_max_m": max(r),
            "estimate_tracking_rms_m": math.sqrt(statistics.fmean(x * x for x in tracking)),
            "height_error_mean_m": statistics.fmean(err),
            "height_error_rms_m": math.sqrt(statistics.fmean(x * x for x in err)),
            "height_min_m": min(heights),
            "ground_contact_s": sum(1 for h in heights if h < 0.05) * SETPOINT_PERIOD_S,
            "samples": float(len(heights)), "range_samples": float(range_samples)}


def vehicle_config(args: argparse.Namespace) -> MavsdkVehicle.Config:
    """The mission file's mavsdk vehicle params, the URL from the flag or the environment."""
    section = load_config(args.config).vehicle
    if section.type != "mavsdk":
        raise SystemExit(f"{args.config}: vehicle.type is {section.type!r}, not mavsdk")
    url = args.url or os.environ.get(ENV_PX4_URL) or section.params.get("url")
    params = {**section.params, "connect_timeout_s": 30.0}
    if url:
        params["url"] = url
    return MavsdkVehicle.Config(**params)


async def main(args: argparse.Namespace) -> int:
    inner = MavsdkVehicle(vehicle_config(args))
    safety = SafetyConfig(geofence=GeofenceConfig(radius_m=30.0), min_altitude_m=0.0,
                          max_altitude_m=10.0, max_horizontal_speed_mps=2.0,
                          max_vertical_speed_mps=1.0)
    safe = SafeVehicle(inner, safety)
    await safe.connect()
    results: dict[str, dict[str, float]] = {}
    version = await inner.autopilot_version()
    try:
        await safe.arm()
        await safe.takeoff(3.0)
        for _ in range(400):
            if safe.state().flight_mode == FlightMode.HOLD and -safe.state().position_ned_m[2] > 2.5:
                break
            await asyncio.sleep(0.1)
        s = safe.state()
        n0, e0, yaw = s.position_ned_m[0], s.position_ned_m[1], s.yaw_deg
        await safe.start_offboard(Setpoint(*s.position_ned_m, yaw))
        for mode in ("estimate", "rangefinder"):
            if mode == "rangefinder" and not results["estimate"]["range_samples"]:
                break  # no downward range arrived: the second hold would repeat the first
            results[mode] = await _hold(safe, inner, mode, n0, e0, yaw, args.height_m,
                                        args.hold_s, args.settle_s)
    finally:
        try:
            await safe.land()
            await inner.wait_landed_and_disarmed(land_timeout_s=90.0)
        finally:
            await safe.close()
    truth = inner.ground_truth()
    print(f"PX4 {version['flight_sw_version']} {version['flight_sw_version_type']} "
          f"(git {version['flight_sw_git_hash']}), {args.config}, truth altitude "
          f"{inner.config.ground_truth_altitude}, horizontal {inner.config.ground_truth_horizontal}"
          + (f"; TRUTH PROBLEM: {truth.problem}" if truth is not None and truth.problem else ""))
    print(f"PX4 hover at {args.height_m:g} m above the ground, {args.hold_s:g} s per mode "
          "(truth: HIL_STATE_QUATERNION)")
    if "rangefinder" not in results:
        print("rangefinder: no DISTANCE_SENSOR reading during the first hold, not held")
    keys = list(next(iter(results.values())))
    print(f"{'mode':<12}" + "".join(f"{k:>25}" for k in keys))
    for mode, r in results.items():
        print(f"{mode:<12}" + "".join(f"{r[k]:>25.3f}" for k in keys))
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/px4_sitl.yaml",
                    help="mission file whose mavsdk vehicle params are used (default %(default)s)")
    ap.add_argument("--url", default=None,
                    help=f"MAVSDK URL (default: {ENV_PX4_URL}, else the config's)")
    ap.add_argument("--height-m", type=float, default=0.675,
                    help="hover height above the ground (the default config's grasp pose)")
    ap.add_argument("--hold-s", type=float, default=30.0)
    ap.add_argument("--settle-s", type=float, default=8.0)
    sys.exit(asyncio.run(main(ap.parse_args())))
