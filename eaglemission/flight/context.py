"""What the assembly hands the plugins of one flight besides their own config.

:class:`SharedContext` holds objects that several fake drivers of one flight must share (the
synthetic world that both synthetic cameras render and whose target the evaluator knows; the
time base of a replayed recording). The first plugin that needs an object builds it through
:meth:`SharedContext.get_or_create`; the others get the same instance. Real drivers ignore it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")

WORLD = "world"
"""Key of the synthetic world (``eaglemission.lab.world.render.SyntheticWorld``)."""
MANIPULATOR = "manipulator"
"""Key of the flight's manipulator when a fake camera should draw it (the lab's simulated
arm registers itself: ``tool_body_at(timestamp_ns)``)."""
REPLAY_EPOCH_NS = "replay_epoch_ns"
"""Key of a replay's time offset: clock time minus recorded time, ns."""


class SharedContext:
    """A small keyed store, safe across threads; values are built once."""

    def __init__(self) -> None:
        self._items: dict[str, Any] = {}
        self._lock = threading.RLock()

    def get_or_create(self, key: str, factory: Callable[[], T]) -> T:
        with self._lock:
            if key not in self._items:
                self._items[key] = factory()
            value: T = self._items[key]
            return value

    def get(self, key: str, default: Any = None) -> Any:
        with self._lock:
            return self._items.get(key, default)

    def __contains__(self, key: object) -> bool:
        with self._lock:
            return key in self._items
