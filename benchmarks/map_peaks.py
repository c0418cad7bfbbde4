"""Can an absolute floor under the adaptive threshold tell "no target" on real ground?

Prints the per-frame peak (0..255) of a detector's map on the target-free real photos
(``../shared/data/aerial_ground``, panned and hovered as ``bench_detectors.py --no-target
--ground-images``) and on the real UAV sequences' frames whose best detection is on the target
(centre inside the box grown 25 % a side; the first 10 % of each sequence's frames not scored),
then, per candidate floor, how many of each would pass it::

    python benchmarks/map_peaks.py                      # dtdmi aerial, downscale 2
    python benchmarks/map_peaks.py --target-image       # + configs/targets/red_box.jpg on the
                                                        #   photos, each sequence's first-frame crop
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_detectors as bench  # noqa: E402
from eaglemission.lab.bench.data import find_sequences, first_frame_crop  # noqa: E402

from eaglemission import registry  # noqa: E402
from eaglemission.types import Frame  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
FLOORS = (20, 30, 40, 50, 60, 80, 100, 120)


def detector(params: dict[str, object], appearance: np.ndarray | None) -> object:
    ctx = {} if appearance is None else {"appearance": appearance}
    return registry.load("detectors", "dtdmi", params, **ctx)


def photo_peaks(site: Path, params: dict[str, object], appearance: np.ndarray | None,
                frames: int) -> list[float]:
    _, photos = bench.photo_grounds(site)
    peaks = []
    for photo in photos.values():
        for step in (4.0, 0.0):  # cruise pan, hover
            d = detector(params, appearance)
            seq = bench.target_free_sequence(photo, frames, step, np.random.RandomState(1))
            for i, img in enumerate(seq):
                r = d.detect(Frame(img, 10**9 + i * 41_666_667, "wide", i))  # type: ignore[attr-defined]
                peaks.append(float(r.saliency.max()) * 255)
    return peaks


def on_target(best_center: tuple[float, float], box: np.ndarray) -> bool:
    x0, y0, x1, y1 = box
    gx, gy = 0.25 * (x1 - x0), 0.25 * (y1 - y0)
    cx, cy = best_center
    return bool(x0 - gx <= cx <= x1 + gx and y0 - gy <= cy <= y1 + gy)


def uav_peaks(params: dict[str, object], with_image: bool) -> tuple[list[float], int]:
    """Peaks of the frames whose best detection is on the target, and the frames scored."""
    hits, scored = [], 0
    for seq in find_sequences(SHARED / "uav_tracking"):
        appearance = first_frame_crop(seq)[1] if with_image else None
        d = detector(params, appearance)
        for i, path in enumerate(seq.frames):
            img = cv2.imread(str(path))
            r = d.detect(Frame(img, 10**9 + i * 100_000_000, "wide", i))  # type: ignore[attr-defined]
            if i < len(seq.frames) // 10:
                continue
            scored += 1
            box = seq.boxes[i] if seq.boxes is not None else None
            if r.best is not None and box is not None and np.all(np.isfinite(box)) \
                    and on_target(r.best.center_px, box):
                hits.append(float(r.saliency.max()) * 255)
    return hits, scored


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="aerial")
    ap.add_argument("--downscale", type=int, default=2)
    ap.add_argument("--frames", type=int, default=20, help="frames per photo and motion")
    ap.add_argument("--target-image", action="store_true")
    args = ap.parse_args(argv)
    if not (SHARED / "aerial_ground").exists():
        print(f"{SHARED}: not found (../shared absent)", file=sys.stderr)
        return 2
    bench.single_thread()
    params: dict[str, object] = {"preset": args.preset, "downscale": args.downscale}
    image = cv2.imread(str(REPO / "configs" / "targets" / "red_box.jpg")) \
        if args.target_image else None
    photos = {site.name: photo_peaks(site, params, image, args.frames)
              for site in sorted((SHARED / "aerial_ground").iterdir()) if site.is_dir()}
    hits, scored = uav_peaks(params, args.target_image)
    print(f"# dtdmi {params}{' + target image' if args.target_image else ''}: per-frame map "
          f"peak on 0..255 (quantiles p0/p5/p50/p95/p100)")
    for name, peaks in photos.items():
        print(f"{name} (target-free, {len(peaks)} frames): "
              f"{np.percentile(peaks, [0, 5, 50, 95, 100]).round(1).tolist()}")
    if hits:
        print(f"UAV frames with the best detection on the target ({len(hits)} of {scored}): "
              f"{np.percentile(hits, [0, 5, 50, 95, 100]).round(1).tolist()}")
    print("\n| floor | UAV on-target frames kept | " +
          " | ".join(f"{n} frames passing" for n in photos) + " |")
    print("|---|---|" + "---|" * len(photos))
    for floor in FLOORS:
        row = " | ".join(f"{sum(p >= floor for p in v)}/{len(v)}" for v in photos.values())
        print(f"| {floor} | {sum(p >= floor for p in hits)}/{len(hits)} | {row} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
