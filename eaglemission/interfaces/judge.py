"""Judge role (entry-point group ``eaglemission.judges``, named after the mission type it
judges): how a flown mission is judged after the flight, against ground truth where a
simulator has it.

The mission never sees ground truth. The assembly builds the judge of the mission's type, when
one is installed, as ``cls(config=<Config instance>, mission_file=..., world=<World | None>,
truth=<GroundTruth | None>)`` and hands it to the mission in
:class:`~eaglemission.interfaces.mission.FlightParts`; the mission calls :meth:`Judge.judge`
with what it reported once it has ended, and logs and prints the :class:`Verdict`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

from eaglemission.types import VehicleState


@runtime_checkable
class Verdict(Protocol):
    success: bool
    judged_on: str
    """``"truth"`` (a simulator's ground truth) or ``"estimate"`` (the autopilot's own)."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields (the mission log's ``evaluation`` record)."""
        ...

    def report_lines(self) -> list[str]:
        """What ``eaglemission run`` prints about it."""
        ...


@runtime_checkable
class Judge(Protocol):
    def judge(self, result: Any, reported: Sequence[VehicleState], *, t0_ns: int,
              expected_action: str | None = None) -> Verdict:
        """Judge a mission's ``result`` (its own report) flown from ``t0_ns``; ``reported``: the
        states the autopilot reported (used when no truth is known); ``expected_action``: the
        safe action this flight should have ended with (fault campaigns), None: any."""
        ...
