"""Fault campaign figures: ``--faults all`` over N simulated runs in virtual time.

Prints the per-fault table (runs, end states, runs in their expected outcome, time to the safe
state, true envelope violations, complete logs), the share of tolerable faults completed and
the failures; exits 1 when a run missed its expected outcome. The full figure is 1,000 runs:

    python benchmarks/fault_campaign.py --runs 1000 --workers 2 --binning 2
    python benchmarks/fault_campaign.py --runs 100 --workers 2 --seed 3 --binning 2 \
        --manipulator simulated_arm
    python benchmarks/fault_campaign.py --runs 50 --workers 2 --binning 2 --vehicle emulator \
        --faults link_loss,link_delay,link_duplicate,link_reorder,autopilot_clock_jump

(``--fast``: the MSS detector at 1/2 resolution, as the closed-loop tests fly. ``--binning 2``:
both cameras binned 2x2 as the daA1280-54uc can be, 640x480 with 7.5 um pixels, the same field of
view; the detector's ``downscale`` is divided by the binning so its maps keep their size.)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import yaml
from eaglemission.lab.campaign.campaign import print_summary, run_campaign
from eaglemission.lab.campaign.emulator import EMULATOR_KINDS, emulator_kinds
from eaglemission.lab.campaign.faults import parse_kinds, print_fault_table

from eaglemission.config import load_config


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", help="mission YAML (default: the embedded one)")
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--faults", default="all")
    ap.add_argument("--fast", action="store_true", help="MSS detector at 1/2 resolution")
    ap.add_argument("--binning", type=int, default=1, choices=(1, 2, 4),
                    help="bin both cameras NxN (same field of view, N x the pixel size)")
    ap.add_argument("--vehicle", choices=("simulated", "emulator"), default="simulated",
                    help="emulator: each run in real time through MAVSDK against its own "
                    "sitl-vehicle process, link faults on its UDP path")
    ap.add_argument("--out", help="keep the run logs and summary.json here")
    ap.add_argument("--only-faults", metavar="KINDS",
                    help="of the same draws, fly only the runs whose fault is one of these "
                    "(comma-separated): after a change to those faults' path")
    ap.add_argument("--manipulator", metavar="TYPE",
                    help="fly every run with this manipulator (e.g. simulated_arm)")
    ap.add_argument("--no-imaging-effects", action="store_true",
                    help="keep the mission file's white balance, motion blur, Bayer and JPEG "
                    "(the worlds of the fault campaigns flown before they were drawn)")
    a = ap.parse_args()
    config = a.config
    if a.fast or a.binning > 1:
        d = load_config(config, check_plugins=False).model_dump(mode="json")
        if a.fast:
            d["detector"] = {"type": "mss", "params": {"downscale": 2}, "per_camera": {}}
        for cam in d["cameras"].values():
            w, h = cam["resolution_px"]
            cam["resolution_px"] = [w // a.binning, h // a.binning]
            cam["pixel_size_um"] *= a.binning
        params = d["detector"]["params"]
        params["downscale"] = max(1, int(params.get("downscale", 1)) // a.binning)
        tmp = Path(tempfile.mkdtemp()) / "campaign.yaml"
        tmp.write_text(yaml.safe_dump(d))
        config = str(tmp)
        print(f"config: {tmp} (detector {d['detector']['type']} {params}, cameras "
              f"{[c['resolution_px'] for c in d['cameras'].values()]})")
    kinds = parse_kinds(a.faults)
    if a.vehicle == "emulator":
        kinds = list(EMULATOR_KINDS) if a.faults.strip() == "all" else emulator_kinds(kinds)
    t0 = time.perf_counter()
    summary = run_campaign(config, runs=a.runs, seed=a.seed, workers=a.workers,
                           out_dir=a.out, progress=True, faults=kinds, vehicle=a.vehicle,
                           only_faults=None if a.only_faults is None
                           else set(parse_kinds(a.only_faults)),
                           imaging_effects=not a.no_imaging_effects,
                           manipulator=a.manipulator)
    wall = time.perf_counter() - t0
    print_summary(summary)
    failed = print_fault_table(summary.runs)
    flown = len(summary.runs)
    print(f"{flown} of {a.runs} runs, seed {a.seed}, {a.workers} worker(s), {wall:.0f} s wall "
          f"({wall / max(flown, 1):.1f} s per run)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
