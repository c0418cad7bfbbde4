"""Progress lines for the slow steps before take-off: waiting for an autopilot and compiling the
numba kernels (the first run after an install compiles them for tens of seconds; numba's disk
cache keeps them for later runs).

Both tick in a thread on the host's clock, so a step that blocks the event loop (a kernel
compiled on the loop's thread, a virtual-time loop that does not advance) still reports.
"""

from __future__ import annotations

import contextlib
import importlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

Say = Callable[[str], None]

TICK_S = 5.0
"""How often a step still running says so."""


class Ticker:
    """Says ``line(elapsed_s)`` every ``every_s`` until stopped (a daemon thread)."""

    def __init__(self, say: Say, line: Callable[[float], str | None], every_s: float = TICK_S
                 ) -> None:
        self._say, self._line, self.every_s = say, line, every_s
        self._stop = threading.Event()
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="eaglemission-progress",
                                        daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            text = self._line(time.monotonic() - self._t0)
            if text:
                self._say(text)

    def __enter__(self) -> Ticker:
        self._t0 = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


def waiting(say: Say, what: str, every_s: float = TICK_S) -> Ticker:
    """``waiting for the autopilot on URL ... 5 s`` every ``every_s`` while the step lasts."""
    return Ticker(say, lambda t: f"waiting for {what} ... {t:.0f} s", every_s)


class CompileWatch:
    """Counts numba compilations (cache misses only: a kernel loaded from numba's disk cache
    is not compiled) and says when the first one starts and how far they are."""

    def __init__(self, say: Say) -> None:
        self._say = say
        self._lock = threading.Lock()
        self.compiled = 0
        self.reported = 0
        """Kernels compiled before take-off (the rest compiled during the flight)."""
        self.current = ""
        self.first_s: float | None = None
        self.compile_s = 0.0
        self._depth = 0
        self._started = 0.0

    def start(self, name: str) -> None:
        with self._lock:
            self._depth += 1
            if self._depth > 1:
                return  # numba's own overloads, compiled inside a kernel's compilation
            self.current = name
            self._started = time.monotonic()
            first = self.first_s is None
            if first:
                self.first_s = self._started
        if first:
            self._say("compiling numba kernels (first run only: numba caches them on disk) ...")

    def end(self) -> None:
        with self._lock:
            self._depth = max(0, self._depth - 1)
            if self._depth == 0:
                self.compiled += 1
                self.compile_s += time.monotonic() - self._started

    @property
    def busy(self) -> bool:
        """A kernel is being compiled now."""
        with self._lock:
            return self._depth > 0

    def tick(self, _elapsed_s: float) -> str | None:
        with self._lock:
            if self.first_s is None:
                return None
            busy = self._depth > 0
            t = time.monotonic() - self.first_s
            name, n = self.current, self.compiled
        if not busy:
            return None
        return f"  compiling ... {t:.0f} s, {n} kernels done, now {name}"

    def summary(self) -> str | None:
        """The line for the kernels compiled so far and not yet reported (None: none); marks
        them reported."""
        with self._lock:
            n, self.reported = self.compiled - self.reported, self.compiled
            t, self.compile_s = self.compile_s, 0.0
        if n == 0:
            return None
        return f"compiled {n} numba kernels in {t:.1f} s (cached for the next runs)"


def _listener(watch: CompileWatch, event: Any) -> Any:
    class _Listener(event.Listener):  # type: ignore[misc]
        def on_start(self, ev: Any) -> None:
            disp = ev.data.get("dispatcher")
            fn = getattr(disp, "py_func", None)
            name = (f"{getattr(fn, '__module__', '?').removeprefix('eaglemission.')}."
                    f"{getattr(fn, '__qualname__', '?')}")
            watch.start(name)

        def on_end(self, ev: Any) -> None:
            watch.end()

    return _Listener()


@contextlib.contextmanager
def compile_progress(say: Say, every_s: float = TICK_S) -> Iterator[CompileWatch]:
    """While inside: say when numba starts compiling, then every ``every_s`` how far it is,
    and at the end how many kernels took how long (nothing when all came from the cache)."""
    watch = CompileWatch(say)
    try:
        event: Any = importlib.import_module("numba.core.event")
    except ImportError:  # pragma: no cover - numba is a dependency
        yield watch
        return
    listener = _listener(watch, event)
    event.register("numba:compile", listener)
    try:
        with Ticker(say, watch.tick, every_s):
            yield watch
    finally:
        event.unregister("numba:compile", listener)
        line = watch.summary()  # what was not said yet (a dry run, a refused flight)
        if line:
            say(line)
