"""The simulated vehicle's telemetry link in virtual time: delay, duplicated and reordered
messages, and the autopilot's clock (the ``faults:`` section's link kinds).

Without a fault the newest telemetry sample is delivered as it is. While one is injected
:meth:`LinkTiming.deliver` hands the reader what a real link would:

* ``link_delay``: the newest sample sent at least ``delay_s`` ago (the link is a queue: never
  one older than the last delivered), stamped on receipt ``delay_s`` after it was sent;
  commands are answered ``delay_s`` later; streamed setpoints reach the autopilot ``delay_s``
  after they were sent, in order (:meth:`LinkTiming.send_setpoint`); the ground's history
  (:attr:`LinkTiming.ground`, what ``state_at`` reads) holds only the samples received,
  stamped on receipt. After the window a fresh sample or setpoint goes straight through and
  overtakes the ones still in flight (dropped: never an older one after a newer one);
* ``link_duplicate``: every message arrives twice (the copy with a later receipt stamp);
* ``link_reorder``: every message overtakes the one before it (which arrives after it).
  With either, the copy or the late message enters the ground's history too, stamped on
  receipt, as the ``mavsdk`` driver's history takes what MAVSDK hands it (a late one then
  stands for a position already left: ``state_at`` near it is off by one message's motion);
* ``autopilot_clock_jump``: the autopilot's timestamps (``autopilot_time_ns``) jump by
  ``jump_s`` and stay shifted (an autopilot clock reset or resync).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace

from eaglemission.telemetry.history import TelemetryHistory
from eaglemission.types import Setpoint, VehicleState


def _window_ns(duration_s: float, origin: str) -> int:
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"{origin}: duration_s must be > 0, got {duration_s}")
    return int(round(duration_s * 1e9))


class LinkTiming:
    """Timing faults of one simulated vehicle's link (see the module docstring)."""

    def __init__(self, history: TelemetryHistory, ground: TelemetryHistory) -> None:
        self._history = history  # the samples sent (stamped when sent)
        self.ground = ground  # the samples received (stamped on receipt): what state_at reads
        self._in_flight: deque[VehicleState] = deque()  # sent, not received (receipt stamps)
        self._setpoints: deque[tuple[int, Setpoint]] = deque()  # in flight: (due_ns, setpoint)
        self.clock_offset_ns = 0
        self._delay_ns = 0
        self._delay_until_ns = -1
        self._duplicate_until_ns = -1
        self._reorder_until_ns = -1
        self._sent: VehicleState | None = None  # the last sample taken off the link, as sent
        self._shown: VehicleState | None = None  # the last message delivered (as received)
        self._pending: VehicleState | None = None  # a copy or a late message, delivered next

    # -- injection -----------------------------------------------------------------------------
    def inject_delay(self, now_ns: int, delay_s: float, duration_s: float) -> None:
        if not (math.isfinite(delay_s) and 0 < delay_s <= 10):
            raise ValueError(f"inject_link_delay: delay_s must be in (0, 10], got {delay_s}")
        self._delay_ns = int(round(delay_s * 1e9))
        self._delay_until_ns = now_ns + _window_ns(duration_s, "inject_link_delay")

    def inject_duplicate(self, now_ns: int, duration_s: float) -> None:
        self._duplicate_until_ns = now_ns + _window_ns(duration_s, "inject_link_duplicate")

    def inject_reorder(self, now_ns: int, duration_s: float) -> None:
        self._reorder_until_ns = now_ns + _window_ns(duration_s, "inject_link_reorder")

    def inject_clock_jump(self, jump_s: float) -> None:
        if not (math.isfinite(jump_s) and jump_s != 0):
            raise ValueError(f"inject_autopilot_clock_jump: jump_s must be finite and != 0, "
                             f"got {jump_s}")
        self.clock_offset_ns += int(round(jump_s * 1e9))

    # -- the link ------------------------------------------------------------------------------
    def command_delay_s(self, now_ns: int) -> float:
        """How much later than without the fault a command is answered."""
        return self._delay_ns * 1e-9 if now_ns < self._delay_until_ns else 0.0

    def send(self, sample: VehicleState) -> None:
        """A telemetry sample leaves the vehicle (at its stamp): received at once, or
        ``delay_s`` later while a delay is injected."""
        sent_ns = sample.timestamp_ns
        self.receive_due(sent_ns)
        if sent_ns >= self._delay_until_ns:
            self._in_flight.clear()  # overtaken by this fresh sample (as state() jumps to it)
            self.ground.append(sample)
            return
        receipt_ns = sent_ns + self._delay_ns
        if self._in_flight:  # a queue: received in the order sent
            receipt_ns = max(receipt_ns, self._in_flight[-1].timestamp_ns)
        self._in_flight.append(replace(sample, timestamp_ns=receipt_ns))

    def receive_due(self, now_ns: int) -> None:
        """Take the samples received by ``now_ns`` into :attr:`ground`."""
        in_flight = self._in_flight
        while in_flight and in_flight[0].timestamp_ns <= now_ns:
            self.ground.append(in_flight.popleft())

    def send_setpoint(self, setpoint: Setpoint, now_ns: int) -> bool:
        """Queue a streamed setpoint sent at ``now_ns`` while a delay is injected (True).
        False: no delay, it goes straight through (and overtakes those still in flight)."""
        queue = self._setpoints
        if now_ns >= self._delay_until_ns:
            queue.clear()
            return False
        due_ns = now_ns + self._delay_ns
        while queue and queue[-1][0] >= due_ns:
            queue.pop()  # overtaken (a shorter delay injected since): never delivered after it
        queue.append((due_ns, setpoint))
        return True

    def due_setpoint(self, now_ns: int) -> Setpoint | None:
        """The newest setpoint in flight due by ``now_ns`` (the older due ones are stale)."""
        queue = self._setpoints
        newest = None
        while queue and queue[0][0] <= now_ns:
            newest = queue.popleft()[1]
        return newest

    def deliver(self, latest: VehicleState, now_ns: int) -> VehicleState:
        """The message a reader gets at ``now_ns`` when ``latest`` is the newest sample sent."""
        delayed = now_ns < self._delay_until_ns
        if not delayed and self._pending is None and now_ns >= max(
                self._duplicate_until_ns, self._reorder_until_ns):
            self._sent = self._shown = latest
            return latest
        src = latest
        if delayed:
            older = self._history.latest_at_or_before(now_ns - self._delay_ns)
            sent = self._sent
            src = older if older is not None else (sent or latest)
            if sent is not None and src.timestamp_ns < sent.timestamp_ns:
                src = sent  # a queue: nothing older than what already came through
        if self._sent is None or src.timestamp_ns != self._sent.timestamp_ns:
            previous, self._sent = self._sent, src
            receipt = src.timestamp_ns + (self._delay_ns if delayed else 0)
            self._shown = replace(src, timestamp_ns=min(max(receipt, src.timestamp_ns), now_ns))
            self._pending = None  # a copy or late message not read yet came before this one
            if now_ns < self._duplicate_until_ns:
                self._pending = src
            elif now_ns < self._reorder_until_ns and previous is not None:
                self._pending = previous
            return self._shown
        if self._pending is not None:
            assert self._shown is not None
            late = self._pending
            self._pending = None
            self._shown = replace(late, timestamp_ns=max(now_ns, self._shown.timestamp_ns + 1))
            self.ground.append(self._shown)  # received: in the history as the driver keeps it
        assert self._shown is not None
        return self._shown
