"""Which imaging effect decides a campaign run (diagnostic, reads ground truth).

Flies run RUN of ``campaign CONFIG --seed SEED [--ground-images DIR]`` as the campaign draws it
(all its imaging effects), with none of them, and with each one switched off in turn, and
prints the evaluator's verdict of each flight. Usage::

    python benchmarks/diag_imaging.py [CONFIG] --seed 7 --run 13 [--ground-images DIR]
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
from eaglemission.lab.campaign.campaign import randomise
from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.lab.world.ground_images import ground_image_files

from eaglemission.config import MissionFile, load_config

OFF = {"jpeg": {"jpeg_quality": None}, "white_balance": {"white_balance_gains_bgr": (1, 1, 1)},
       "motion_blur": {"motion_blur": False}, "bayer": {"bayer_pattern": None}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("config", nargs="?")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--run", type=int, default=0)
    ap.add_argument("--ground-images", metavar="DIR")
    a = ap.parse_args()
    logging.disable(logging.WARNING)
    photos = ground_image_files(Path(a.ground_images)) if a.ground_images else None
    rng = np.random.RandomState(a.seed)
    seeds = [int(rng.randint(0, 2**31 - 1)) for _ in range(a.run + 1)]
    cfg = randomise(load_config(a.config), np.random.RandomState(seeds[a.run]), photos)
    assert cfg.world is not None
    drawn = {k: cfg.world.params[k] for k in ("white_balance_gains_bgr", "motion_blur",
                                              "bayer_pattern", "jpeg_quality")}
    print(f"run {a.run} of seed {a.seed}: {drawn}")
    variants: dict[str, dict[str, object]] = {"as drawn": {}, "none": {}}
    for name, update in OFF.items():
        variants["none"].update(update)
        variants[f"{name} off"] = update
    for name, update in variants.items():
        d = cfg.model_dump(mode="json")
        d["world"]["params"].update(update)
        ev = run_simulation(MissionFile.model_validate(d)).evaluation
        h = ev.horizontal_error_m
        print(f"  {name:18s} {'SUCCESS' if ev.success else 'FAILURE'}  horizontal "
              f"{'-' if h is None else f'{h * 100:.1f} cm'}  grasp distance "
              f"{ev.grasp_distance_m or float('nan'):.3f} m", flush=True)


if __name__ == "__main__":
    main()
