"""An ordinary MAVSDK 4.1 client program against the in-process emulator (not a test module).

The client uses MAVSDK's own blocking API the way a user's script does (``Mavsdk``, a
connection, ``first_autopilot``, plugin classes built on the system); the bytes go through
``raw://`` to a :class:`Px4Emulator` in the same process, so the tests need no sockets and no
PX4. Each blocking MAVSDK call is bounded by MAVSDK itself (commands ~2-3 s); every wait here has
a timeout.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from eaglemission.drivers.vehicles.px4 import decode_custom_mode
from eaglemission.lab.vehicles.emulator.emulator import EmulatorConfig, Px4Emulator

from eaglemission.types import FlightMode

PLUGINS = {"action": ("action", "Action"), "offboard": ("offboard", "Offboard"),
           "telemetry": ("telemetry", "Telemetry"), "mission": ("mission", "Mission"),
           "mission_raw": ("mission_raw", "MissionRaw"), "geofence": ("geofence", "Geofence"),
           "param": ("param", "Param"), "manual": ("manual_control", "ManualControl"),
           "direct": ("mavlink_direct", "MavlinkDirect")}


class PlainClient:
    """MAVSDK's plugins on the emulator's system: ``client.action.arm()`` etc."""

    def __init__(self, emu: Px4Emulator, timeout_s: float = 10.0) -> None:
        import importlib

        from mavsdk.component_type import ComponentType
        from mavsdk.mavsdk import Configuration, Mavsdk

        self.emu = emu
        self.sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        self.sdk.add_any_connection_with_handle("raw://")
        self._raw = self.sdk.subscribe_raw_bytes_to_be_sent(emu.feed)
        emu.set_output(self.sdk.pass_received_raw_bytes)
        self.system = self.sdk.first_autopilot(timeout_s)
        if self.system is None:
            raise AssertionError(f"no autopilot within {timeout_s:g} s")
        self._plugins: dict[str, Any] = {}
        for attr, (module, cls) in PLUGINS.items():
            mod = importlib.import_module(f"mavsdk.plugins.{module}")
            self._plugins[attr] = getattr(mod, cls)(self.system)
        self.m = {name: importlib.import_module(f"mavsdk.plugins.{module}")
                  for name, (module, _) in PLUGINS.items()}

    def __getattr__(self, name: str) -> Any:
        plugins = self.__dict__.get("_plugins", {})
        if name in plugins:
            return plugins[name]
        raise AttributeError(name)

    def close(self) -> None:
        self.emu.set_output(None)
        for p in self._plugins.values():
            p.destroy()
        self.sdk.destroy()

    # ------------------------------------------------------------------ what it sees
    def mode(self) -> FlightMode:
        return FlightMode(self.telemetry.flight_mode().name)

    def ned(self) -> tuple[float, float, float]:
        p = self.telemetry.position_velocity_ned().position
        return (p.north_m, p.east_m, p.down_m)

    def yaw_deg(self) -> float:
        return float(self.telemetry.attitude_euler().yaw_deg)

    def armed(self) -> bool:
        return bool(self.telemetry.armed())

    def wait(self, pred: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Wall-time bounded poll (AssertionError naming ``what``)."""
        deadline = time.monotonic() + timeout_s
        while not pred():
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not reached within {timeout_s:g} s (wall); "
                                     f"mode {self.mode().value}, NED {self.ned()}")
            time.sleep(0.02)

    def wait_health(self, timeout_s: float = 10.0) -> None:
        def ok() -> bool:
            h = self.telemetry.health()
            return bool(h.is_global_position_ok and h.is_home_position_ok and h.is_armable)

        self.wait(ok, timeout_s, "health (position, home, armable)")
        # PX4 sends STATUSTEXT only while it hears a GCS heartbeat (as the recorded clients)
        self.wait(self.emu.statustext_link_live, timeout_s, "a GCS heartbeat from MAVSDK")

    def take_off(self, altitude_m: float = 5.0, timeout_s: float = 30.0) -> None:
        """Arm, take off and wait until holding at ``altitude_m``."""
        self.action.set_takeoff_altitude(altitude_m)
        self.action.arm()
        self.action.takeoff()
        self.wait(lambda: -self.ned()[2] > altitude_m - 0.5 and self.mode() == FlightMode.HOLD,
                  timeout_s, f"takeoff to {altitude_m:g} m")

    def heartbeat_modes(self, since_wall_s: float) -> list[tuple[int, int, int]]:
        """(main, sub, base_mode) of the HEARTBEATs the emulator sent since then (record=True)."""
        return [((t.msg.custom_mode >> 16) & 0xFF, (t.msg.custom_mode >> 24) & 0xFF,
                 t.msg.base_mode) for t in self.emu.sent("HEARTBEAT") if t.wall_s >= since_wall_s]


@contextmanager
def plain_client(speedup: float = 4.0, **config: Any) -> Iterator[PlainClient]:
    """An emulator (recording its traffic) with an ordinary MAVSDK client connected."""
    emu = Px4Emulator(EmulatorConfig(speedup=speedup, **config), record=True)
    emu.start()
    client: PlainClient | None = None
    try:
        client = PlainClient(emu)
        client.wait_health()
        yield client
    finally:
        if client is not None:
            client.close()
        emu.stop()


def bearing_deg(centre: tuple[float, float], p: tuple[float, float, float]) -> float:
    return math.degrees(math.atan2(p[1] - centre[1], p[0] - centre[0]))


__all__ = ["PlainClient", "bearing_deg", "decode_custom_mode", "plain_client"]
