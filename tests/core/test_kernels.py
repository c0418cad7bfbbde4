"""The lazy kernel loader, and that the compiled kernels the equality tests compare with their
numpy references really load (a None kernel would make those tests compare numpy with numpy)."""

from __future__ import annotations

import pytest

from eaglemission.kernels import lazy_kernel


def test_missing_kernel_is_none_and_loading_is_cached() -> None:
    assert lazy_kernel("eaglemission.no_such_kernel_module", "f")() is None
    load = lazy_kernel("math", "sqrt")
    assert load() is load()
    assert load()(9.0) == 3.0


@pytest.mark.parametrize("module,loader", [
    ("eaglemission.estimators.rpnp", "_kernel"),
    ("eaglemission.estimators.pnp_refine", "_refine_kernel"),
    ("eaglemission.perception.colour", "_colour_kernel"),
])
def test_the_compiled_kernels_load(module: str, loader: str) -> None:
    import importlib

    kernel = getattr(importlib.import_module(module), loader)()
    assert kernel is not None and hasattr(kernel, "py_func")  # a numba dispatcher
