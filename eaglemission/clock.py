"""Clocks. Every timestamp in eaglemission is host ``CLOCK_MONOTONIC`` nanoseconds.

``MonotonicClock`` is the wall clock of real flights. ``VirtualTimeLoop`` is an asyncio event
loop whose time jumps forward whenever nothing is ready and no worker thread is busy, so that a
simulation with ``asyncio.sleep``/``asyncio.timeout`` everywhere runs faster than real time and
deterministically. ``LoopClock`` reads the running loop's time, which is real or virtual.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextvars
import functools
import selectors
import threading
import time
from collections import deque
from collections.abc import Callable, Coroutine
from typing import Any, Protocol, TypeVar, TypeVarTuple, Unpack, runtime_checkable

T = TypeVar("T")
Ts = TypeVarTuple("Ts")


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
    """Wraps the loop's selector: a timed wait becomes a jump of virtual time when idle, and
    worker results are handed back one at a time, in submission order, only when the loop is
    idle (nothing ready), so that a simulation interleaves the same way whatever the threads'
    real timing."""

    def __init__(self, inner: selectors.BaseSelector, loop: VirtualTimeLoop) -> None:
        self._inner = inner
        self._loop = loop

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        events = self._inner.select(0)
        if events or timeout == 0:
            return events
        loop = self._loop
        if loop._workers:
            # Frozen virtual time: wait (in real time) for the OLDEST worker only; a later one
            # that finishes first waits its turn. The self-pipe wakes us when any finishes.
            if not loop._workers[0][0].done():
                events = self._inner.select(0.05)
            if loop._workers[0][0].done():
                loop._deliver_oldest()
            return events
        if timeout is None:
            return self._inner.select(0.01)  # nothing scheduled: let real I/O arrive
        loop._virtual_s += timeout
        return []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """Event loop with virtual time starting at ``start_s``.

    Blocking work goes to worker threads through :meth:`run_in_executor` (also what
    ``asyncio.to_thread`` and :func:`run_blocking` use): virtual time stands still while any
    worker runs, and results come back in submission order at idle points only, so a run is
    deterministic given its inputs (docs/conventions.md, "Time").
    """

    def __init__(self, start_s: float = 1.0) -> None:
        super().__init__()
        self._virtual_s = float(start_s)
        self._workers: deque[tuple[concurrent.futures.Future[Any], asyncio.Future[Any]]] = deque()
        internals: Any = self  # asyncio's private selector-loop attributes (not in typeshed)
        internals._selector = _VirtualSelector(internals._selector, self)
        self._clock_resolution = 1e-9

    def time(self) -> float:
        return self._virtual_s

    @property
    def busy_workers(self) -> int:
        """Worker calls submitted and not yet handed back."""
        return len(self._workers)

    def run_in_executor(self, executor: concurrent.futures.Executor | None,
                        func: Callable[[Unpack[Ts]], T], *args: *Ts) -> asyncio.Future[T]:
        internals: Any = self  # asyncio's private selector-loop API (not in typeshed)
        internals._check_closed()
        pool: concurrent.futures.Executor | None = executor or internals._default_executor
        if pool is None:
            pool = concurrent.futures.ThreadPoolExecutor(thread_name_prefix="asyncio")
            internals._default_executor = pool
        cf = pool.submit(func, *args)
        af: asyncio.Future[T] = self.create_future()
        self._workers.append((cf, af))
        cf.add_done_callback(lambda _f: internals._write_to_self())
        return af

    def _deliver_oldest(self) -> None:
        cf, af = self._workers.popleft()
        if af.cancelled():
            return
        exc = cf.exception()
        if exc is not None:
            af.set_exception(exc)
        else:
            af.set_result(cf.result())

    async def run_in_worker(self, fn: Callable[..., T], *args: Any) -> T:
        ctx = contextvars.copy_context()
        result: T = await self.run_in_executor(None, functools.partial(ctx.run, fn, *args))
        return result


async def run_blocking(fn: Callable[..., T], *args: Any) -> T:
    """Run blocking work in a worker thread, keeping virtual time frozen meanwhile."""
    loop = asyncio.get_running_loop()
    if isinstance(loop, VirtualTimeLoop):
        return await loop.run_in_worker(fn, *args)
    return await asyncio.to_thread(fn, *args)


class BoundLoopClock:
    """The clock of one event loop, readable from any thread (``loop.time()`` is a plain
    read; :class:`LoopClock` needs the running loop and fails in a worker thread). On a normal
    loop it is host monotonic time; on a :class:`VirtualTimeLoop`, virtual time."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop

    @property
    def virtual(self) -> bool:
        return isinstance(self._loop, VirtualTimeLoop)

    def now_ns(self) -> int:
        return int(round(self._loop.time() * 1e9))

    async def sleep(self, duration_s: float) -> None:
        await asyncio.sleep(duration_s)


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
