"""``eaglemission detect``: a video or an image folder through the mission's perception, or one
detector, with overlay images (:mod:`eaglemission.perception.overlay`: saliency where salient
with its colour bar and threshold, region outlines, ranked MBRs with their corner order, the kept
target's box) and ``detections.jsonl``.

With ``--config MISSION`` (a mission file) it runs exactly what the mission runs on a camera
(:mod:`.footage`: detect, acquire and keep, choose the target), and each line of
``detections.jsonl`` gives the target's box in that frame (null until the target is confirmed)
and the boxes best first, the target's first. With ``--detector NAME`` it runs that detector
alone. See docs/detectors.md."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np
from eaglemission.missions.footage import FootageOptions, FootagePerception
from numpy.typing import NDArray

from eaglemission import registry
from eaglemission.commands import Command
from eaglemission.commands.params import UsageError, deep_merge, parse_kv
from eaglemission.config import MissionFile
from eaglemission.errors import InputError
from eaglemission.flight.progress import compile_progress
from eaglemission.perception.appearance import AppearanceConfig, TargetAppearance
from eaglemission.perception.inputs import (
    IMAGE_EXTS,
    frame_time_ns,
    images_in,
    read_image,
    read_target_image,
)
from eaglemission.perception.keep import box_of
from eaglemission.perception.overlay import draw_overlay
from eaglemission.types import Detection, DetectionResult, Frame, TargetPrior

# the logger keeps the name of the module the command came from (eaglemission.detectors.cli,
# shown in the log lines); built, not spelled out: a module name string counts as an import
log = logging.getLogger(__name__.rpartition(".")[0] + ".cli")

VIDEO_EXTS = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg")


def iter_input(path: Path, fps: float, max_frames: int | None) -> Iterator[tuple[str, Frame]]:
    """(stem, Frame) from a video file or an image folder; timestamps from the video or ``fps``."""
    if not path.exists():
        raise UsageError(f"INPUT {str(path)!r}: not found; give a video file or an image folder")
    n = 0
    if path.is_dir():
        files = images_in(path)
        if not files:
            raise UsageError(f"INPUT {str(path)!r}: no images ({', '.join(IMAGE_EXTS)}) in the folder")
        for i, f in enumerate(files):
            if max_frames is not None and n >= max_frames:
                return
            yield f.stem, Frame(read_image(f), frame_time_ns(i, fps), "input", i)
            n += 1
        return
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise UsageError(f"INPUT {str(path)!r}: cannot open as a video (formats: "
                         f"{', '.join(VIDEO_EXTS)}) and it is not a folder")
    try:
        vfps = cap.get(cv2.CAP_PROP_FPS)
        rate = vfps if vfps and math.isfinite(vfps) and vfps > 0 else fps
        i = 0
        while max_frames is None or n < max_frames:
            ok, img = cap.read()
            if not ok:
                break
            frame = Frame(cast(NDArray[np.uint8], img), frame_time_ns(i, rate), "input", i)
            yield f"{i:06d}", frame
            i += 1
            n += 1
        if i == 0:
            raise UsageError(f"INPUT {str(path)!r}: the video has no readable frame")
    finally:
        cap.release()


def detector_from_args(args: argparse.Namespace) -> tuple[str, dict[str, Any]]:
    """Detector name and params from ``--config`` (a mission file's ``detector`` section, or a
    mapping of params) overridden by ``--detector`` and ``--params``."""
    name: str | None = args.detector
    params: dict[str, Any] = {}
    if args.config is not None:
        data = _config_data(args.config)
        if isinstance(data, dict) and isinstance(data.get("detector"), dict):
            section = data["detector"]
            params = dict(section.get("params") or {})
            if name is None or name == section.get("type"):
                name = section.get("type", name)
            else:
                params = {}  # the file's params belong to another detector
                log.warning("--detector %s overrides the config's detector %s; its params are "
                            "ignored", name, section.get("type"))
        elif isinstance(data, dict):
            params = data
        elif data is not None:
            raise UsageError(f"--config {args.config}: expected a mapping (a mission file or "
                             f"detector params), got {type(data).__name__}")
    if name is None:
        raise UsageError("give --detector NAME (or --config with a `detector:` section)")
    return name, deep_merge(params, parse_kv(args.params))


def _config_data(path: Path) -> Any:
    from eaglemission.config import parse_yaml, read_config_text

    return parse_yaml(read_config_text(path), source=str(path))


def target_image_from_args(args: argparse.Namespace) -> np.ndarray | None:
    """The example image of the target: ``--target-image PATH``, else the mission file's
    ``target.appearance_image`` (relative to the mission file), else None."""
    if args.target_image is not None:
        return read_target_image(Path(args.target_image))
    if args.config is not None:
        data = _config_data(args.config)
        target = data.get("target") if isinstance(data, dict) else None
        rel = target.get("appearance_image") if isinstance(target, dict) else None
        if rel:
            path = Path(rel)
            if not path.is_absolute():
                path = Path(args.config).resolve().parent / path
            return read_target_image(path)
    return None


def _detect_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", type=Path, help="a video file or a folder of images")
    p.add_argument("--detector", default=None, help="detector plugin (see `eaglemission plugins`)")
    p.add_argument("--config", type=Path, default=None,
                   help="a mission file: run the mission's perception (acquire and keep) as on "
                        "a camera; or a YAML of detector params (with --detector)")
    p.add_argument("--params", nargs="*", default=[], metavar="KEY=VALUE",
                   help="detector params, e.g. regions.threshold=otsu downscale=2")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--fps", type=float, default=30.0,
                   help="frame rate for an image folder's timestamps (videos use their own)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    p.add_argument("--no-video", action="store_true", help="images only, no overlay.mp4")
    p.add_argument("--target-image", default=None, metavar="PATH",
                   help="an example image of the target (a tight crop, or a photo on a plain "
                        "background): the detector is followed by the appearance prior; "
                        "default: the --config mission file's target.appearance_image")
    g = p.add_argument_group("target prior (keeps only regions that fit; off by default)")
    g.add_argument("--min-area-px", type=float, default=None, help="smallest MBR area, px^2")
    g.add_argument("--max-area-px", type=float, default=None, help="largest MBR area, px^2")
    g.add_argument("--aspect-ratio", type=float, default=None,
                   help="long/short side of the target's top face")
    g.add_argument("--aspect-tolerance", type=float, default=0.5,
                   help="relative tolerance on the aspect ratio (default 0.5)")


def prior_from_args(args: argparse.Namespace) -> TargetPrior | None:
    """A :class:`TargetPrior` from the ``detect`` options, or None when none is given."""
    if args.min_area_px is None and args.max_area_px is None and args.aspect_ratio is None:
        return None
    lo = 0.0 if args.min_area_px is None else args.min_area_px
    hi = math.inf if args.max_area_px is None else args.max_area_px
    if not (0 <= lo <= hi):
        raise UsageError(f"--min-area-px/--max-area-px: need 0 <= min <= max, got {lo}, {hi}")
    if args.aspect_ratio is not None and not args.aspect_ratio >= 1:
        raise UsageError(f"--aspect-ratio: long/short, must be >= 1, got {args.aspect_ratio}")
    if not args.aspect_tolerance >= 0:
        raise UsageError(f"--aspect-tolerance: must be >= 0, got {args.aspect_tolerance}")
    return TargetPrior(min_area_px=lo, max_area_px=hi, aspect_ratio=args.aspect_ratio,
                       aspect_tolerance=args.aspect_tolerance)


def run_detect(args: argparse.Namespace) -> int:
    if not (args.fps > 0 and math.isfinite(args.fps)):
        raise UsageError(f"--fps: must be > 0, got {args.fps}")
    if args.max_frames is not None and args.max_frames < 1:
        raise UsageError(f"--max-frames: must be >= 1, got {args.max_frames}")
    # the first run compiles the detector's kernels (building it, its first frame): say so
    with compile_progress(lambda line: print(line, file=sys.stderr, flush=True)):
        return _detect(args)


def _detect(args: argparse.Namespace) -> int:
    from rich.console import Console

    step, name = _stepper(args)
    out = Path(args.out)
    frames_iter = iter_input(Path(args.input), args.fps, args.max_frames)
    out.mkdir(parents=True, exist_ok=True)
    console = Console(stderr=True)
    writer = None
    size = (0, 0)
    size_warned = False
    video_fps = args.fps
    if Path(args.input).is_file():
        cap = cv2.VideoCapture(str(args.input))
        vfps = cap.get(cv2.CAP_PROP_FPS) if cap.isOpened() else 0.0
        cap.release()
        if vfps and math.isfinite(vfps) and vfps > 0:
            video_fps = vfps
    n = n_det = 0
    times = []
    try:
        with (out / "detections.jsonl").open("w") as jl:
            for stem, frame in frames_iter:
                t = time.perf_counter()
                try:
                    result, target, kept = step(frame)
                except InputError as exc:
                    raise UsageError(f"frame {stem}: {exc}") from None
                times.append(time.perf_counter() - t)
                overlay = draw_overlay(frame.image, result,
                                       kept_box=box_of(target) if kept and target else None)
                cv2.imwrite(str(out / f"{stem}.jpg"), overlay)
                if not args.no_video:
                    if writer is None:
                        size = (overlay.shape[1], overlay.shape[0])
                        writer = cv2.VideoWriter(str(out / "overlay.mp4"),
                                                 cv2.VideoWriter.fourcc(*"mp4v"), video_fps, size)
                    if (overlay.shape[1], overlay.shape[0]) == size:
                        writer.write(overlay)
                    elif not size_warned:
                        size_warned = True
                        console.print(f"[yellow]frame {stem}: size changed; overlay.mp4 keeps "
                                      f"{size[0]}x{size[1]} frames only (the JPEGs have all)")
                ranked = ([target] if target is not None else []) + [
                    d for d in result.detections if target is None
                    or not np.allclose(d.center_px, target.center_px)]
                jl.write(json.dumps({
                    "frame": stem, "timestamp_ns": frame.timestamp_ns,
                    "threshold": result.threshold,
                    "target": None if not kept or target is None else _box_json(target),
                    "detections": [{"rank": k, "score": d.score, "center_px": d.center_px,
                                    "corners_px": d.corners_px.tolist(), "size_px": d.size_px,
                                    "angle_deg": d.angle_deg, "area_px": d.area_px}
                                   for k, d in enumerate(ranked)]}) + "\n")
                n += 1
                n_det += len(result.detections)
    finally:
        if writer is not None:
            writer.release()
    console.print(f"{name}: {n} frame(s), {n_det / max(n, 1):.2f} detection(s)/frame, "
                  f"median {1e3 * float(np.median(times)):.1f} ms/frame; overlays in {out}")
    return 0


Step = Callable[[Frame], tuple[DetectionResult, Detection | None, bool]]
"""One frame: (the detector's result, the target or best detection, whether it is kept)."""


def _box_json(d: Detection) -> dict[str, Any]:
    u0, v0, u1, v1 = box_of(d)
    return {"center_px": d.center_px, "box_px": [u0, v0, u1, v1]}


def _mission_file(path: Path) -> MissionFile | None:
    """``--config``'s mission file, or None when it is only detector params."""
    data = _config_data(path)
    if not (isinstance(data, dict) and "mission" in data and "cameras" in data):
        return None
    from eaglemission.config import load_config

    return load_config(path)


def _stepper(args: argparse.Namespace) -> tuple[Step, str]:
    """What runs on each frame: the mission's perception (``--config`` a mission file, no
    ``--detector``), else one detector (followed by the appearance prior with an image)."""
    cfg = _mission_file(args.config) if args.config is not None else None
    if cfg is not None and args.detector is None and not args.params:
        image = read_target_image(Path(args.target_image)) if args.target_image else None
        fp = FootagePerception(cfg, FootageOptions(example_image=image))

        def mission(frame: Frame) -> tuple[DetectionResult, Detection | None, bool]:
            meas = fp.process(frame)
            h, w = np.asarray(frame.image).shape[:2]  # no map when only the tracker ran
            res = fp.last_result or DetectionResult(np.zeros((h, w), np.float32), (),
                                                    frame.timestamp_ns, frame.camera_id,
                                                    frame.seq)
            return res, meas.detection, meas.kept

        return mission, f"the mission's perception of {args.config}"
    name, params = detector_from_args(args)
    prior = prior_from_args(args)
    image = target_image_from_args(args)
    detector = registry.load("detectors", name, params)
    if image is not None:  # the appearance prior after the detector, as the mission flies it
        section = _config_data(args.config).get("appearance") if args.config else None
        appearance = AppearanceConfig.model_validate(section or {})
        detector = TargetAppearance(image=image, example=appearance.example).with_prior(
            detector, appearance.prior)

    def alone(frame: Frame) -> tuple[DetectionResult, Detection | None, bool]:
        res = detector.detect(frame, prior)
        return res, res.best, False

    return alone, name


DETECT_COMMAND = Command(
    "run the mission's perception (--config MISSION) or a detector on a video or an image "
    "folder: the target's box per frame, overlays",
    _detect_args, run_detect)
