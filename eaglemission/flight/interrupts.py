"""Ctrl-C / SIGTERM during ``eaglemission run``: the first signal asks the mission for its safe
stop (``safety.on_interrupt``), a second exits at once (docs/field_bringup.md, "Fly")."""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

from eaglemission.config import MissionFile

EXIT_INTERRUPTED = 130


class FlightInterrupts:
    """SIGINT / SIGTERM during a flight: the first asks the mission for its safe stop
    (``safety.on_interrupt``, bounded by ``safety.interrupt_timeout_s``), or, before the
    mission runs, cancels the flight (nothing is armed yet); a second exits at once."""

    def __init__(self, cfg: MissionFile, say: Callable[[str], None]) -> None:
        self.cfg, self.say = cfg, say
        self.count = 0
        self.mission: Any = None
        self.mission_task: asyncio.Task[Any] | None = None
        self.flight_task = asyncio.current_task()
        self._loop = asyncio.get_running_loop()
        self._installed: list[int] = []
        self._timer: asyncio.TimerHandle | None = None

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._loop.add_signal_handler(sig, self._on_signal, int(sig))
                self._installed.append(int(sig))
            except (NotImplementedError, RuntimeError):  # not the main thread
                pass

    def remove(self) -> None:
        for signum in self._installed:
            self._loop.remove_signal_handler(signum)
        self._installed = []
        if self._timer is not None:
            self._timer.cancel()

    def _on_signal(self, signum: int) -> None:
        self.count += 1
        name = signal.Signals(signum).name
        if self.count > 1:
            sys.stderr.write(f"{name} again: exiting at once (the autopilot keeps its last "
                             "mode)\n")
            sys.stderr.flush()
            os._exit(EXIT_INTERRUPTED)
        if self.mission is None or self.mission_task is None:
            self.say(f"{name}: stopping before the flight (nothing armed)")
            if self.flight_task is not None:
                self.flight_task.cancel()
            return
        action = self.cfg.safety.on_interrupt
        self.say(f"{name}: safe stop ({action}) in progress; {name} again exits at once")
        self.mission.interrupt(f"interrupted by {name}", action)
        self._timer = self._loop.call_later(self.cfg.safety.interrupt_timeout_s, self._too_slow)

    def _too_slow(self) -> None:
        if self.mission_task is not None and not self.mission_task.done():
            self.say(f"the safe stop did not finish within "
                     f"{self.cfg.safety.interrupt_timeout_s:g} s: stopping the mission")
            self.mission_task.cancel()
