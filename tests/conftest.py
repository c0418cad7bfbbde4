"""Shared fixtures: seeded RNG, the ../shared data folder, fake clocks; how the tests are shared
between the xdist workers."""

from __future__ import annotations

import gc
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]

MACHINE_GROUP = "machine"


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups (--dist loadgroup)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Each module runs on one worker (its module-scoped fixtures are built once); the modules
    marked ``machine`` share one group, so they run one at a time: they use UDP ports, start
    emulator processes or find their child flights in /proc, or talk to a PX4 SITL, which a
    second worker would disturb."""
    for item in items:
        if item.get_closest_marker("xdist_group") is not None:
            continue
        group = (MACHINE_GROUP if item.get_closest_marker("machine") is not None
                 else item.nodeid.split("::", 1)[0])
        item.add_marker(pytest.mark.xdist_group(group))


def shared_dir() -> Path | None:
    """``../shared`` next to the checkout (or ``$EAGLEMISSION_SHARED``), None when absent."""
    env = os.environ.get("EAGLEMISSION_SHARED")
    p = Path(env) if env else REPO.parent / "shared"
    return p if p.is_dir() else None


@pytest.fixture(autouse=True)
def short_gc_pauses(request: pytest.FixtureRequest) -> Iterator[None]:
    """Late in a run a worker holds 1.3-1.6 million objects (numba's compiler state, imports,
    module fixtures), and a full collection then stops every thread for up to 1.3 s, longer
    than the offboard watchdog's 0.5 s in a real-time test that is not a flight. After each
    test what it left is collected and the survivors frozen (:func:`gc.freeze`), so a test's
    full collections walk only what it allocated, as a flight's do (eaglemission/flight/heap.py).
    Tests marked ``gc_unfrozen`` run on the whole heap, unfrozen."""
    if request.node.get_closest_marker("gc_unfrozen") is not None:
        gc.unfreeze()
    yield
    gc.collect()
    gc.freeze()


@pytest.fixture(autouse=True)
def wide_console(monkeypatch: pytest.MonkeyPatch) -> None:
    """The CLI's rich console wraps at COLUMNS (80 off a terminal) and folds a word longer than
    what is left of the line, a temporary path included (longer under xdist: ``popen-gw1``):
    one width for every test, its subprocesses included."""
    monkeypatch.setenv("COLUMNS", "1000")


@pytest.fixture
def shared() -> Path:
    p = shared_dir()
    if p is None:
        pytest.skip("../shared is absent (set EAGLEMISSION_SHARED)")
    return p


@pytest.fixture
def davis(shared: Path) -> Path:
    p = shared / "data" / "video_saliency" / "DAVIS2016"
    if not p.is_dir():
        pytest.skip("DAVIS2016 data absent from ../shared")
    return p


@pytest.fixture
def px4_tlogs(shared: Path) -> Path:
    p = shared / "data" / "px4_sitl_tlogs"
    if not p.is_dir():
        pytest.skip("px4_sitl_tlogs absent from ../shared")
    return p


@pytest.fixture
def rng() -> np.random.RandomState:
    return np.random.RandomState(12345)


@pytest.fixture
def sitl_config():
    from eaglemission.config import load_config

    return load_config(check_plugins=False)
