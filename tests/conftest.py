"""Shared fixtures: seeded RNG, the ../shared data folder, fake clocks; how the tests are shared
between the xdist workers."""

from __future__ import annotations

import gc
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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
    loadgroup = bool(getattr(config.option, "loadgroup", False))  # set on xdist's workers
    for item in items:
        marker = item.get_closest_marker("xdist_group")
        if marker is None:
            group = (MACHINE_GROUP if item.get_closest_marker("machine") is not None
                     else item.nodeid.split("::", 1)[0])
            item.add_marker(pytest.mark.xdist_group(group))
        else:
            group = str(marker.args[0] if marker.args else marker.kwargs.get("name", "default"))
        if loadgroup:
            _tell_xdist_the_group(item, group)


def _tell_xdist_the_group(item: pytest.Item, group: str) -> None:
    """xdist's workers tell the scheduler an item's group as a ``@group`` suffix of its node
    id. xdist 3.8 writes the suffix into ``item._nodeid``, which pytest 9.2 no longer reads
    (the id is the structured ``item._id``; pytest-xdist issue 1386): the groups were then
    silently ignored and two workers ran the machine modules at once. The suffix is written into
    the structured id here (once: xdist's own suffix, where it still works, ends the same)."""
    node_id = getattr(item, "_id", None)
    parse = getattr(type(node_id), "parse", None)
    if node_id is None or parse is None or str(node_id).endswith(f"@{group}"):
        return
    item._id = parse(f"{node_id}@{group}")


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


# ---------------------------------------------------------------------------------------------
# PX4 SITL: one test at a time, a fresh instance each when a build is given
# ---------------------------------------------------------------------------------------------
PX4_LOCK_TIMEOUT_S = 1800.0
"""How long a test waits for another user of the machine's PX4 (another test run)."""


@dataclass(frozen=True)
class Px4Sitl:
    """The PX4 a test flies: where to connect, which simulator, the started instance (None
    for a PX4 the user runs)."""

    url: str
    sim: str
    instance: Any = None


@pytest.fixture
def px4_sitl(tmp_path: Path) -> Iterator[Px4Sitl]:
    """A PX4 SITL for this test alone. ``EAGLEMISSION_PX4_BUILD`` set: a fresh instance started
    for the test (``EAGLEMISSION_PX4_SIM`` sih|jmavsim, ``EAGLEMISSION_JMAVSIM_JAR``) and
    stopped after it; else ``EAGLEMISSION_PX4_URL``: the PX4 the user started, its simulator
    from EAGLEMISSION_PX4_SIM or its airframe. Skipped when neither is set. The machine's PX4
    lock is held throughout, so no two tests (workers, runs) fly it at once."""
    from eaglemission.lab.px4 import sitl

    from eaglemission.names import ENV_PX4_URL

    url = os.environ.get(ENV_PX4_URL)
    build = os.environ.get(sitl.ENV_PX4_BUILD)
    if not url and not build:
        pytest.skip(f"no PX4 SITL: set {ENV_PX4_URL} (a running PX4, e.g. "
                    f"udpin://0.0.0.0:14540) or {sitl.ENV_PX4_BUILD} (a fresh PX4 per test)")
    with sitl.machine_lock(PX4_LOCK_TIMEOUT_S):
        if build:
            opts = sitl.resolve_options(workdir_parent=tmp_path)
            sitl.wait_until_free(PX4_LOCK_TIMEOUT_S)  # a PX4 started by hand, not by a test
            instance = sitl.start(opts)
            try:
                yield Px4Sitl(url or instance.url, instance.sim, instance)
            finally:
                sitl.stop(instance)
        else:
            assert url is not None
            sim = (os.environ.get(sitl.ENV_PX4_SIM) or "").lower()
            if sim and sim not in sitl.SIMS:
                pytest.fail(f"{sitl.ENV_PX4_SIM}={sim}: use one of {', '.join(sitl.SIMS)}")
            if not sim:
                from eaglemission.lab.px4.probe import airframe_sim

                sim = airframe_sim()
            yield Px4Sitl(url, sim)

