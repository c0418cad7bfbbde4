"""Lazy loading of compiled (numba) kernels.

A plugin's numba kernels live in their own modules, compiled (or loaded from numba's disk
cache) on first use rather than at import; every caller keeps a pure-numpy reference path and
falls back to it when the kernel cannot be imported.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from typing import Any


def lazy_kernel(module: str, name: str) -> Callable[[], Any]:
    """A cached loader of ``module.name``: the kernel, or None when it cannot be imported."""

    @functools.cache
    def load() -> Any:
        try:
            return getattr(importlib.import_module(module), name)
        except ImportError:  # pragma: no cover - numba is a dependency
            return None

    return load
