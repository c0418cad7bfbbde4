"""Bounded waits on vehicle conditions (every wait has a timeout)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TypeVar

from eaglemission.clock import Clock
from eaglemission.errors import TimeoutError_

T = TypeVar("T")


async def wait_until(
    predicate: Callable[[], T],
    timeout_s: float,
    *,
    clock: Clock | None = None,
    poll_s: float = 0.05,
    what: str = "condition",
) -> T:
    """Poll ``predicate()`` every ``poll_s`` until it returns something truthy; return that.

    Time is read from ``clock`` (any eaglemission Clock, so a :class:`ManualClock` or virtual
    loop makes the wait instant in wall time); without a clock the running loop's time is used.
    Raises :class:`~eaglemission.errors.TimeoutError_` naming ``what`` after ``timeout_s``.

    Commands that take time (takeoff, goto, land) return when accepted, like MAVSDK; waiting
    for their effect is the caller's job::

        await vehicle.takeoff(5.0)
        await wait_until(lambda: vehicle.state().relative_altitude_m > 4.5, 30.0,
                         clock=clock, what="altitude 4.5 m")
    """
    if not timeout_s > 0:
        raise ValueError(f"timeout_s: must be > 0, got {timeout_s}")
    if not poll_s > 0:
        raise ValueError(f"poll_s: must be > 0, got {poll_s}")

    def now_s() -> float:
        if clock is not None:
            return clock.now_ns() * 1e-9
        return asyncio.get_running_loop().time()

    deadline = now_s() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        remaining = deadline - now_s()
        if remaining <= 0:
            raise TimeoutError_(f"wait_until({what})", timeout_s)
        step = min(poll_s, remaining)
        if clock is not None:
            await clock.sleep(step)
        else:
            await asyncio.sleep(step)
