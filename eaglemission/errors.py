"""One exception hierarchy for the whole framework.

Messages say what went wrong and how to fix it ("problem: remedy"). Estimation failures are
*values* (:class:`eaglemission.types.EstimationFailed`), not exceptions.
"""

from __future__ import annotations

from typing import Any


class EagleMissionError(Exception):
    """Base of every error raised on purpose by eaglemission."""


class ConfigError(EagleMissionError):
    """A configuration is invalid. ``problems`` holds one path-qualified line per problem."""

    def __init__(self, problems: list[str] | str, *, source: str | None = None) -> None:
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        self.source = source
        head = f"{source}: " if source else ""
        if len(self.problems) == 1:
            msg = head + self.problems[0]
        else:
            msg = head + f"{len(self.problems)} problems:\n" + "\n".join(
                f"  - {p}" for p in self.problems
            )
        super().__init__(msg)


class PluginError(EagleMissionError):
    """A plugin cannot be found, imported, or does not conform to its role's interface."""


class DriverError(EagleMissionError):
    """A driver call failed. Shaped like MAVSDK's per-plugin errors: result, origin, params."""

    def __init__(self, result: str, origin: str, params: Any = None, detail: str = "") -> None:
        self.result = result
        self.origin = origin
        self.params = params
        self.detail = detail
        text = f"{origin} failed: {result}"
        if params not in (None, (), {}):
            text += f" (args: {params!r})"
        if detail:
            text += f": {detail}"
        super().__init__(text)


class TimeoutError_(DriverError):
    """A bounded wait ran out (named with a trailing underscore to keep the builtin visible)."""

    def __init__(self, origin: str, timeout_s: float, detail: str = "") -> None:
        self.timeout_s = timeout_s
        super().__init__("TIMEOUT", origin, None, detail or f"no answer within {timeout_s:g} s")


# -- cameras -------------------------------------------------------------------------------------
class CameraError(DriverError):
    """A camera failed."""


class GrabTimeout(CameraError):
    """No frame arrived within ``timeout_s``."""

    def __init__(self, camera_id: str, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        super().__init__("TIMEOUT", f"camera {camera_id!r}.grab()", None,
                         f"no frame within {timeout_s:g} s")


class CameraLost(CameraError):
    """The device disappeared or stopped answering."""


class EndOfStream(CameraError):
    """A replay has no more frames. Not a fault: the stream is over."""

    def __init__(self, camera_id: str, frames_served: int) -> None:
        self.frames_served = frames_served
        super().__init__("END_OF_STREAM", f"camera {camera_id!r}.grab()", None,
                         f"all {frames_served} frames served")


class FrameError(CameraError):
    """A frame is corrupted, of the wrong size or of the wrong format."""


# -- vehicles ------------------------------------------------------------------------------------
class VehicleError(DriverError):
    """A vehicle command was refused or failed."""


class SafetyViolation(VehicleError):
    """A command was refused by the safety envelope."""


class ModeChangedExternally(VehicleError):
    """Someone else (pilot, ground station, autopilot failsafe) took control."""


# -- perception ----------------------------------------------------------------------------------
class InputError(EagleMissionError, ValueError):
    """An array given to a detector or estimator has the wrong shape, dtype or content."""
