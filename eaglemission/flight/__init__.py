"""One flight: the mission file's parts built through the registry (:mod:`.assembly`) and
flown (:mod:`.run`), with Ctrl-C handling (:mod:`.interrupts`), the dry run's checks
(:mod:`.preflight`) and a frozen heap during the flight (:mod:`.heap`)."""

from eaglemission.flight.assembly import Assembly, assemble
from eaglemission.flight.run import (
    EXIT_CONFIG,
    EXIT_CONNECTION,
    EXIT_DONE,
    EXIT_ERROR,
    EXIT_FAILSAFE,
    EXIT_PREFLIGHT,
    EXIT_REPLAY_DIVERGED,
    EXIT_TRUTH_FAILED,
    FlightOptions,
    FlightResult,
    exit_code_for,
    fly,
    fly_sync,
)

__all__ = ["EXIT_CONFIG", "EXIT_CONNECTION", "EXIT_DONE", "EXIT_ERROR", "EXIT_FAILSAFE",
           "EXIT_PREFLIGHT", "EXIT_REPLAY_DIVERGED", "EXIT_TRUTH_FAILED", "Assembly",
           "FlightOptions", "FlightResult", "assemble", "exit_code_for", "fly", "fly_sync"]
