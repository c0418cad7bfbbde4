"""Detail at the camera's scale on photo ground: the scale-free contrast per pixel (mean
luminance gradient / mean luminance, :func:`gradient_energy`) of rendered frames near the target
divided by the photo's own at native scale, with and without the detail layer; and the render
time per frame of photo ground vs the procedural texture.

Usage::

    python benchmarks/bench_ground_detail.py IMAGE.jpg [--frames 20]

IMAGE needs its ``NAME.yaml`` (``m_per_px``), as in ``../shared/data/aerial_ground``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
from eaglemission.lab.world.ground_images import read_photo
from eaglemission.lab.world.photo_ground import gradient_energy
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import GroundImageConfig, SyntheticWorldConfig

from eaglemission.config import TargetConfig
from eaglemission.geometry import CameraModel, CameraMount, euler_to_quat

CAMERAS = {"wide": 2.8, "narrow": 12.0}
GROUND_M_PER_PX = {"wide": 0.008, "narrow": 0.002}  # near the target


def frames(world: SyntheticWorld, cid: str, n: int) -> tuple[list[np.ndarray], float]:
    model = CameraModel.from_lens(cid, focal_length_mm=CAMERAS[cid],
                                  mount=CameraMount(0.0, -90.0, 0.0, (0.0, 0.0, 0.0)))
    rng = np.random.RandomState(1)
    out, dt = [], []
    for k in range(n):
        height_m = GROUND_M_PER_PX[cid] * float(model.K[0, 0])  # nadir: m/px = height / f
        pos = (rng.uniform(-20, 20), rng.uniform(-20, 20), -height_m)
        t = time.perf_counter()
        img, _ = world.render(model, pos, euler_to_quat(0.0, 0.0, 0.0), 1_000_000_000 + k)
        dt.append(time.perf_counter() - t)
        out.append(img)
    return out, float(np.median(dt))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("image")
    ap.add_argument("--frames", type=int, default=20)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    target = TargetConfig(length_m=0.4, width_m=0.25, height_m=0.15)
    native = gradient_energy(read_photo(Path(args.image)))
    print(f"photo {args.image}: contrast per pixel at native scale {native:.4f}")
    for detail in (False, True):
        gi = GroundImageConfig(path=args.image, detail=detail)
        sim = SyntheticWorldConfig(ground_image=gi, noise_sigma=0.0, target_north_m=200.0)
        world = SyntheticWorld(sim, target, extent_m=120.0)
        for cid in CAMERAS:
            imgs, med = frames(world, cid, args.frames)
            e = float(np.mean([gradient_energy(i) for i in imgs]))
            print(f"detail={detail!s:5} {cid:6}: contrast per pixel {e:.4f}, ratio to photo "
                  f"{e / native:.2f}, render {med * 1e3:.1f} ms/frame")
    sim = SyntheticWorldConfig(noise_sigma=0.0, target_north_m=200.0)
    world = SyntheticWorld(sim, target, extent_m=120.0)
    for cid in CAMERAS:
        imgs, med = frames(world, cid, args.frames)
        e = float(np.mean([gradient_energy(i) for i in imgs]))
        print(f"procedural {cid:6}: contrast per pixel {e:.4f}, render {med * 1e3:.1f} ms/frame")


if __name__ == "__main__":
    main()
