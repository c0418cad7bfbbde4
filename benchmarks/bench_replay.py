"""Recorded flights replayed (``eaglemission replay FILE.mcap``, docs/recording.md): per seed,
the setpoints and state changes of the recording and of its replay, whether they are
identical, and the wall times; optionally the same flight recorded with JPEG frames (the
default), whose replay is expected to diverge.

    python benchmarks/bench_replay.py                        # seeds 1,2,3, 320x240 cameras
    python benchmarks/bench_replay.py --seeds 1 --resolution 1280 --jpeg

The flights are the tests' (tests/missions/test_mcap_replay.py): MSS detector, the coarse
approach times out after 3 s (``--full``: the embedded mission's timeouts, a flight to DONE).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from eaglemission.commands.replay import replay
from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import FlightOptions, fly_sync
from eaglemission.recording.mcap_reader import log_records
from eaglemission.recording.options import RecordOptions


def config(seed: int, width_px: int, full: bool) -> MissionFile:
    data = load_config(check_plugins=False).model_dump(mode="json")
    data["detector"] = {"type": "mss", "params": {"downscale": 2}}
    data["world"]["params"]["seed"] = seed
    if not full:
        data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 3.0
    for cid in ("wide", "narrow"):
        data["cameras"][cid]["resolution_px"] = [width_px, width_px * 3 // 4]
    return MissionFile.model_validate(data)


def one(seed: int, width_px: int, full: bool, lossless: bool, folder: Path) -> str:
    path = folder / f"seed{seed}-{'png' if lossless else 'jpeg'}.mcap"
    t0 = time.perf_counter()
    res = fly_sync(config(seed, width_px, full), FlightOptions(record=RecordOptions(
        path, lossless=lossless)))
    t_rec = time.perf_counter() - t0
    records = list(log_records(path, ("setpoint", "state")))
    n_sp = sum(r["kind"] == "setpoint" for r in records)
    n_st = sum(r["kind"] == "state" for r in records)
    t1 = time.perf_counter()
    rep = replay(path)
    t_rep = time.perf_counter() - t1
    c = rep.comparison
    final = res.outcome.final_state if res.outcome is not None else res.error
    line = (f"seed {seed} ({'png' if lossless else 'jpeg'} frames, {width_px} px, {final}, "
            f"{res.sim_s:.1f} s flight, {path.stat().st_size / 1e6:.1f} MB): recorded "
            f"{n_sp} setpoints / {n_st} state changes, replayed {len(c.replayed['setpoint'])} / "
            f"{len(c.replayed['state'])}: {'IDENTICAL' if c.identical else 'DIVERGED'}; wall "
            f"{t_rec:.1f} s recording, {t_rep:.1f} s replay")
    if c.divergence is not None:
        line += "\n    " + "\n    ".join(c.divergence.lines())
    return line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--resolution", type=int, default=320, help="camera width, px (4:3)")
    ap.add_argument("--full", action="store_true", help="the embedded mission's timeouts")
    ap.add_argument("--jpeg", action="store_true", help="also record with JPEG frames")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in (int(s) for s in args.seeds.split(",")):
            for lossless in (True, False) if args.jpeg else (True,):
                print(one(seed, args.resolution, args.full, lossless, Path(tmp)), flush=True)


if __name__ == "__main__":
    main()
