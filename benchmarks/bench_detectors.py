"""Per-frame CPU time of every detector, single thread, as ratios to OpenCV's spectral residual.

    python benchmarks/bench_detectors.py                      # speed, all loadable detectors
    python benchmarks/bench_detectors.py --detectors dtdmi,dtdmi@literal,sr --frames 40
    python benchmarks/bench_detectors.py --no-target          # false detections, empty scenes
    python benchmarks/bench_detectors.py --no-target --ground-images ../shared/data/aerial_ground/garfield_park
    python benchmarks/bench_detectors.py --detectors sr,dtdmi@aerial --target-image first-frame

Speed: every detector and the reference (``cv2.saliency.StaticSaliencySpectralResidual``,
called directly on the BGR frame) run *interleaved* on the same frames in the same process, so
machine load hits all of them alike; the figure is the CPU time of the calling thread
(``time.thread_time``, all libraries pinned to one thread) of ``detect()`` = map + regions, and
the ratio to SR's median is the stable number. Frames: real DAVIS 2016 frames (854x480, and
upscaled bilinearly to 1280x960) when ../shared exists, else generated textured frames.

No target (``--no-target``): detections per frame with each detector's config (default, or
``--params``) on target-free ground, a camera translating 4 px/frame (cruise) and hovering
(static + sensor noise), 854x480. Ground from the synthetic world's textures
(lab/world/textures.py) when importable, else generated value noise; ``--ground-images
DIR``: the real nadir photos in DIR at their own scale. The requirement: at most 0.05
detections per frame.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from eaglemission import registry  # noqa: E402
from eaglemission.commands.params import build_spec, parse_detector_specs  # noqa: E402
from eaglemission.errors import EagleMissionError  # noqa: E402
from eaglemission.types import Frame  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DAVIS = REPO.parent / "shared" / "data" / "video_saliency" / "DAVIS2016"
SIZES = ((1280, 960), (854, 480))


def single_thread() -> None:
    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass


def davis_frames(n: int) -> list[np.ndarray] | None:
    """``n`` consecutive frames of one DAVIS sequence (the detectors are stateful)."""
    folder = DAVIS / "dog" / "frames"
    if not folder.is_dir():
        return None
    files = sorted(folder.glob("*.jpg"))[:n]
    return [cv2.imread(str(f)) for f in files]


def generated_frames(n: int, w: int = 854, h: int = 480, seed: int = 0) -> list[np.ndarray]:
    """A textured scene panning 4 px/frame with a moving box (no ../shared)."""
    rng = np.random.RandomState(seed)
    tex = fbm_texture(h + 8 * n, w + 8 * n, rng)
    out = []
    for i in range(n):
        img = tex[2 * i:2 * i + h, 4 * i:4 * i + w].copy()
        cv2.rectangle(img, (200 + 6 * i, 200), (260 + 6 * i, 240), (40, 60, 200), -1)
        out.append(img)
    return out


def fbm_texture(h: int, w: int, rng: np.random.RandomState) -> np.ndarray:
    """Colour value noise (sum of octaves), a stand-in for ground texture."""
    acc = np.zeros((h, w, 3), np.float32)
    for cell, amp in ((64, 40.0), (16, 20.0), (4, 10.0)):
        small = rng.randn(h // cell + 2, w // cell + 2, 3).astype(np.float32)
        acc += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    base = np.array([60, 100, 80], np.float32)
    return np.clip(acc + base, 0, 255).astype(np.uint8)


def target_image(spec: str | None) -> np.ndarray | None:
    """``--target-image``: an image file, or ``first-frame`` (the bounding box of the first
    DAVIS 'dog' mask cropped from its frame)."""
    if spec is None:
        return None
    if spec != "first-frame":
        img = cv2.imread(spec)
        if img is None:
            raise EagleMissionError(f"--target-image {spec!r}: not an image file")
        return img
    from eaglemission.lab.bench.boxes import box_from_mask, crop_box

    frame = DAVIS / "dog" / "frames" / "00000.jpg"
    mask = cv2.imread(str(DAVIS / "dog" / "gt" / "00000.png"), cv2.IMREAD_GRAYSCALE)
    img = cv2.imread(str(frame))
    if img is None or mask is None:
        raise EagleMissionError("--target-image first-frame: DAVIS 'dog' frame 0 and its mask "
                                "not found (../shared absent?); give an image file")
    return crop_box(img, box_from_mask(mask >= 128))


def load_detectors(spec_text: str | None, params: list[str],
                   appearance: np.ndarray | None = None) -> list[tuple[str, object]]:
    """The detectors of ``--detectors`` (labels ending in ``+appearance`` followed by the
    appearance prior with ``appearance`` as the example image), default every loadable one."""
    if spec_text is None:
        names = sorted(registry.available("detectors"))
        out = []
        for name in names:
            try:
                out.append((name, registry.load("detectors", name)))
            except EagleMissionError as exc:
                print(f"# skipped {name}: {exc}", file=sys.stderr)
        return out
    return [(s.label, build_spec(s, appearance))
            for s in parse_detector_specs(spec_text, params)]


def time_speed(frames: list[np.ndarray], dets: list[tuple[str, object]], size: tuple[int, int],
               repeat: int) -> dict[str, list[float]]:
    w, h = size
    imgs = [f if f.shape[:2] == (h, w) else cv2.resize(f, (w, h), interpolation=cv2.INTER_LINEAR)
            for f in frames]
    sr = cv2.saliency.StaticSaliencySpectralResidual_create()
    times: dict[str, list[float]] = {"SR (cv2, reference)": []}
    times.update({label: [] for label, _ in dets})
    for _, d in dets:
        d.reset()  # type: ignore[attr-defined]
    for r in range(repeat):
        for i, img in enumerate(imgs):
            frame = Frame(img, 1_000_000_000 + (r * len(imgs) + i) * 41_666_667, "wide", i)
            t = time.thread_time()
            sr.computeSaliency(img)
            times["SR (cv2, reference)"].append(time.thread_time() - t)
            for label, d in dets:
                t = time.thread_time()
                d.detect(frame)  # type: ignore[attr-defined]
                times[label].append(time.thread_time() - t)
    warm = 3  # first frames: allocation, JIT, caches
    return {k: v[warm:] for k, v in times.items()}


def speed(args: argparse.Namespace) -> int:
    frames = davis_frames(args.frames)
    source = f"DAVIS 2016 'dog', {len(frames)} frames" if frames else None
    if frames is None:
        frames = generated_frames(args.frames)
        source = f"generated textured frames ({len(frames)})"
    dets = load_detectors(args.detectors, args.params, target_image(args.target_image))
    print(f"# per-frame CPU time of detect() (one thread), {source}, x{args.repeat}; "
          f"ratios to cv2 SR timed on the same frames in the same run"
          + (f"; every detector given the target image {args.target_image}"
             if args.target_image else ""))
    for size in SIZES:
        t = time_speed(frames, dets, size, args.repeat)
        ref = float(np.median(t["SR (cv2, reference)"]))
        print(f"\n## {size[0]}x{size[1]}\n")
        print("| detector | median ms | p90 ms | median x SR | p90 x SR | fps (median) |")
        print("|---|---|---|---|---|---|")
        for label, v in t.items():
            med, p90 = float(np.median(v)), float(np.percentile(v, 90))
            print(f"| {label} | {1e3 * med:.2f} | {1e3 * p90:.2f} | {med / ref:.2f} | "
                  f"{p90 / ref:.2f} | {1 / med:.0f} |")
    return 0


def ground_images() -> tuple[str, dict[str, np.ndarray]]:
    try:
        from eaglemission.lab.world.textures import KINDS, base_texture

        return "synthetic-world textures (lab/world/textures.py), 2 cm/texel", {
            k: base_texture(k, 1400, 0.02, 7) for k in KINDS}
    except Exception as exc:  # the camera helper's module may be absent or changed
        print(f"# world textures unavailable ({exc}); using generated value noise",
              file=sys.stderr)
        rng = np.random.RandomState(7)
        return "generated value noise", {f"noise{i}": fbm_texture(1400, 1400, rng)
                                         for i in range(4)}


def target_free_sequence(tex: np.ndarray, n: int, step_px: float, rng: np.random.RandomState,
                         w: int = 854, h: int = 480) -> list[np.ndarray]:
    out = []
    for i in range(n):
        m = np.float32([[1, 0, -(50 + step_px * i)], [0, 1, -(60 + 0.5 * step_px * i)]])
        img = cv2.warpAffine(tex, m, (w, h), flags=cv2.INTER_LINEAR)
        out.append(np.clip(img + rng.randn(h, w, 3) * 2.0, 0, 255).astype(np.uint8))
    return out


TARGET_BGR = (30, 40, 210)  # configs/sitl_synthetic.yaml's box
TARGET_TEX_BOX = (500, 300, 20, 12)  # u, v, w, h in texture pixels (0.40 x 0.25 m at 2 cm)


def with_target(tex: np.ndarray) -> np.ndarray:
    u, v, w, h = TARGET_TEX_BOX
    out = tex.copy()
    out[v:v + h, u:u + w] = TARGET_BGR
    return out


def target_centre(i: int, step_px: float) -> tuple[float, float]:
    u, v, w, h = TARGET_TEX_BOX
    return (u + (w - 1) / 2 - (50 + step_px * i), v + (h - 1) / 2 - (60 + 0.5 * step_px * i))


def photo_grounds(folder: Path) -> tuple[str, dict[str, np.ndarray]]:
    """``--ground-images DIR``: the real nadir photos ``DIR/NAME.jpg|png`` at their own scale
    (34-73 mm per pixel in ../shared/data/aerial_ground), nothing composited on them."""
    photos = {}
    for path in sorted(folder.glob("*")):
        if path.suffix.lower() in (".jpg", ".jpeg", ".png"):
            img = cv2.imread(str(path))
            if img is None:
                raise EagleMissionError(f"--ground-images: {path}: not an image file")
            photos[path.stem] = img
    if not photos:
        raise EagleMissionError(f"--ground-images {folder}: no NAME.jpg|png in it")
    return f"real aerial photos of {folder} at their own scale", photos


def no_target(args: argparse.Namespace) -> int:
    source, textures = (photo_grounds(Path(args.ground_images)) if args.ground_images
                        else ground_images())
    dets = load_detectors(args.detectors, args.params, target_image(args.target_image))
    motions = (("cruise", 4.0), ("hover", 0.0))
    rng = np.random.RandomState(11)
    seqs = {f"{kind}/{motion}": target_free_sequence(tex, args.frames, step, rng)
            for kind, tex in textures.items() for motion, step in motions}
    rng = np.random.RandomState(12)
    with_t = {f"{kind}/{motion}": (step, target_free_sequence(with_target(tex), args.frames,
                                                              step, rng))
              for kind, tex in textures.items() for motion, step in motions}
    n_frames = sum(len(s) for s in seqs.values())
    print(f"# detections per target-free frame, {source}; "
          f"{len(seqs)} sequences x {args.frames} frames = {n_frames} frames at 854x480 "
          f"(cruise: 4 px/frame pan; hover: static + noise); target <= 0.05. Last column: the "
          f"same sequences with a world-fixed 20 x 12 px box of BGR {TARGET_BGR} pasted on the "
          f"ground, fraction of frames whose best detection is within 10 px of its centre")
    print("\n| detector | detections/frame | frames with >= 1 | worst sequence | "
          "box found (best det.) |")
    print("|---|---|---|---|---|")
    for label, d in dets:
        total = hit = found = 0
        worst = (0.0, "-")
        for name, frames in seqs.items():
            d.reset()  # type: ignore[attr-defined]
            n_det = 0
            for i, img in enumerate(frames):
                res = d.detect(Frame(img, 1_000_000_000 + i * 41_666_667, "wide", i))  # type: ignore[attr-defined]
                n_det += len(res.detections)
                hit += bool(res.detections)
            total += n_det
            worst = max(worst, (n_det / len(frames), name))
        for step, frames in with_t.values():
            d.reset()  # type: ignore[attr-defined]
            for i, img in enumerate(frames):
                res = d.detect(Frame(img, 1_000_000_000 + i * 41_666_667, "wide", i))  # type: ignore[attr-defined]
                if res.best is not None:
                    cu, cv_ = target_centre(i, step)
                    found += np.hypot(res.best.center_px[0] - cu, res.best.center_px[1] - cv_) < 10
        print(f"| {label} | {total / n_frames:.3f} | {hit}/{n_frames} | "
              f"{worst[1]} ({worst[0]:.2f}) | {found}/{n_frames} |")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--detectors", default=None,
                   help="comma-separated (NAME or NAME@preset); default: every loadable one")
    p.add_argument("--params", nargs="*", default=[], metavar="DETECTOR:KEY=VALUE",
                   help="as for `eaglemission bench` (needs --detectors)")
    p.add_argument("--frames", type=int, default=30, help="frames per run / per sequence")
    p.add_argument("--repeat", type=int, default=1, help="passes over the frames (speed)")
    p.add_argument("--no-target", action="store_true", help="false detections on empty ground")
    p.add_argument("--target-image", default=None, metavar="PATH|first-frame",
                   help="the example image of the target for the detectors labelled "
                        "NAME+appearance (the appearance prior after the detector); first-frame: "
                        "the first DAVIS 'dog' mask's box")
    p.add_argument("--ground-images", default=None, metavar="DIR",
                   help="--no-target: pan and hover over the real photos DIR/NAME.jpg|png "
                        "instead of the synthetic world's textures")
    args = p.parse_args(argv)
    single_thread()
    try:
        return no_target(args) if args.no_target else speed(args)
    except EagleMissionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
