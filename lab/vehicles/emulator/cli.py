"""``eaglemission sitl-vehicle``: run the PX4-like MAVLink emulator on its own.

QGroundControl (listens on UDP 14550), MAVSDK (``udpin://0.0.0.0:14540``) or any MAVLink tool
can connect to it::

    eaglemission sitl-vehicle --mavlink udpout://127.0.0.1:14540      # for MAVSDK / the mission
    eaglemission sitl-vehicle --mavlink udpout://127.0.0.1:14550      # for QGroundControl

It runs until SIGTERM or SIGINT (a process started in the background from a non-interactive
shell ignores SIGINT, so SIGTERM is handled too), ``--duration-s``, or the end of the process
given by ``--exit-with-pid`` (a campaign's worker that starts one per run and may be killed).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING

from eaglemission.lab.world.synthetic import world_config

from eaglemission.commands import Command
from eaglemission.errors import ConfigError

if TYPE_CHECKING:  # the emulator (pymavlink) is imported when the command runs
    from eaglemission.lab.vehicles.emulator.config import EmulatorSnapshot


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mavlink", default="udpout://127.0.0.1:14540",
                   help="udpout://HOST:PORT (send first) or udpin://HOST:PORT (listen); "
                        "default %(default)s (where MAVSDK listens for PX4 SITL)")
    p.add_argument("--speedup", type=float, default=1.0,
                   help="emulator time / wall time (dynamics and failsafe timers); keep <= 10 "
                        "with offboard (MAVSDK streams setpoints every 50 ms wall)")
    p.add_argument("--home", type=float, nargs=3, metavar=("LAT_DEG", "LON_DEG", "AMSL_M"),
                   help="home position (default PX4 SITL's 47.397742 8.545594 489.4)")
    p.add_argument("--seed", type=int, default=0, help="estimate drift / gust seed")
    p.add_argument("--wind", type=float, nargs=2, default=(0.0, 0.0), metavar=("N_MPS", "E_MPS"),
                   help="mean wind")
    p.add_argument("--duration-s", type=float, default=None, help="stop after this long")
    p.add_argument("--exit-with-pid", type=int, metavar="PID",
                   help="stop when process PID is gone (checked every 0.2 s)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="PX4 parameter override, e.g. COM_OBL_RC_ACT=5 (repeatable)")
    p.add_argument("--mission", metavar="YAML",
                   help="take the world's wind and seed (`simulation`) and, when its vehicle "
                        "is `simulated`, its dynamics and rangefinder from this mission file "
                        "(what `run --vehicle emulator` does); `-` reads it from standard input")
    p.add_argument("--rangefinder", action="store_true",
                   help="stream a downward DISTANCE_SENSOR (as PX4 SIH)")
    p.add_argument("--status-json", metavar="PATH",
                   help="write the emulator's own state (mode, armed, landed, true position) "
                        "to this file every 0.2 s")


def _params(items: list[str]) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            sep = ""
        if not sep:
            raise ConfigError(f"--param {item!r}: use NAME=VALUE, e.g. COM_OBL_RC_ACT=5")
    return out


def _run(args: argparse.Namespace) -> int:
    from eaglemission import extras

    extras.require("mavsdk", "sitl-vehicle")  # pymavlink: one line and exit 2 without it
    from eaglemission.lab.vehicles.emulator.emulator import EmulatorConfig, Px4Emulator

    from eaglemission.commands import console as make_console

    console = make_console()
    kw: dict[str, object] = {"speedup": args.speedup, "seed": args.seed,
                             "wind_ne_mps": tuple(args.wind), "params": _params(args.param)}
    if args.home:
        kw.update(home_latitude_deg=args.home[0], home_longitude_deg=args.home[1],
                  home_altitude_amsl_m=args.home[2])
    if args.mission:
        kw.update(emulator_settings_from_mission(args.mission))
    if args.rangefinder:
        rf = kw.get("rangefinder")
        kw["rangefinder"] = ({**rf, "enabled": True} if isinstance(rf, dict)
                             else {"enabled": True})
    try:
        cfg = EmulatorConfig.model_validate(kw)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    emu = Px4Emulator(cfg, link=args.mavlink)
    try:
        emu.start()
        console.print(f"PX4-like emulator on [bold]{args.mavlink}[/bold] "
                      f"(speed-up {cfg.speedup:g}); SIGTERM or Ctrl-C to stop")
        deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
        last_mode = None
        while not stop.wait(0.2):
            snap = emu.snapshot()
            if args.status_json:
                write_status(args.status_json, snap)
            if (snap.mode, snap.armed) != last_mode:
                last_mode = (snap.mode, snap.armed)
                console.print(f"t={snap.sim_time_s:7.1f} s  mode {snap.mode.value}"
                              f"{'  ARMED' if snap.armed else ''}")
            if deadline is not None and time.monotonic() >= deadline:
                break
            if args.exit_with_pid is not None and not _alive(args.exit_with_pid):
                console.print(f"process {args.exit_with_pid} is gone")
                break
    finally:
        emu.stop()
        for s, h in old.items():
            signal.signal(s, h)
    console.print("emulator stopped")
    return 0


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, owned by another user
        return True
    return True


def emulator_settings_from_mission(path: str) -> dict[str, object]:
    """EmulatorConfig fields from a mission file: the world's seed and wind; the simulated
    vehicle's dynamics (speeds inside the envelope) and rangefinder when its vehicle is
    ``simulated``."""
    from eaglemission.lab.vehicles.multicopter.dynamics import speeds_within_envelope
    from eaglemission.lab.vehicles.simulated.vehicle import SimulatedVehicleConfig

    from eaglemission.config import load_config

    if path == "-":  # the mission's YAML on stdin (the campaign's emulator runs)
        from eaglemission.config import parse_yaml, validate_mapping

        cfg = validate_mapping(parse_yaml(sys.stdin.read(), source="<stdin>"), source="<stdin>",
                               check_plugins=False)
    else:
        cfg = load_config(path, check_plugins=False)
    out: dict[str, object] = {}
    world = world_config(cfg)
    if world is not None:
        out.update(seed=world.seed, wind_ne_mps=tuple(world.wind_ne_mps))
    vp = (SimulatedVehicleConfig.model_validate(dict(cfg.vehicle.params))
          if cfg.vehicle.type == "simulated" else SimulatedVehicleConfig())
    out["dynamics"] = speeds_within_envelope(vp.dynamics, cfg.safety).model_dump()
    out["rangefinder"] = vp.rangefinder.model_dump()
    return out


def write_status(path: str, snap: EmulatorSnapshot) -> None:
    """The emulator's snapshot as JSON, replaced atomically."""
    import dataclasses
    import json
    import os

    d = dataclasses.asdict(snap)
    d["mode"] = getattr(d["mode"], "value", str(d["mode"]))
    d["wall_time_s"] = time.time()
    tmp = f"{path}.tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(d, f, default=str)
    os.replace(tmp, path)


SITL_VEHICLE_COMMAND = Command(
    "run the PX4-like MAVLink emulator (for MAVSDK, QGroundControl, the mission)", _add, _run)
