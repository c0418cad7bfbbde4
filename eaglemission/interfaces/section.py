"""Section role (entry-point group ``eaglemission.sections``): a mission-file section that a
package adds, named after the section (the lab's ``faults``).

The core validates the section with the plugin's ``Config`` and otherwise never reads it. The
assembly builds the plugin as ``cls(config=<Config instance>)`` before anything else, and calls
it at four points of a flight: ``prepare`` before the vehicle is built (it may return the
mission file changed, e.g. a vehicle URL behind a relay it started), ``attach`` once every part
is built (it may wrap parts), ``mission_hooks`` before the mission starts, and ``close`` after
the flight, whatever happened.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from eaglemission.config import MissionFile
    from eaglemission.interfaces.mission import MissionHooks


@runtime_checkable
class Section(Protocol):
    def prepare(self, config: MissionFile) -> MissionFile:
        """The mission file to fly (``config`` itself when nothing changes)."""
        ...

    def attach(self, assembly: Any) -> None:
        """Called with the built :class:`~eaglemission.flight.assembly.Assembly`."""
        ...

    def mission_hooks(self, hooks: MissionHooks) -> MissionHooks:
        """The hooks the mission gets (``hooks`` itself when nothing is added)."""
        ...

    def close(self) -> None:
        """Release what ``prepare`` started (idempotent)."""
        ...
