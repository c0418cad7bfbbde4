"""Offboard watchdog: a thread that commands HOLD when fresh setpoints stop.

MAVSDK re-sends the last offboard setpoint at 20 Hz by itself, so a mission whose event loop
hangs (a blocking call, a deadlock, a detector stuck in C code holding the GIL only briefly)
still looks alive to PX4, and PX4's own offboard-loss failsafe (COM_OF_LOSS_T) never fires
(MAVSDK-Python #741). This watchdog runs in its own thread, outside the event loop it guards,
and calls a *synchronous* hold function (for the MAVSDK driver: MAVSDK's blocking
``Offboard.stop()`` / ``Action.hold()`` on MAVSDK's own I/O thread, which needs nothing from
the blocked loop) when :meth:`OffboardWatchdog.feed` has not been called for ``timeout_s``.

It is one-shot per activation: after firing it stays disarmed until :meth:`arm` is called
again (the next ``start_offboard``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)


class OffboardWatchdog:
    """Fires ``on_expire(age_s)`` in its own thread when not fed for ``timeout_s``.

    Parameters
    ----------
    timeout_s : float
        Longest allowed gap between two fresh setpoints, in seconds (wall, monotonic).
    on_expire : callable(age_s) -> None
        Called once per activation from the watchdog thread; it may block (it should be
        bounded). Exceptions are logged and recorded in :attr:`last_error`.
    poll_s : float or None
        Check period; default ``timeout_s / 10`` (at least 5 ms).
    name : str
        Thread name.
    """

    def __init__(self, timeout_s: float, on_expire: Callable[[float], None], *,
                 poll_s: float | None = None, name: str = "offboard-watchdog") -> None:
        if not timeout_s > 0:
            raise ValueError(f"timeout_s: must be > 0, got {timeout_s}")
        self.timeout_s = float(timeout_s)
        self.poll_s = float(poll_s) if poll_s is not None else max(0.005, self.timeout_s / 10.0)
        self._on_expire = on_expire
        self._lock = threading.Lock()
        self._armed = False
        self._last_feed = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._name = name
        self.fired_count = 0
        self.last_fired_age_s: float | None = None
        self.last_error: BaseException | None = None

    # -- lifecycle
    def start(self) -> None:
        """Start the thread (idempotent). It does nothing until :meth:`arm`."""
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the thread (idempotent)."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)
            if not t.is_alive():
                self._thread = None

    # -- use
    def arm(self, grace_s: float = 0.0) -> None:
        """Start watching (offboard started); counts as a fresh setpoint. ``grace_s`` moves
        the first deadline later (``timeout_s + grace_s`` from now): a backstop while a mode
        change is being confirmed, re-armed without grace once it is."""
        with self._lock:
            self._armed = True
            self._last_feed = time.monotonic() + max(0.0, float(grace_s))

    def disarm(self) -> None:
        """Stop watching (offboard stopped on purpose)."""
        with self._lock:
            self._armed = False

    def feed(self) -> None:
        """A fresh setpoint was produced."""
        with self._lock:
            self._last_feed = time.monotonic()

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def running(self) -> bool:
        """The thread is alive (e.g. still inside a blocking hold call after :meth:`stop`)."""
        return self._thread is not None and self._thread.is_alive()

    def age_s(self) -> float:
        """Seconds since the last fresh setpoint."""
        with self._lock:
            return max(0.0, time.monotonic() - self._last_feed)

    # -- thread
    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            with self._lock:
                if not self._armed:
                    continue
                age = time.monotonic() - self._last_feed
                if age <= self.timeout_s:
                    continue
                self._armed = False  # one shot
            self.fired_count += 1
            self.last_fired_age_s = age
            log.warning("offboard watchdog: no fresh setpoint for %.2f s (limit %.2f s): "
                        "commanding HOLD", age, self.timeout_s)
            try:
                self._on_expire(age)
            except BaseException as exc:  # noqa: BLE001 - a watchdog thread must survive
                self.last_error = exc
                log.exception("offboard watchdog: the hold command failed")
