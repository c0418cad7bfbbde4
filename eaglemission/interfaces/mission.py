"""Mission role (entry-point group ``eaglemission.missions``)."""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Mission(Protocol):
    """A mission drives a vehicle from perception. ``run`` returns a result summary.

    Construction: ``cls(config=<cls.Config instance>, mission_config=MissionFile, **context)``.
    """

    async def run(self) -> Any: ...
