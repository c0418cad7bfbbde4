"""A flight runs on a frozen heap (eaglemission/flight/heap.py): the objects alive at its start are
not walked by the flight's full collections, and are collectable again after it."""

from __future__ import annotations

import gc
import weakref

import pytest
from eaglemission.lab.campaign.sim import run_simulation

from eaglemission.flight.heap import frozen_heap

# the suite freezes the heap between tests (tests/conftest.py): these see the heap as a mission
# process does, unfrozen
pytestmark = pytest.mark.gc_unfrozen


class _Node:
    def __init__(self) -> None:
        self.me = self  # a reference cycle: only the cycle collector frees it


def test_frozen_heap_exempts_the_objects_alive_at_entry_until_exit() -> None:
    node = _Node()
    gone = weakref.ref(node)
    with frozen_heap() as frozen:
        assert frozen > 0
        del node
        gc.collect()
        assert gone() is not None  # frozen: a full collection does not walk it
        with frozen_heap():  # nested: keeps the outer freeze
            pass
        assert gc.get_freeze_count() > 0
        gc.collect()
        assert gone() is not None
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert gone() is None  # unfrozen: collected, nothing leaked


def test_the_flight_runs_on_a_frozen_heap(fast_config) -> None:
    """Objects alive before the flight are frozen during it (the pause it saves is printed by
    benchmarks/bench_gc_pauses.py) and unfrozen after it."""
    ballast = [{"i": i, "l": [i]} for i in range(100_000)]
    seen: list[int] = []

    def at_state(t_s: float, new: str, reason: str, action: str) -> None:
        seen.append(gc.get_freeze_count())

    run_simulation(fast_config, on_state=at_state)
    assert len(seen) > 3 and min(seen) > len(ballast)  # every state change: the ballast frozen
    assert gc.get_freeze_count() == 0
