"""The fuzz targets of tests/fuzz at scale, from one seeded generator per target: counts,
outcomes, crashes (must be 0) and throughput.

    python benchmarks/fuzz.py --configs 100000 --telemetry 20000 --mavlink 100000 --seed 1
    python benchmarks/fuzz.py --configs 2000 --files 500 --frames 500 --seed 7   # a quick one

Targets (see each module's docstring for its property):

* ``--configs N``: mission files (tests/fuzz/fuzz_config.py); 90% mutated shipped files
  validated as ``eaglemission validate`` does, 10% random / cut / shuffled YAML text through
  the ``validate`` command itself;
* ``--telemetry N``: scripts of commands under hostile telemetry into the safety envelope
  (fuzz_telemetry.py);
* ``--mavlink N``: mutated MAVLink streams into the emulator, and as many HIL_STATE_QUATERNION
  JSON documents into HilTruth (fuzz_mavlink.py);
* ``--files N``: mutated MCAP recordings into ``log`` / ``log --recover`` and mutated JSON
  lines into their readers (fuzz_files.py);
* ``--frames N``: arrays into the frame checks, frame sequences into every detector
  (fuzz_frames.py);
* ``--missions N``: whole simulated missions under bursts of hostile telemetry
  (fuzz_mission.py; a few seconds each).

Target ``t`` uses ``random.Random(f"{seed}:{t}")``: a run is reproduced by its seed and counts.
The registry's entry-point scan (~20 ms a call, several per validation) is cached for the run
(the installed plugins do not change while it runs); nothing else is changed.
Exit status 1 if any target crashed.
"""

from __future__ import annotations

import argparse
import functools
import importlib.metadata
import logging
import random
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "fuzz"))

from fuzz_common import FuzzCrash, Tally  # noqa: E402

CRASHES_SHOWN = 5


def _cache_entry_points() -> None:
    import eaglemission.commands.checks as checks
    import eaglemission.registry as registry

    cached = functools.lru_cache(maxsize=None)(
        lambda group: tuple(importlib.metadata.entry_points(group=group)))
    registry.entry_points = lambda group: cached(group)  # type: ignore[assignment]
    checks.entry_points = lambda group: cached(group)  # type: ignore[assignment]


def _loop(tally: Tally, n: int, one: Callable[[int], str]) -> None:
    for i in range(n):
        try:
            tally.outcomes[one(i)] += 1
        except FuzzCrash as exc:
            tally.crashes.append(exc)


def run_configs(n: int, rng: random.Random, tmp: Path) -> Tally:
    from fuzz_config import (
        CONFIG_FILES,
        base_documents,
        check_document,
        check_file,
        mutate,
        random_text,
    )

    docs = base_documents()
    texts = [p.read_text("utf-8") for p in CONFIG_FILES]
    path = tmp / "mission.yaml"
    tally = Tally()

    def one(i: int) -> str:
        if rng.random() < 0.1:
            path.write_text(random_text(rng, texts), encoding="utf-8", errors="surrogatepass")
            return "file:" + check_file(path)
        return "doc:" + check_document(mutate(rng.choice(docs), rng))

    _loop(tally, n, one)
    return tally


def run_telemetry(n: int, rng: random.Random, tmp: Path) -> Tally:
    from fuzz_telemetry import check_sequence, random_sequence

    tally = Tally()
    _loop(tally, n, lambda i: check_sequence(random_sequence(rng)))
    return tally


def run_mavlink(n: int, rng: random.Random, tmp: Path) -> Tally:
    from eaglemission.drivers.vehicles.mavsdk.hil_truth import HilTruth
    from fuzz_mavlink import EmulatorRig, check_hil, check_stream, random_hil_json, random_stream

    tally = Tally()
    state: dict[str, Any] = {"rig": EmulatorRig.new(), "truth": HilTruth()}

    def one(i: int) -> str:
        if i % 500 == 0:  # a fresh vehicle now and then (a long stream drifts into failsafes)
            state["rig"].close()
            state["rig"], state["truth"] = EmulatorRig.new(), HilTruth()
        out = check_stream(state["rig"], random_stream(rng))
        return out + "+hil:" + check_hil(state["truth"], 1000 * (i + 1), random_hil_json(rng))

    try:
        _loop(tally, n, one)
    finally:
        state["rig"].close()
    return tally


def run_files(n: int, rng: random.Random, tmp: Path) -> Tally:
    from fuzz_files import check_jsonl, check_mcap, mutate_bytes, sample_jsonl, sample_recording

    samples = [sample_recording(tmp / "z.mcap"), sample_recording(tmp / "n.mcap",
                                                                   compression="none")]
    log, tel = sample_jsonl()
    tally = Tally()

    def one(i: int) -> str:
        if i % 2:
            return "jsonl:" + check_jsonl(tmp, mutate_bytes(log, rng), mutate_bytes(tel, rng))
        return "mcap:" + check_mcap(tmp / "f.mcap", mutate_bytes(rng.choice(samples), rng))

    _loop(tally, n, one)
    return tally


def run_frames(n: int, rng: random.Random, tmp: Path) -> Tally:
    from fuzz_frames import (
        check_detector,
        check_frame_checks,
        detector_names,
        new_detector,
        random_frame_image,
    )

    names = detector_names()
    dets = {name: new_detector(name) for name in names}
    tally = Tally()

    def one(i: int) -> str:
        if i % 2:
            return "checks:" + check_frame_checks(rng)
        name = names[(i // 2) % len(names)]
        try:
            return f"{name}:" + check_detector(name, dets[name], random_frame_image(rng), i)
        except FuzzCrash:
            dets[name] = new_detector(name)
            raise

    _loop(tally, n, one)
    return tally


def run_missions(n: int, rng: random.Random, tmp: Path) -> Tally:
    from fuzz_mission import check_mission

    from eaglemission.config import load_config

    cfg = load_config(None)
    tally = Tally()
    _loop(tally, n, lambda i: check_mission(cfg, rng.randrange(2**32)).split(":")[0])
    return tally


TARGETS: dict[str, Callable[[int, random.Random, Path], Tally]] = {
    "configs": run_configs, "telemetry": run_telemetry, "mavlink": run_mavlink,
    "files": run_files, "frames": run_frames, "missions": run_missions}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    for name in TARGETS:
        ap.add_argument(f"--{name}", type=int, default=0, metavar="N", help=f"{name} cases")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)  # interventions and refusals are expected by the thousand
    _cache_entry_points()
    total_crashes = 0
    print(f"fuzz seed {args.seed}")
    with tempfile.TemporaryDirectory() as tmp:
        for name, run in TARGETS.items():
            n = getattr(args, name)
            if n <= 0:
                continue
            rng = random.Random(f"{args.seed}:{name}")
            t0 = time.perf_counter()
            tally = run(n, rng, Path(tmp))
            wall = time.perf_counter() - t0
            total_crashes += len(tally.crashes)
            outcomes = ", ".join(f"{k} {v}" for k, v in sorted(tally.outcomes.items()))
            print(f"{name:10s} {tally.total():7d} cases  {len(tally.crashes):4d} crashes  "
                  f"{tally.total() / wall:8.1f} cases/s  {wall:7.1f} s  "
                  f"(seed {args.seed}:{name}; {outcomes})", flush=True)
            for c in tally.crashes[:CRASHES_SHOWN]:
                print(f"    CRASH {c.problem}\n          case: {c.case}")
    print(f"crashes: {total_crashes}")
    return 1 if total_crashes else 0


if __name__ == "__main__":
    sys.exit(main())
