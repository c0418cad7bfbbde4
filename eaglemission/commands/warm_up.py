"""``eaglemission warm-up [CONFIG]``: compile every numba kernel a flight uses, once, ahead.

The first flight after an install otherwise compiles them itself (tens of seconds before the
header, a few kernels more in the air). Warming up flies the embedded simulation in virtual
time with CONFIG's detector, estimators and appearance (those hold the kernels), nothing recorded;
numba's disk cache then serves every later run. Progress is said as it compiles.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from eaglemission.commands import Command, console

KERNEL_SECTIONS = ("detector", "estimators", "appearance")
"""The sections whose plugins compile numba kernels, taken from CONFIG."""


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?",
                   help="mission YAML whose detector, estimators and appearance to compile "
                        "(default: the embedded sitl_synthetic.yaml)")


def warm_up_config(cfg: Any) -> Any:
    """The embedded simulation with ``cfg``'s kernel sections (a validated MissionFile)."""
    from eaglemission.config import MissionFile, load_config

    data = load_config(None).model_dump()
    mine = cfg.model_dump()
    for key in KERNEL_SECTIONS:
        data[key] = mine[key]
    return MissionFile.model_validate(data)


def _run(args: argparse.Namespace) -> int:
    from eaglemission.config import load_config
    from eaglemission.errors import ConfigError
    from eaglemission.flight import progress
    from eaglemission.flight.run import FlightOptions, fly_sync

    out = console()

    def say(text: str) -> None:
        out.print(text, markup=False, highlight=False)

    source = args.config or "<embedded sitl_synthetic.yaml>"
    try:
        cfg = warm_up_config(load_config(args.config))
    except (ConfigError, ValueError) as exc:
        say(f"invalid: {exc}")
        return 2
    say(f"warm-up: compiling the kernels of {source} (detector {cfg.detector.type}, "
        f"estimators {cfg.estimators.coarse.type}/{cfg.estimators.fine.type}) by flying the "
        "embedded simulation with them")
    t0 = time.perf_counter()
    with progress.compile_progress(say) as watch, progress.Ticker(
            say, lambda t: None if watch.busy else f"  flying the simulation ... {t:.0f} s"):
        result = fly_sync(cfg, FlightOptions(record_config=False))
        total = watch.compiled
    wall = time.perf_counter() - t0
    if result.outcome is None:  # nothing flew: the kernels of the flight were not all reached
        say(f"warm-up incomplete: the simulation did not fly ({result.error}); {total} "
            "kernels compiled")
        return 1
    if total:
        say(f"warm-up done in {wall:.0f} s: {total} kernels compiled and cached; the next "
            "`eaglemission run` starts without compiling")
    else:
        say(f"warm-up done in {wall:.0f} s: every kernel was already in numba's cache")
    return 0


COMMAND = Command("compile the numba kernels ahead (once after installing, before flying)",
                  _add, _run)
