"""Where a campaign's runs execute: ``local`` (a spawn multiprocessing pool, ``--workers``) or
``ray`` (Ray tasks on a local Ray started with ``num_cpus=--workers``, or on the cluster at
``--address``).

Both run the same per-run function on the same jobs and yield each run's result as it finishes.
Every worker pins its thread pools to one thread (:data:`THREAD_ENV`, ``cv2.setNumThreads(1)``,
``numba.set_num_threads(1)``), so a run's result does not depend on where it ran: the summaries
of both executors are equal apart from :data:`WALL_TIME_FIELDS`.

On a cluster (``--address``) the project travels as Ray's ``runtime_env["working_dir"]``: a
staging copy of the installed package (core and plugin folders as ``eaglemission/...``) and its
``.dist-info`` (the entry points the registry loads plugins from); see :func:`stage_project`.
The project's dependencies (numpy, OpenCV, numba, ..., ray itself at the same version) must be
installed on the nodes. The run configs travel as task arguments.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import multiprocessing as mp
import os
import shutil
import signal
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from eaglemission.errors import EagleMissionError

Job = tuple[Any, ...]
"""One run's arguments, opaque here: ``job[0]`` is the run index."""
RunFn = Callable[[Any], dict[str, Any]]

THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "NUMEXPR_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
"""Thread counts set in every worker's environment before it imports numpy, OpenCV, numba."""

WALL_TIME_FIELDS = ("speedup", "latency_p90_ms")
"""Run fields that measure the host's time (how fast the computer flew it), not the flight."""

STALL_TIMEOUT_S = 3600.0
"""No run finishing for this long ends the campaign with an error (a hung worker)."""

RAY_INIT_ATTEMPTS = 3
"""Tries to start or reach Ray: a loaded host can miss Ray's own 30 s raylet start timeout."""

PLUGIN_PACKAGES = ("drivers", "detectors", "estimators", "missions", "lab", "configs")
"""The plugin folders installed as ``eaglemission.<name>`` (pyproject ``package-dir``)."""

RAY_MISSING = ("the ray executor needs Ray: pip install 'eaglemission[ray]' "
               "(or use --executor local)")


class CampaignExecutorError(EagleMissionError):
    """An executor could not be set up or lost its workers."""


class Executor(Protocol):
    """Runs ``fn`` on each job, yielding the results in completion order."""

    name: str

    def map_unordered(self, fn: RunFn, jobs: Sequence[Job]) -> Iterator[dict[str, Any]]: ...


def pin_threads() -> None:
    """Pin this process's thread pools to one thread (called in each worker, per run)."""
    os.environ.update(THREAD_ENV)
    import cv2
    import numba

    cv2.setNumThreads(1)
    numba.set_num_threads(1)


def _pool_worker_init() -> None:
    """A local pool's worker: pinned threads, and Ctrl-C left to the campaign (a terminal
    sends it to the whole process group; the campaign stops its workers itself; what a run
    starts in a session of its own, an emulator run's ``sitl-vehicle``, ends with its worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    pin_threads()


@contextmanager
def _thread_env() -> Iterator[None]:
    """:data:`THREAD_ENV` in ``os.environ`` while it lasts: spawned children inherit it."""
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update(THREAD_ENV)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@dataclass
class LocalExecutor:
    """A spawn pool of ``workers`` processes (5 runs each, then a fresh one); ``workers <= 1``
    runs in this process (unpinned: the caller's thread settings are left alone)."""

    workers: int = 2
    name: str = "local"

    def map_unordered(self, fn: RunFn, jobs: Sequence[Job]) -> Iterator[dict[str, Any]]:
        if self.workers <= 1 or not jobs:
            yield from map(fn, jobs)
            return
        with _thread_env():
            pool = mp.get_context("spawn").Pool(self.workers, initializer=_pool_worker_init,
                                                maxtasksperchild=5)
            ok = False
            try:
                it = pool.imap_unordered(fn, jobs)
                for _ in jobs:
                    try:
                        yield it.next(timeout=STALL_TIMEOUT_S)
                    except mp.TimeoutError:
                        raise CampaignExecutorError(
                            f"local executor: no run finished in {STALL_TIMEOUT_S:.0f} s") from None
                ok = True
            finally:
                if ok:
                    pool.close()
                else:  # interrupted or failed: do not wait for the runs still flying
                    pool.terminate()
                pool.join()


def _ray_task(fn: RunFn, job: Job) -> dict[str, Any]:
    """One run inside a Ray worker."""
    pin_threads()
    return fn(job)


def import_ray() -> Any:
    """The ``ray`` module, or :class:`CampaignExecutorError` naming the extra to install."""
    try:
        return importlib.import_module("ray")
    except ImportError as exc:
        raise CampaignExecutorError(RAY_MISSING) from exc


def stage_project(dest: Path) -> Path:
    """Copy the installed project into ``dest`` as an importable tree with its metadata:
    ``eaglemission/`` (core, with the plugin folders as subpackages, wherever the install put
    them: editable or not) and ``eaglemission-<version>.dist-info/`` (METADATA and the entry
    points). Ray adds a ``working_dir`` to each worker's ``sys.path``; returns ``dest``."""
    import eaglemission

    skip = shutil.ignore_patterns("__pycache__", "*.pyc")
    core = dest / "eaglemission"
    shutil.copytree(Path(next(iter(eaglemission.__path__))), core, ignore=skip)
    for sub in PLUGIN_PACKAGES:
        src = Path(next(iter(importlib.import_module(f"eaglemission.{sub}").__path__)))
        if not (core / sub).exists():
            shutil.copytree(src, core / sub, ignore=skip)
    dist = importlib.metadata.distribution("eaglemission")
    info = dest / f"eaglemission-{dist.version}.dist-info"
    info.mkdir()
    # the distribution this process's registry reads (an egg-info keeps METADATA as PKG-INFO)
    for name, alt in (("METADATA", "PKG-INFO"), ("entry_points.txt", None)):
        text = dist.read_text(name) or (dist.read_text(alt) if alt else None)
        if text is None:
            raise CampaignExecutorError(f"the installed eaglemission has no {name}: reinstall it")
        (info / name).write_text(text)
    return dest


@dataclass
class RayExecutor:
    """Ray tasks, one CPU each: a local Ray with ``num_cpus=workers`` or the cluster at
    ``address`` (the project shipped as the job's ``working_dir``). A Ray already initialised
    by the caller is used as it is and left running."""

    workers: int = 2
    address: str | None = None
    name: str = "ray"

    def map_unordered(self, fn: RunFn, jobs: Sequence[Job]) -> Iterator[dict[str, Any]]:
        if not jobs:  # a resumed campaign with every run stored: no Ray to start
            return
        ray = import_ray()
        import logging

        own = not ray.is_initialized()
        with tempfile.TemporaryDirectory(prefix="eaglemission-ray-") as tmp:
            env: dict[str, Any] = {"env_vars": dict(THREAD_ENV)}
            if self.address is not None:
                env["working_dir"] = str(stage_project(Path(tmp) / "project"))
            if own:
                # "local": a new local Ray, never a cluster found via RAY_ADDRESS or `ray start`
                kw: dict[str, Any] = {"address": self.address} if self.address else \
                    {"address": "local", "num_cpus": self.workers}
                for attempt in range(1, RAY_INIT_ATTEMPTS + 1):
                    try:
                        ray.init(**kw, runtime_env=env, include_dashboard=False,
                                 log_to_driver=False, logging_level=logging.WARNING)
                        break
                    except Exception as exc:  # ConnectionError, a slow raylet...: say where
                        ray.shutdown()
                        if attempt == RAY_INIT_ATTEMPTS:
                            raise CampaignExecutorError(
                                f"ray executor: cannot start Ray at {self.address or 'local'} "
                                f"({attempt} attempts): {type(exc).__name__}: {exc}") from exc
            task = ray.remote(_ray_task).options(num_cpus=1, runtime_env=None if own else env)
            pending = [task.remote(fn, job) for job in jobs]
            try:
                while pending:
                    done, pending = ray.wait(pending, num_returns=1, timeout=STALL_TIMEOUT_S)
                    if not done:
                        raise CampaignExecutorError(
                            f"ray executor: no run finished in {STALL_TIMEOUT_S:.0f} s")
                    yield ray.get(done[0])
            finally:
                for ref in pending:  # interrupted: stop the runs still queued or flying
                    ray.cancel(ref, force=True)
                if own:
                    ray.shutdown()


def make_executor(name: str, *, workers: int = 2, address: str | None = None) -> Executor:
    """The executor called ``name`` (``local`` or ``ray``); ``address`` only for ``ray``."""
    if name == "local":
        if address is not None:
            raise CampaignExecutorError("--address: only for --executor ray")
        return LocalExecutor(workers=workers)
    if name == "ray":
        if importlib.util.find_spec("ray") is None:
            raise CampaignExecutorError(RAY_MISSING)
        return RayExecutor(workers=max(1, workers), address=address)
    raise CampaignExecutorError(f"--executor: unknown {name!r} (local or ray)")


def flight_fields(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The runs without their :data:`WALL_TIME_FIELDS`: what must not depend on the executor."""
    return [{k: v for k, v in r.items() if k not in WALL_TIME_FIELDS} for r in runs]
