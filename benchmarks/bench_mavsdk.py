"""MAVSDK driver against the PX4-like emulator: command round trips, telemetry rates, watchdog.

    python benchmarks/bench_mavsdk.py                 # raw:// and loopback UDP
    python benchmarks/bench_mavsdk.py --links raw --n 50

Prints, per link: the median / 90th percentile of a bounded command round trip through the
driver (``set_param`` = PARAM_SET -> PARAM_VALUE, and arm/disarm = COMMAND_LONG ->
COMMAND_ACK + the HEARTBEAT confirming it), the rates at which position and attitude samples
reach the driver's history (requested: 50 Hz; the requirement is >= 50 Hz), and how long after
the last fresh setpoint the offboard watchdog has the emulator in HOLD with the event loop
*blocked* (``time.sleep`` in the loop; configured timeout 0.5 s). Wall-clock figures on a shared
machine: compare them within one run, not across machines.
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import statistics
import time

from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle
from eaglemission.lab.vehicles.emulator.emulator import EmulatorConfig, Px4Emulator

from eaglemission.types import FlightMode, Setpoint


def _free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))]


async def _wait(pred, timeout_s: float) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not reached")
        await asyncio.sleep(0.005)


async def bench(link: str, n: int) -> dict[str, float]:
    cfg = EmulatorConfig(speedup=4.0)
    if link == "raw":
        emu = Px4Emulator(cfg)
        vehicle = MavsdkVehicle(MavsdkVehicle.Config(url="raw://", watchdog_timeout_s=0.5),
                                mavlink_peer=emu)
    else:
        port = _free_port()
        emu = Px4Emulator(cfg, link=f"udpout://127.0.0.1:{port}")
        vehicle = MavsdkVehicle(MavsdkVehicle.Config(url=f"udpin://127.0.0.1:{port}",
                                                     watchdog_timeout_s=0.5))
    emu.start()
    out: dict[str, float] = {}
    try:
        t0 = time.monotonic()
        await vehicle.connect()
        out["connect_s"] = time.monotonic() - t0
        rt = []
        for _ in range(n):
            t = time.perf_counter()
            await vehicle.set_param("MPC_XY_CRUISE", 5.0)
            rt.append((time.perf_counter() - t) * 1e3)
        out["param_ms_median"], out["param_ms_p90"] = statistics.median(rt), _pct(rt, 0.9)
        rt = []
        for _ in range(max(3, n // 5)):
            t = time.perf_counter()
            await vehicle.arm()
            await vehicle.disarm()
            rt.append((time.perf_counter() - t) * 1e3 / 2)
        out["arm_ms_median"], out["arm_ms_p90"] = statistics.median(rt), _pct(rt, 0.9)
        # telemetry rates into the history
        await asyncio.sleep(2.0)
        hist = vehicle._history  # noqa: SLF001 - the bench reads the driver's internals
        out["history_hz"] = len(hist) / hist.span_ns * 1e9
        c = vehicle._c  # noqa: SLF001
        n_pos = n_att = 0
        last_pos, last_att = c.local_t_ns, c.attitude_t_ns
        t_end = time.monotonic() + 2.0
        while time.monotonic() < t_end:
            await asyncio.sleep(0.001)
            if c.local_t_ns != last_pos:
                n_pos, last_pos = n_pos + 1, c.local_t_ns
            if c.attitude_t_ns != last_att:
                n_att, last_att = n_att + 1, c.attitude_t_ns
        out["local_position_hz"], out["attitude_hz"] = n_pos / 2.0, n_att / 2.0
        # watchdog with a blocked loop
        await vehicle.arm()
        await vehicle.takeoff(3.0)
        await _wait(lambda: vehicle.state().in_air and vehicle.state().flight_mode == FlightMode.HOLD, 30)
        here = vehicle.state()
        sp = Setpoint(*here.position_ned_m, here.yaw_deg)
        await vehicle.start_offboard(sp)
        for _ in range(10):
            await asyncio.sleep(0.05)
            await vehicle.set_setpoint(sp)
        t_last = time.monotonic()
        t_hold = None
        while time.monotonic() - t_last < 2.0:  # the loop is blocked: only polling the emulator
            if emu.snapshot().mode == FlightMode.HOLD:
                t_hold = time.monotonic()
                break
            time.sleep(0.005)
        out["watchdog_hold_after_s"] = float("nan") if t_hold is None else t_hold - t_last
    finally:
        await vehicle.close()
        emu.stop()
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--links", default="raw,udp", help="comma-separated: raw, udp")
    p.add_argument("--n", type=int, default=40, help="round trips per command")
    args = p.parse_args()
    print("link  connect_s  set_param_ms(med/p90)  arm_ms(med/p90)  history_hz  local_pos_hz  "
          "attitude_hz  watchdog_hold_after_s (timeout 0.5)")
    for link in args.links.split(","):
        r = asyncio.run(bench(link.strip(), args.n))
        print(f"{link:5s} {r['connect_s']:9.2f}  {r['param_ms_median']:7.2f}/{r['param_ms_p90']:<7.2f}"
              f"    {r['arm_ms_median']:6.2f}/{r['arm_ms_p90']:<7.2f}  {r['history_hz']:10.1f}"
              f"  {r['local_position_hz']:12.1f}  {r['attitude_hz']:11.1f}  "
              f"{r['watchdog_hold_after_s']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
