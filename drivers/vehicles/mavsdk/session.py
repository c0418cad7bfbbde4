"""The MAVSDK instance behind the driver: the link, the first autopilot, the plugins, bounded
calls in a private thread pool with MAVSDK's errors mapped to ours, and a teardown that never
destroys MAVSDK while a call is still running (MAVSDK 4.1 would abort the process)."""

from __future__ import annotations

import asyncio
import concurrent.futures
import functools
import json
import logging
from collections.abc import Callable, Sequence
from typing import Any

from eaglemission.drivers.vehicles.events import EVENT_REFUSED
from eaglemission.drivers.vehicles.mavsdk.support import (
    REMEDIES,
    MavlinkPeer,
    MavsdkVehicleConfig,
    import_mavsdk,
    route_mavsdk_logs,
)
from eaglemission.drivers.vehicles.mavsdk.telemetry import EventSink

from eaglemission.errors import TimeoutError_, VehicleError

log = logging.getLogger(__name__)

PLUGINS = ("Telemetry", "Action", "Offboard", "Mission", "Param", "Geofence", "MavlinkDirect",
           "Info")
"""The MAVSDK plugins the driver creates (all at once: plugins only see later messages). Not
MAVSDK's Gripper: against PX4 v1.16, which answers a gripper command IN_PROGRESS and then
ACCEPTED (probed), MAVSDK 4.1's Gripper returns UNKNOWN at the first ack and calls back again
at the second (the asyncio binding then crashed the process, the blocking one hung its next
call); :meth:`MavsdkSession.command_long` sends DO_GRIPPER instead."""
AUTOPILOT_COMPONENT = 1
"""MAV_COMP_ID_AUTOPILOT1: PX4's autopilot component."""
MAV_RESULTS = {0: "ACCEPTED", 1: "BUSY", 2: "COMMAND_DENIED", 3: "UNSUPPORTED", 4: "FAILED",
               5: "IN_PROGRESS", 6: "CANCELLED"}
"""MAV_RESULT of a final COMMAND_ACK as the driver's result names (MAVSDK's where it has one:
TEMPORARILY_REJECTED is MAVSDK's BUSY)."""


class MavsdkSession:
    """One MAVSDK instance and what hangs on it (see the module docstring)."""

    def __init__(self, config: MavsdkVehicleConfig, event: EventSink,
                 peer: MavlinkPeer | None) -> None:
        self.config = config
        self._event = event
        self._peer = peer
        self.mavsdk: dict[str, Any] = {}  # the MAVSDK classes (import_mavsdk)
        self.plugins: dict[str, Any] = {}  # plugin instances by class name
        self._sdk: Any = None
        self._system: Any = None
        self._raw_handle: Any = None
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._leaked: list[Any] = []
        self.system_id = 0
        """The connected autopilot's MAVLink system id (PX4's MAV_SYS_ID: 1 by default, but a
        real aircraft or a second SITL instance may have another)."""

    async def open(self, scheme: str, timeout_s: float) -> bool:
        """Add the connection and wait for the first autopilot (at most ``timeout_s``); create
        the plugins. False when no autopilot was heard."""
        cfg = self.config
        m = self.mavsdk = import_mavsdk()
        route_mavsdk_logs()
        self._executor = concurrent.futures.ThreadPoolExecutor(max_workers=4,
                                                               thread_name_prefix="mavsdk-call")
        ctype = (m["ComponentType"].COMPANION_COMPUTER if cfg.component == "companion_computer"
                 else m["ComponentType"].GROUND_STATION)
        self._sdk = sdk = m["Mavsdk"](m["Configuration"].create_with_component_type(ctype))
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        await self.bounded("connect()", lambda: sdk.add_any_connection_with_handle(cfg.url),
                           timeout_s=timeout_s, params=cfg.url)
        if scheme == "raw":
            assert self._peer is not None
            self._raw_handle = sdk.subscribe_raw_bytes_to_be_sent(self._peer.feed)
            self._peer.set_output(sdk.pass_received_raw_bytes)
        system = await self._first_autopilot(max(0.05, timeout_s - (loop.time() - t0)))
        if system is None:
            return False
        self._system = system
        self.system_id = int(system.get_system_id())
        for name in PLUGINS:
            self.plugins[name] = m[name](system)
        return True

    async def _first_autopilot(self, timeout_s: float) -> Any:
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[Any] = loop.create_future()

        def settle(system: Any) -> None:
            if not fut.done():
                fut.set_result(system)

        def done(system: Any) -> None:  # MAVSDK's thread
            loop.call_soon_threadsafe(settle, system)

        handle = self._sdk.first_autopilot_async(timeout_s, done)
        try:
            async with asyncio.timeout(timeout_s + 1.0):
                return await fut
        except TimeoutError:
            return None
        finally:
            self._sdk.cancel_first_autopilot(handle)

    async def bounded(self, origin: str, fn: Callable[[], Any], *, timeout_s: float | None = None,
                      params: Any = None) -> Any:
        """Run a blocking MAVSDK call in the private pool, bounded; map its errors."""
        if self._executor is None:
            raise VehicleError("NO_SYSTEM", origin, params, REMEDIES["NO_SYSTEM"])
        timeout = self.config.command_timeout_s if timeout_s is None else timeout_s
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(timeout):
                return await loop.run_in_executor(self._executor, fn)
        except TimeoutError:
            self._event(EVENT_REFUSED, f"{origin}: no answer within {timeout:g} s",
                        {"command": origin, "result": "TIMEOUT"})
            raise TimeoutError_(origin, timeout, f"no answer within {timeout:g} s: "
                                + REMEDIES["TIMEOUT"]) from None
        except ConnectionError as exc:  # add_any_connection: bad URL, port in use, no device
            raise VehicleError("CONNECTION_ERROR", origin, params,
                               f"{exc}: check the URL, that the port is free and the device exists") from exc
        except Exception as exc:
            if self.mavsdk and isinstance(exc, self.mavsdk["MavsdkError"]):
                raise self._error(exc, origin, params) from exc
            raise

    async def command_long(self, origin: str, command: int, params: Sequence[float], *,
                           timeout_s: float | None = None) -> int:
        """COMMAND_LONG to the connected autopilot (its own system id, component 1) through
        MAVSDK's MavlinkDirect, which waits for the final COMMAND_ACK (past IN_PROGRESS ones);
        the ack's MAV_RESULT. Bounded like every call (``command_timeout_s``)."""
        values = [float(v) for v in params] + [0.0] * (7 - len(params))
        fields: dict[str, Any] = {"target_system": self.system_id,
                                  "target_component": AUTOPILOT_COMPONENT,
                                  "command": int(command), "confirmation": 0}
        fields.update({f"param{i + 1}": v for i, v in enumerate(values)})
        msg = self.mavsdk["MavlinkMessage"](message_name="COMMAND_LONG", system_id=0,
                                            component_id=0, target_system_id=self.system_id,
                                            target_component_id=AUTOPILOT_COMPONENT,
                                            fields_json=json.dumps(fields))
        md = self.plugins["MavlinkDirect"]
        ack = await self.bounded(origin, lambda: md.send_command(msg), timeout_s=timeout_s,
                                 params=tuple(params))
        return int(json.loads(ack.fields_json).get("result", -1))

    def _error(self, exc: Any, origin: str, params: Any) -> VehicleError:
        result = getattr(exc, "result", None)
        name = getattr(result, "name", str(result))
        self._event(EVENT_REFUSED, f"{origin}: {name}", {"command": origin, "result": name})
        detail = f"MAVSDK {getattr(exc, 'origin', origin)}: {name}"
        if result is None:  # MAVSDK could not even start the call (e.g. open the link)
            detail = (f"MAVSDK {origin}: {exc}" if str(exc) not in ("", "None")
                      else f"MAVSDK could not do {origin}")
            if origin == "connect()":
                detail += (f" with {params}: check the URL, that the port is free and the "
                           "device exists")
        elif name in REMEDIES:
            detail += f" ({REMEDIES[name]})"
        return VehicleError(name, origin, params, detail)

    async def shutdown(self, grace_s: float, busy: Callable[[], bool]) -> None:
        """After everything that calls into MAVSDK was stopped: wait (at most ``grace_s``) for
        the calls in flight, then destroy the plugins and MAVSDK, or leak them when calls are
        still running or ``busy()`` (the watchdog thread did not stop)."""
        loop = asyncio.get_running_loop()
        if self._peer is not None:
            self._peer.set_output(None)  # no more bytes into MAVSDK once it is destroyed
        idle = True
        if self._executor is not None:
            ex, self._executor = self._executor, None
            try:
                async with asyncio.timeout(grace_s):
                    await loop.run_in_executor(None, functools.partial(
                        ex.shutdown, wait=True, cancel_futures=True))
            except TimeoutError:
                idle = False
        if busy():
            idle = False
        if self._sdk is None:
            return
        sdk, self._sdk = self._sdk, None
        plugins = list(self.plugins.values())
        self.plugins.clear()
        self._system = None
        if not idle:
            log.error("mavsdk: calls still running after %.0f s: MAVSDK is not destroyed "
                      "(it would abort the process); it is released at exit", grace_s)
            self._leaked.append(sdk)
            return

        def destroy() -> None:
            for plugin in plugins:  # plugins first: each holds the System
                plugin.destroy()
            sdk.destroy()

        await loop.run_in_executor(None, destroy)
