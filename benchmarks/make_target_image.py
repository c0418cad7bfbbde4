"""The simulated target's example image (``target.appearance_image``), as a field team would
take one: a tight crop of the target in a frame of the mission's own narrow camera, here
rendered by the synthetic world of a mission file (its target, its default light).

    python benchmarks/make_target_image.py configs/sitl_synthetic.yaml \
        --out configs/targets/red_box.jpg

The view: 2.0 m from the target's top-face centre, 40 deg below the horizon, from the
south-west, so the top and two shaded sides show (what a tilted camera sees in the approach).
The crop is the target's projected outline's bounding box grown by ``--margin`` of its size.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import world_config

from eaglemission.config import load_config
from eaglemission.geometry import euler_to_quat


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", help="mission YAML (default: the embedded one)")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--range-m", type=float, default=2.0)
    ap.add_argument("--depression-deg", type=float, default=40.0)
    ap.add_argument("--azimuth-deg", type=float, default=45.0)
    ap.add_argument("--margin", type=float, default=0.05)
    ap.add_argument("--max-side-px", type=int, default=256, help="shrink the crop to this")
    a = ap.parse_args()
    cfg = load_config(a.config, check_plugins=False)
    sim = world_config(cfg)
    if sim is None:
        print("error: the mission file has no synthetic world", file=sys.stderr)
        return 2
    world = SyntheticWorld(sim, cfg.target, seed=sim.seed, extent_m=40.0)
    model = cfg.cameras.narrow.to_model("narrow")
    top = np.asarray(world.target_position_ned_m, dtype=np.float64)
    dep, az = math.radians(a.depression_deg), math.radians(a.azimuth_deg)
    cam = top + a.range_m * np.array([-math.cos(dep) * math.cos(az),
                                      -math.cos(dep) * math.sin(az), -math.sin(dep)])
    # the narrow camera is pitched down by its mount: level the body, point it at the target
    pitch_mount = -cfg.cameras.narrow.mount.pitch_deg
    q = euler_to_quat(0.0, pitch_mount - a.depression_deg, a.azimuth_deg)
    pos = cam - np.asarray(cfg.cameras.narrow.mount.lever_arm_m)
    img, truth = world.render(model, pos, q, 10**9)
    poly = np.asarray(truth.target_polygon_px, dtype=np.float64)
    if not truth.target_visible or len(poly) < 3:
        print("error: the target is not in view from that pose", file=sys.stderr)
        return 1
    x0, y0 = poly.min(axis=0)
    x1, y1 = poly.max(axis=0)
    mx, my = a.margin * (x1 - x0), a.margin * (y1 - y0)
    h, w = img.shape[:2]
    c0, r0 = max(0, int(x0 - mx)), max(0, int(y0 - my))
    c1, r1 = min(w, int(math.ceil(x1 + mx)) + 1), min(h, int(math.ceil(y1 + my)) + 1)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    crop = img[r0:r1, c0:c1]
    k = a.max_side_px / max(crop.shape[:2])
    if k < 1:
        crop = cv2.resize(crop, None, fx=k, fy=k, interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(out), crop)
    print(f"wrote {out}: {crop.shape[1]} x {crop.shape[0]} px, the target from {a.range_m:g} m at "
          f"{a.depression_deg:g} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
