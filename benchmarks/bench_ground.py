"""False detections on real target-free ground: aerial photographs cropped at camera-like scales.

    python benchmarks/bench_ground.py                                 # the mission's detector, SR
    python benchmarks/bench_ground.py --detectors dtdmi@field,dtdmi@aerial,sr --per-photo
    python benchmarks/bench_ground.py --scales-mm 9 18 36 --crops 3 --frames 4

Ground: every ``NAME.jpg`` of ``../shared/data/aerial_ground/<site>/`` with its ``NAME.yaml``
(``m_per_px``). Each photo is resampled (bicubic) to each ground sampling distance of
``--scales-mm`` -- by default 9, 18 and 36 mm per pixel: what the wide camera of
configs/sitl_synthetic.yaml (2.8 mm lens, 3.75 um pixels, 30 deg down at 5 m) sees near the
bottom of its image (~8 mm), at its centre (13 mm across, 27 mm along) and towards the horizon
(>= 36 mm). The photos are 34-73 mm per pixel, so the finer scales are *upsampled* (no detail is
added: smoother than a real camera at that scale; ``--scales-mm 34 73`` keeps their own detail).
At every scale ``--crops`` windows of ``--size`` (1280x960, the camera's) are taken at seeded
random positions, and each window is a short pan of ``--frames`` frames (4 px per frame, sensor
noise sigma 2), so that detectors with temporal state see motion; every detector is reset per
window. Nothing is composited: every detection is false. The requirement: at most 0.05 false
detections per frame.

Detectors are given as for ``eaglemission bench`` (``NAME``, ``NAME@preset``, ``--params``);
by default the mission's (configs/sitl_synthetic.yaml's detector, at the runner's
``detector_downscale`` 2, with the mission's ``target.appearance_image`` unless ``--target-image``
is given) and SR. Photos are the ground the mission's simulated world
may use, so the two sites are reported separately: tune on one, test on the other.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from eaglemission import registry  # noqa: E402
from eaglemission.commands.params import parse_detector_specs  # noqa: E402
from eaglemission.errors import EagleMissionError  # noqa: E402
from eaglemission.types import Frame  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
GROUND = REPO.parent / "shared" / "data" / "aerial_ground"
DEFAULT_DETECTORS = "mission,sr"
PAN_PX = 4.0


@dataclass(frozen=True)
class Photo:
    site: str
    name: str
    path: Path
    m_per_px: float


def find_photos(root: Path) -> list[Photo]:
    """Every ``<site>/NAME.jpg|png`` with a ``NAME.yaml`` holding ``m_per_px``."""
    out = []
    for img in sorted(root.glob("*/*")):
        if img.suffix.lower() not in (".jpg", ".jpeg", ".png"):
            continue
        side = img.with_suffix(".yaml")
        if not side.is_file():
            continue
        m = float(yaml.safe_load(side.read_text())["m_per_px"])
        out.append(Photo(img.parent.name, img.stem, img, m))
    return out


def pan_window(photo: np.ndarray, factor: float, x0: float, y0: float, size: tuple[int, int],
               frames: int, rng: np.random.RandomState) -> list[np.ndarray]:
    """``frames`` views of the photo resampled by ``factor`` (destination px per photo px), the
    window's top-left at photo pixel (x0, y0), panning ``PAN_PX`` destination px per frame."""
    w, h = size
    interp = cv2.INTER_CUBIC if factor >= 1 else cv2.INTER_AREA
    out = []
    for i in range(frames):
        dx = x0 + i * PAN_PX / factor
        dy = y0 + 0.5 * i * PAN_PX / factor
        if factor >= 1:
            m = np.float32([[factor, 0, -dx * factor], [0, factor, -dy * factor]])
            img = cv2.warpAffine(photo, m, (w, h), flags=interp, borderMode=cv2.BORDER_REFLECT)
        else:
            src = photo[int(dy):int(dy + h / factor) + 1, int(dx):int(dx + w / factor) + 1]
            img = cv2.resize(src, (w, h), interpolation=interp)
        noisy = img.astype(np.float32) + rng.randn(h, w, 3).astype(np.float32) * 2.0
        out.append(np.clip(noisy, 0, 255).astype(np.uint8))
    return out


def mission_detector_spec() -> tuple[str, str, dict]:
    """(label, plugin, params) of configs/sitl_synthetic.yaml's detector at the runner's
    default ``detector_downscale`` (2)."""
    from eaglemission.config import load_config

    cfg = load_config(check_plugins=False)
    params = dict(cfg.detector.params)
    cls = registry.get("detectors", cfg.detector.type)
    if "downscale" in getattr(cls.Config, "model_fields", {}) and "downscale" not in params:
        params["downscale"] = 2
    return "mission", cfg.detector.type, params


def mission_context() -> dict[str, np.ndarray]:
    """The mission's detector context: its ``target.appearance_image``, when it has one."""
    from eaglemission.config import load_config
    from eaglemission.flight.assembly import load_appearance_image

    img = load_appearance_image(load_config(check_plugins=False))
    return {} if img is None else {"appearance": img}


def load_detectors(spec_text: str, params: list[str]) -> list[tuple[str, str, dict]]:
    names = [s.strip() for s in spec_text.split(",") if s.strip()]
    out = []
    rest = [n for n in names if n != "mission"]
    specs = {s.label: s for s in parse_detector_specs(",".join(rest), params)} if rest else {}
    for n in names:
        if n == "mission":
            out.append(mission_detector_spec())
        else:
            s = specs[n]
            out.append((s.label, s.name, s.params))
    return out


def target_image(spec: str) -> np.ndarray:
    """``--target-image``: an image file, or ``colour``: a patch of the mission's target colour."""
    if spec == "colour":
        from eaglemission.config import load_config

        bgr = load_config(check_plugins=False).target.color_bgr
        if bgr is None:
            raise SystemExit("error: configs/sitl_synthetic.yaml has no target.color_bgr")
        return np.full((24, 40, 3), bgr, np.uint8)
    img = cv2.imread(spec)
    if img is None:
        raise SystemExit(f"error: --target-image {spec}: not an image")
    return img


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--data", type=Path, default=GROUND)
    p.add_argument("--detectors", default=DEFAULT_DETECTORS,
                   help="comma-separated NAME or NAME@preset; `mission` = the mission's detector")
    p.add_argument("--params", nargs="*", default=[], metavar="DETECTOR:KEY=VALUE")
    p.add_argument("--scales-mm", type=float, nargs="*", default=[9.0, 18.0, 36.0],
                   help="ground sampling distances of the crops, mm per pixel")
    p.add_argument("--crops", type=int, default=3, help="windows per photo and scale")
    p.add_argument("--frames", type=int, default=4, help="frames per window (a short pan)")
    p.add_argument("--size", default="1280x960", help="crop size WxH (the camera's)")
    p.add_argument("--sites", nargs="*", default=None, help="only these site folders")
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--per-photo", action="store_true", help="also print each photo's figures")
    p.add_argument("--target-image", default=None, metavar="PATH|colour",
                   help="give the detectors an example image of the target (context "
                        "`appearance`): an image file, or `colour` = a 24 x 40 px patch of "
                        "configs/sitl_synthetic.yaml's target.color_bgr")
    a = p.parse_args(argv)
    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass
    if not a.data.is_dir():
        print(f"error: {a.data}: no aerial_ground folder (../shared absent?)", file=sys.stderr)
        return 2
    photos = [ph for ph in find_photos(a.data) if a.sites is None or ph.site in a.sites]
    if not photos:
        print(f"error: no NAME.jpg + NAME.yaml photos under {a.data}", file=sys.stderr)
        return 2
    w, h = (int(v) for v in a.size.lower().split("x"))
    context = {}
    if a.target_image is not None:
        context["appearance"] = target_image(a.target_image)
    try:
        dets = [(label, registry.load("detectors", name, prm,
                                      **(mission_context() if label == "mission"
                                         and not context else context)))
                for label, name, prm in load_detectors(a.detectors, a.params)]
    except EagleMissionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    # counts[label][(site, scale)] = [frames, detections, frames with any]
    counts: dict[str, dict[tuple[str, float], list[int]]] = {
        label: defaultdict(lambda: [0, 0, 0]) for label, _ in dets}
    per_photo: dict[str, dict[str, list[int]]] = {label: defaultdict(lambda: [0, 0, 0])
                                                  for label, _ in dets}
    worst: dict[str, tuple[float, str]] = {label: (0.0, "-") for label, _ in dets}
    rng = np.random.RandomState(a.seed)
    t0 = time.perf_counter()
    n_frames = 0
    for ph in photos:
        img = cv2.imread(str(ph.path))
        ih, iw = img.shape[:2]
        for mm in a.scales_mm:
            factor = ph.m_per_px / (mm / 1000.0)
            span_w = (w + a.frames * PAN_PX) / factor
            span_h = (h + a.frames * PAN_PX) / factor
            if span_w > iw or span_h > ih:
                continue  # the photo is too small for this scale
            for c in range(a.crops):
                x0 = rng.uniform(0, iw - span_w)
                y0 = rng.uniform(0, ih - span_h)
                frames = pan_window(img, factor, x0, y0, (w, h), a.frames, rng)
                n_frames += len(frames)
                for label, d in dets:
                    d.reset()
                    n_det = n_any = 0
                    for i, f in enumerate(frames):
                        res = d.detect(Frame(f, 1_000_000_000 + i * 33_333_333, "wide", i))
                        n_det += len(res.detections)
                        n_any += bool(res.detections)
                    for tally in (counts[label][(ph.site, mm)], per_photo[label][ph.name]):
                        tally[0] += len(frames)
                        tally[1] += n_det
                        tally[2] += n_any
                    rate = n_det / len(frames)
                    if rate > worst[label][0]:
                        worst[label] = (rate, f"{ph.name} at {mm:g} mm, crop {c}")
    sites = sorted({ph.site for ph in photos})
    print(f"# false detections per frame on target-free real ground "
          f"({len(photos)} photos, {', '.join(sites)}; {n_frames} frames of {w}x{h} per "
          f"detector: {a.crops} crops x {a.frames} frames per photo and scale, scales "
          f"{', '.join(f'{s:g}' for s in a.scales_mm)} mm/px; {time.perf_counter() - t0:.0f} s). "
          f"Target: <= 0.05")
    cols = [(s, mm) for s in sites for mm in a.scales_mm]
    print("\n| detector | all: false / frame | frames with >= 1 | "
          + " | ".join(f"{s} {mm:g} mm" for s, mm in cols) + " | worst window |")
    print("|---|---|---|" + "---|" * len(cols) + "---|")
    for label, _ in dets:
        tot = np.sum([v for v in counts[label].values()], axis=0) if counts[label] else [0, 0, 0]
        cells = []
        for key in cols:
            f, n, _any = counts[label].get(key, [0, 0, 0])
            cells.append(f"{n / f:.3f}" if f else "-")
        print(f"| {label} | {tot[1] / max(tot[0], 1):.3f} | {tot[2]}/{tot[0]} | "
              + " | ".join(cells) + f" | {worst[label][1]} ({worst[label][0]:.2f}) |")
    for site in sites:
        print(f"\n{site}: " + ", ".join(
            f"{label} {sum(v[1] for k, v in counts[label].items() if k[0] == site) / max(1, sum(v[0] for k, v in counts[label].items() if k[0] == site)):.3f}"
            for label, _ in dets))
    if a.per_photo:
        print("\n| photo | " + " | ".join(label for label, _ in dets) + " |")
        print("|---|" + "---|" * len(dets))
        for ph in photos:
            cells = []
            for label, _ in dets:
                f, n, _any = per_photo[label][ph.name]
                cells.append(f"{n / max(f, 1):.3f}")
            print(f"| {ph.site}/{ph.name} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
