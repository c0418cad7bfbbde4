"""The autopilot's outputs for the MAVSDK vehicle: SERVO_OUTPUT_RAW as it reports them (PX4
sends it at 10 Hz on the offboard link), each message kept with the host time it arrived;
MAV_CMD_DO_SET_ACTUATOR; the gripper (MAV_CMD_DO_GRIPPER)."""

from __future__ import annotations

import collections
import json
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from eaglemission.drivers.vehicles.events import EVENT_GRIPPER, EVENT_REFUSED
from eaglemission.drivers.vehicles.mavsdk.session import MAV_RESULTS
from eaglemission.drivers.vehicles.mavsdk.support import REMEDIES

from eaglemission.errors import VehicleError

if TYPE_CHECKING:  # the vehicle calls these with itself; imported for the annotations only
    from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle

SERVO_CHANNELS = 16


@dataclass(frozen=True, slots=True)
class ServoOutputs:
    """One SERVO_OUTPUT_RAW: the pulse widths (us) of outputs 1-16 of one port."""

    received_ns: int
    """Host time the message arrived."""
    port: int
    pwm_us: tuple[int, ...]
    """Output 1 first; 0 where the autopilot does not send the channel."""


def parse_servo_output_raw(received_ns: int, fields: dict[str, Any]) -> ServoOutputs:
    """A SERVO_OUTPUT_RAW's fields (MAVSDK MavlinkDirect's JSON) as :class:`ServoOutputs`."""
    return ServoOutputs(int(received_ns), int(fields.get("port", 0)),
                        tuple(int(fields.get(f"servo{i}_raw", 0) or 0)
                              for i in range(1, SERVO_CHANNELS + 1)))


class ServoOutputLog:
    """The latest SERVO_OUTPUT_RAW messages (thread-safe: MAVSDK's thread adds)."""

    def __init__(self, keep: int = 256) -> None:
        self._lock = threading.Lock()
        self._items: collections.deque[ServoOutputs] = collections.deque(maxlen=keep)

    def on_message(self, received_ns: int, fields_json: str) -> None:
        try:
            out = parse_servo_output_raw(received_ns, json.loads(fields_json))
        except (ValueError, TypeError):
            return  # a malformed message is dropped; the next one comes in 0.1 s
        with self._lock:
            self._items.append(out)

    def subscribe(self, mavlink_direct: Any) -> Any:
        """Keep every SERVO_OUTPUT_RAW that MAVSDK's MavlinkDirect plugin receives (with the
        host time it arrived); MAVSDK's handle (the plugin is destroyed with the session)."""
        return mavlink_direct.subscribe_message(
            "SERVO_OUTPUT_RAW", lambda msg, _ud=None: self.on_message(time.monotonic_ns(),
                                                                      msg.fields_json))

    def latest(self, port: int = 0) -> ServoOutputs | None:
        with self._lock:
            for item in reversed(self._items):
                if item.port == port:
                    return item
        return None

    def since(self, received_ns: int) -> list[ServoOutputs]:
        with self._lock:
            return [o for o in self._items if o.received_ns >= received_ns]


async def set_actuator(v: MavsdkVehicle, index: int, value: float) -> None:
    """MAV_CMD_DO_SET_ACTUATOR through MAVSDK's ``Action.set_actuator``: PX4 drives the outputs
    whose function is "Peripheral via Actuator Set ``index``" (301-306) to ``value`` (-1..1);
    acknowledged, bounded by the vehicle's ``command_timeout_s``."""
    v._require("set_actuator()")
    if not 1 <= int(index) <= 6 or not -1.0 <= float(value) <= 1.0:
        raise VehicleError("INVALID_ARGUMENT", "set_actuator()", (index, value),
                           f"set_actuator({index}, {value}): index must be 1-6 and value -1..1")
    action = v.plugins["Action"]
    await v.bounded("set_actuator()", lambda: action.set_actuator(int(index), float(value)),
                    params=(int(index), float(value)))


MAV_CMD_DO_GRIPPER = 211
GRIPPER_ACTION_RELEASE, GRIPPER_ACTION_GRAB = 0, 1


async def gripper(v: MavsdkVehicle, origin: str, action: str, code: int) -> None:
    """DO_GRIPPER, returning once the gripper is done: PX4 v1.16 answers IN_PROGRESS, then
    ACCEPTED PD_GRIPPER_TO (1 s) later (probed; already in that state: ACCEPTED at once)."""
    v._require(origin)
    instance = v.config.gripper_instance
    result = await v.session.command_long(origin, MAV_CMD_DO_GRIPPER,
                                          [float(instance), float(code)])
    if result != 0:
        name = MAV_RESULTS.get(result, f"MAV_RESULT_{result}")
        v.event(EVENT_REFUSED, f"{origin}: {name}", {"command": origin, "result": name})
        raise VehicleError(name, origin, (instance,), f"the autopilot answered DO_GRIPPER {name}"
                           + (f" ({REMEDIES[name]})" if name in REMEDIES else ""))
    v.event(EVENT_GRIPPER, f"Gripper {action}", {"action": action})
