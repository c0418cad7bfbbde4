"""Clocks: virtual time jumps when idle, freezes while a worker thread runs."""

from __future__ import annotations

import asyncio
import time

import pytest

from eaglemission.clock import LoopClock, ManualClock, MonotonicClock, run_blocking, run_virtual


def test_virtual_loop_runs_sleeps_faster_than_real_time() -> None:
    async def main() -> tuple[float, list[float]]:
        clock = LoopClock()
        t0 = clock.now_ns()
        ticks: list[float] = []

        async def ticker(n: int, dt: float) -> None:
            for _ in range(n):
                await asyncio.sleep(dt)
            ticks.append((clock.now_ns() - t0) / 1e9)

        async with asyncio.TaskGroup() as tg:
            tg.create_task(ticker(100, 0.1))
            tg.create_task(ticker(30, 0.5))
        return (clock.now_ns() - t0) / 1e9, ticks

    wall0 = time.monotonic()
    elapsed, ticks = run_virtual(main())
    assert elapsed == pytest.approx(15.0, abs=1e-6)
    assert sorted(ticks) == pytest.approx([10.0, 15.0], abs=1e-6)
    assert time.monotonic() - wall0 < 2.0


def test_virtual_time_frozen_while_worker_runs_so_no_false_timeout() -> None:
    async def main() -> float:
        clock = LoopClock()
        t0 = clock.now_ns()
        async with asyncio.timeout(0.01):  # 10 ms of virtual time
            await run_blocking(time.sleep, 0.05)  # 50 ms of real work
        return (clock.now_ns() - t0) / 1e9

    assert run_virtual(main()) == pytest.approx(0.0, abs=1e-6)


def test_virtual_timeout_fires_in_virtual_time() -> None:
    async def main() -> bool:
        try:
            async with asyncio.timeout(30.0):
                await asyncio.sleep(3600.0)
        except TimeoutError:
            return True
        return False

    wall0 = time.monotonic()
    assert run_virtual(main())
    assert time.monotonic() - wall0 < 2.0


def test_manual_clock() -> None:
    c = ManualClock(start_ns=5)
    c.advance(1.5)
    assert c.now_ns() == 5 + 1_500_000_000
    with pytest.raises(ValueError, match="duration_s"):
        c.advance(-1)


def test_monotonic_clock_is_host_monotonic() -> None:
    c = MonotonicClock()
    a = time.monotonic_ns()
    b = c.now_ns()
    assert 0 <= b - a < 1_000_000_000
