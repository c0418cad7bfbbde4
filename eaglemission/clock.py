"""Clocks. Every timestamp in eaglemission is host ``CLOCK_MONOTONIC`` nanoseconds.

``MonotonicClock`` is the wall clock of real flights. ``VirtualTimeLoop`` is an asyncio event
loop whose time jumps forward whenever nothing is ready and no worker thread is busy, so that a
simulation with ``asyncio.sleep``/``asyncio.timeout`` everywhere runs faster than real time and
deterministically. ``LoopClock`` reads the running loop's time, which is real or virtual.
"""

from __future__ import annotations

import asyncio
import selectors
import threading
import time
from collections.abc import Callable, Coroutine
from typing import Any, Protocol, TypeVar, runtime_checkable

T = TypeVar("T")


@runtime_checkable
class Clock(Protocol):
    """Time source: ``now_ns`` and an awaitable ``sleep``."""

    def now_ns(self) -> int: ...

    async def sleep(self, duration_s: float) -> None: ...


class MonotonicClock:
    """Host ``CLOCK_MONOTONIC``."""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    async def sleep(self, duration_s: float) -> None:
        await asyncio.sleep(duration_s)


class ManualClock:
    """A clock advanced by hand (unit tests, offline stepping)."""

    def __init__(self, start_ns: int = 1_000_000_000) -> None:
        self._t_ns = int(start_ns)
        self._lock = threading.Lock()

    def now_ns(self) -> int:
        with self._lock:
            return self._t_ns

    def advance(self, duration_s: float) -> None:
        if duration_s < 0:
            raise ValueError(f"duration_s: must be >= 0, got {duration_s}")
        with self._lock:
            self._t_ns += int(round(duration_s * 1e9))

    async def sleep(self, duration_s: float) -> None:
        self.advance(max(0.0, duration_s))
        await asyncio.sleep(0)


class LoopClock:
    """The running event loop's clock (virtual under :class:`VirtualTimeLoop`)."""

    def now_ns(self) -> int:
        return int(round(asyncio.get_running_loop().time() * 1e9))

    async def sleep(self, duration_s: float) -> None:
        await asyncio.sleep(duration_s)


class _VirtualSelector:
    """Wraps the loop's selector: a timed wait becomes a jump of virtual time when idle."""

    def __init__(self, inner: selectors.BaseSelector, loop: VirtualTimeLoop) -> None:
        self._inner = inner
        self._loop = loop

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        events = self._inner.select(0)
        if events or timeout == 0:
            return events
        if self._loop.busy_workers > 0:
            # A worker thread will wake us through the self-pipe; wait in real time, frozen
            # virtual time (so a slow computation never looks like a timeout).
            return self._inner.select(0.05 if timeout is None else min(timeout, 0.05))
        if timeout is None:
            return self._inner.select(0.01)  # nothing scheduled: let real I/O arrive
        self._loop._virtual_s += timeout
        return []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """Event loop with virtual time starting at ``start_s``.

    Use :meth:`run_in_worker` (not ``asyncio.to_thread``) for blocking work so the loop knows
    to wait for it instead of jumping time.
    """

    def __init__(self, start_s: float = 1.0) -> None:
        super().__init__()
        self._virtual_s = float(start_s)
        self.busy_workers = 0
        self._selector = _VirtualSelector(self._selector, self)  # type: ignore[has-type,arg-type]
        self._clock_resolution = 1e-9

    def time(self) -> float:
        return self._virtual_s

    async def run_in_worker(self, fn: Callable[..., T], *args: Any) -> T:
        self.busy_workers += 1
        try:
            return await asyncio.to_thread(fn, *args)
        finally:
            self.busy_workers -= 1


async def run_blocking(fn: Callable[..., T], *args: Any) -> T:
    """Run blocking work in a worker thread, keeping virtual time frozen meanwhile."""
    loop = asyncio.get_running_loop()
    if isinstance(loop, VirtualTimeLoop):
        return await loop.run_in_worker(fn, *args)
    return await asyncio.to_thread(fn, *args)


def run_virtual(coro: Coroutine[Any, Any, T], *, start_s: float = 1.0) -> T:
    """Run a coroutine to completion on a fresh :class:`VirtualTimeLoop`."""
    loop = VirtualTimeLoop(start_s)
    try:
        asyncio.set_event_loop(loop)
        return loop.run_until_complete(coro)
    finally:
        try:
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.run_until_complete(loop.shutdown_default_executor())
        finally:
            asyncio.set_event_loop(None)
            loop.close()
