"""Keep Python's full garbage collections short during a flight.

The setpoint stream, the telemetry task and the offboard watchdog are Python code in one
process: a full (generation 2) collection stops all of them while it walks every tracked object,
and that walk grows with the heap. Measured in the test suite's process on this 2-core machine
(`gc.callbacks`): full collections of 0.15-0.46 s at 0.4-0.8 million tracked objects, up to
1.05 s with both cores busy, and 0.73-1.0 s at 1.39 million late in the suite on a quiet
machine, where the offboard watchdog commands HOLD after 0.5 s without a fresh setpoint; a
real-time flight in that process has ended before FINE_APPROACH with MAVSDK "dropping
subscription callbacks".

:func:`frozen_heap` moves every object alive at the flight's start to the permanent generation
(:func:`gc.freeze`), so the flight's collections walk only what the flight allocated; the heap
is unfrozen after the flight. Nothing is leaked: frozen objects are exempt from collection only
while frozen (garbage among them is collected after the flight). No collection first: in the
test process that would cost a full walk per flight.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def frozen_heap() -> Iterator[int]:
    """Freeze the heap for the duration of the block, unfreeze after; yields the number of
    objects frozen. Nested use keeps the outer freeze (the inner block unfreezes nothing)."""
    outer = gc.get_freeze_count()
    if outer == 0:
        gc.freeze()
    try:
        yield gc.get_freeze_count()
    finally:
        if outer == 0:
            gc.unfreeze()
