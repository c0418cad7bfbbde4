"""``eaglemission bench`` and ``eaglemission detect``: saliency benchmark and overlay tool.

``bench`` scores detectors on folders laid out as ``<seq>/frames/*.jpg`` + ``<seq>/gt/*.png``
(the layout of ../shared/data/video_saliency/DAVIS2016) with the per-image-mean protocol of
:mod:`eaglemission.detectors.metrics`, and writes a markdown + JSON table and PR/ROC plots.
``detect`` runs one detector on a video or an image folder and writes overlay images (heat map,
thresholded regions, MBRs with their corner order). Detectors are loaded only through
``eaglemission.registry.load("detectors", name, params)``. See docs/detectors.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import shlex
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from eaglemission.detectors.metrics import CurveAccumulator, SequenceScores, normalize_map, quantize
from eaglemission.detectors.regions import to_uint8

from eaglemission import registry
from eaglemission.commands import Command
from eaglemission.errors import EagleMissionError, InputError
from eaglemission.types import DetectionResult, Frame, TargetPrior

log = logging.getLogger(__name__)

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
VIDEO_EXTS = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg")
T0_NS = 1_000_000_000  # first frame's timestamp (the virtual clock also starts at 1 s)


class UsageError(EagleMissionError):
    """A command-line argument is wrong (missing folder, no frames, bad --params)."""


# ---------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------
def parse_value(text: str) -> Any:
    """A ``--params`` value: YAML scalar/flow syntax (``3``, ``0.5``, ``true``, ``[1, 2]``)."""
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def set_dotted(target: dict[str, Any], key: str, value: Any) -> None:
    """``set_dotted(d, "regions.threshold", "otsu")`` -> ``d["regions"]["threshold"] = "otsu"``."""
    parts = key.split(".")
    node = target
    for p in parts[:-1]:
        child = node.setdefault(p, {})
        if not isinstance(child, dict):
            raise UsageError(f"--params {key}: {p!r} is already set to a value, not a section")
        node = child
    node[parts[-1]] = value


def parse_kv(items: Sequence[str], *, option: str = "--params") -> dict[str, Any]:
    """``["a=1", "regions.threshold=otsu"]`` -> nested dict."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{option} {item!r}: write KEY=VALUE (e.g. regions.threshold=otsu)")
        set_dotted(out, key.strip(), parse_value(value.strip()))
    return out


def deep_merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = v
    return out


@dataclass(frozen=True)
class DetectorSpec:
    """A detector to run: plugin ``name``, report ``label`` (``name`` or ``name@variant``)."""

    name: str
    label: str
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def variant(self) -> str | None:
        return self.label.partition("@")[2] or None


def parse_detector_specs(detectors: str, params: Sequence[str]) -> list[DetectorSpec]:
    """``--detectors a,b@v`` and ``--params SPEC:k=v`` -> specs.

    ``name:k=v`` applies to every variant of ``name``; ``name@v:k=v`` to that variant only (and
    wins). A variant with no params of its own sets ``preset: v`` when the plugin's Config has a
    ``preset`` field (``dtdmi@literal`` -> ``preset=literal``).
    """
    labels = [s.strip() for s in detectors.split(",") if s.strip()]
    if not labels:
        raise UsageError("--detectors: give at least one detector name (e.g. sr,ft,mss)")
    if len(set(labels)) != len(labels):
        raise UsageError(f"--detectors: a detector is listed twice in {detectors!r}")
    per_name: dict[str, list[str]] = {}
    per_label: dict[str, list[str]] = {}
    for item in params:
        spec, sep, kv = item.partition(":")
        if not sep or "=" not in kv or "=" in spec:
            raise UsageError(f"--params {item!r}: write DETECTOR:KEY=VALUE "
                             f"(e.g. dtdmi:preset=literal or ft:regions.threshold=otsu)")
        spec = spec.strip()
        if spec not in labels and spec not in {lab.partition("@")[0] for lab in labels}:
            raise UsageError(f"--params {item!r}: {spec!r} is not in --detectors {detectors!r}")
        (per_label if "@" in spec else per_name).setdefault(spec, []).append(kv)
    specs = []
    for label in labels:
        name, _, variant = label.partition("@")
        if not name:
            raise UsageError(f"--detectors: {label!r} has no plugin name before '@'")
        p = deep_merge(parse_kv(per_name.get(name, [])), parse_kv(per_label.get(label, [])))
        if variant and label not in per_label:
            cls = registry.get("detectors", name)
            if "preset" not in getattr(cls.Config, "model_fields", {}):
                raise UsageError(
                    f"--detectors {label!r}: {name!r} has no `preset` param; give the "
                    f"variant's params with --params {label}:KEY=VALUE")
            p = deep_merge(p, {"preset": variant})
        specs.append(DetectorSpec(name, label, p))
    return specs


# ---------------------------------------------------------------------------------------------
# Dataset
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BenchSequence:
    name: str
    frames: tuple[Path, ...]
    gts: tuple[Path | None, ...]  # same length; None: frame not annotated (run, not scored)

    @property
    def n_scored(self) -> int:
        return sum(g is not None for g in self.gts)


def _images_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file())


def find_sequences(data: Path, only: Sequence[str] | None = None) -> list[BenchSequence]:
    """Sequences of ``data`` (``<seq>/frames/*`` with ``<seq>/gt/<stem>.png``), sorted by name."""
    if not data.exists():
        raise UsageError(f"--data {str(data)!r}: folder not found; give a folder of "
                         f"<seq>/frames/*.jpg + <seq>/gt/*.png")
    if not data.is_dir():
        raise UsageError(f"--data {str(data)!r}: is a file, not a folder of sequences")
    found = {p.name: p for p in sorted(data.iterdir()) if (p / "frames").is_dir()}
    if only:
        missing = [s for s in only if s not in found]
        if missing:
            raise UsageError(f"--sequences: {', '.join(missing)} not found in {str(data)!r}; "
                             f"available: {', '.join(found) or 'none'}")
        found = {s: found[s] for s in only}
    if not found:
        raise UsageError(f"--data {str(data)!r}: no sequence folder with a frames/ subfolder")
    out = []
    for name, folder in found.items():
        frames = _images_in(folder / "frames")
        if not frames:
            raise UsageError(f"sequence {name!r}: no frames in {str(folder / 'frames')!r}")
        gt_dir = folder / "gt"
        gt_by_stem = {p.stem: p for p in _images_in(gt_dir)} if gt_dir.is_dir() else {}
        gts = tuple(gt_by_stem.get(f.stem) for f in frames)
        if not any(g is not None for g in gts):
            raise UsageError(f"sequence {name!r}: no ground truth: expected "
                             f"{str(gt_dir)!r}/<frame stem>.png")
        out.append(BenchSequence(name, tuple(frames), gts))
    return out


def read_image(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise UsageError(f"cannot read image {str(path)!r}: unreadable or not an image")
    return img


def read_gt(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """Binary GT (``>= 128``), resized (nearest) to the frame's ``shape`` if needed."""
    g = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if g is None:
        raise UsageError(f"cannot read ground truth {str(path)!r}")
    if g.shape != shape:
        g = cv2.resize(g, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return g >= 128


def frame_time_ns(index: int, fps: float) -> int:
    return T0_NS + round(index * 1e9 / fps)


# ---------------------------------------------------------------------------------------------
# Bench
# ---------------------------------------------------------------------------------------------
@dataclass
class DetectorRun:
    spec: DetectorSpec
    sequences: dict[str, SequenceScores] = field(default_factory=dict)
    overall: CurveAccumulator = field(default_factory=CurveAccumulator)
    detections: int = 0
    frames: int = 0
    hits: int = 0  # scored frames whose best detection's centre lies on the GT mask
    scored: int = 0
    time_s: list[float] = field(default_factory=list)


def run_detector_on_sequence(detector: Any, seq: BenchSequence, fps: float, run: DetectorRun,
                             save_dir: Path | None, on_frame: Any = None) -> SequenceScores:
    """Run one detector over a sequence (state reset first) and score it."""
    detector.reset()
    acc = CurveAccumulator()
    for i, (fpath, gpath) in enumerate(zip(seq.frames, seq.gts)):
        image = read_image(fpath)
        frame = Frame(image, frame_time_ns(i, fps), "bench", i)
        t = time.perf_counter()
        result: DetectionResult = detector.detect(frame)
        run.time_s.append(time.perf_counter() - t)
        run.detections += len(result.detections)
        run.frames += 1
        if gpath is not None:
            sal01 = normalize_map(result.saliency)
            gt = read_gt(gpath, image.shape[:2])
            acc.add(sal01, gt)
            run.scored += 1
            run.hits += best_on_gt(result, gt)
            if save_dir is not None:
                out = save_dir / seq.name / f"{fpath.stem}.png"
                out.parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(out), quantize(sal01))
        if on_frame is not None:
            on_frame()
    scores = acc.scores()
    run.overall.merge(acc)
    return scores


def best_on_gt(result: DetectionResult, gt: np.ndarray) -> bool:
    """Whether the best detection's centre falls on a ground-truth pixel."""
    if result.best is None:
        return False
    u, v = (int(round(c)) for c in result.best.center_px)
    return bool(0 <= v < gt.shape[0] and 0 <= u < gt.shape[1] and gt[v, u])


def _fmt(x: float) -> str:
    return f"{x:.4f}"


def markdown_table(runs: Sequence[DetectorRun], sequences: Sequence[str]) -> str:
    """Overall table (with ratios to ``sr`` when it ran) and a per-sequence max-F table."""
    ref = next((r for r in runs if r.spec.label == "sr"), None)
    ref_f = ref.overall.scores().max_f if ref else None
    lines = ["| detector | max F (beta^2=0.3) | AUC | MAE | max F / SR | frames | "
             "detections/frame | best detection on GT | median ms/frame |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        s = r.overall.scores()
        ratio = f"{s.max_f / ref_f:.3f}" if ref_f else "-"
        med = 1e3 * float(np.median(r.time_s)) if r.time_s else math.nan
        lines.append(f"| {r.spec.label} | {_fmt(s.max_f)} | {_fmt(s.auc)} | {_fmt(s.mae)} | "
                     f"{ratio} | {s.n_frames} | {r.detections / max(r.frames, 1):.2f} | "
                     f"{r.hits / max(r.scored, 1):.3f} | {med:.1f} |")
    lines += ["", "Per sequence, max F / AUC / MAE:", "",
              "| sequence | " + " | ".join(r.spec.label for r in runs) + " |",
              "|---|" + "---|" * len(runs)]
    for name in sequences:
        cells = []
        for r in runs:
            s = r.sequences[name]
            cells.append(f"{s.max_f:.3f} / {s.auc:.3f} / {s.mae:.3f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot_curves(runs: Sequence[DetectorRun], out: Path) -> list[Path]:
    """PR and ROC curves of the pooled per-image-mean curves (as the paper's Figs. 10-11)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for kind in ("pr", "roc"):
        fig, ax = plt.subplots(figsize=(5.5, 5), dpi=120)
        for r in runs:
            s = r.overall.scores()
            if kind == "pr":
                ax.plot(s.recall, s.precision, label=f"{r.spec.label} (maxF {s.max_f:.3f})")
            else:
                ax.plot(np.r_[0, s.fpr[::-1], 1], np.r_[0, s.recall[::-1], 1],
                        label=f"{r.spec.label} (AUC {s.auc:.3f})")
        if kind == "pr":
            ax.set(xlabel="recall", ylabel="precision", title="Precision-recall (per-image mean)")
        else:
            ax.plot([0, 1], [0, 1], color="0.7", lw=0.8, ls="--")
            ax.set(xlabel="false positive rate", ylabel="true positive rate",
                   title="ROC (per-image mean)")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.01)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower left" if kind == "pr" else "lower right")
        fig.tight_layout()
        p = out / f"{kind}_curves.png"
        fig.savefig(p)
        plt.close(fig)
        paths.append(p)
    return paths


def results_json(runs: Sequence[DetectorRun], sequences: Sequence[BenchSequence], args: Any,
                 command: str) -> dict[str, Any]:
    out: dict[str, Any] = {
        "command": command,
        "protocol": ("per-image mean; each map min-max normalised per frame, quantised to 0..255, "
                     "thresholds t = 0..255 as map >= t; max F with beta^2 = 0.3 (Eq. 17); AUC "
                     "by trapezoids with (0,0) and (1,1); MAE on the normalised map; GT = mask >= 128"),
        "data": str(args.data),
        "fps": args.fps,
        "sequences": {s.name: {"frames": len(s.frames), "scored": s.n_scored} for s in sequences},
        "detectors": {},
    }
    for r in runs:
        s = r.overall.scores()
        out["detectors"][r.spec.label] = {
            "plugin": r.spec.name,
            "params": r.spec.params,
            "overall": s.as_dict(),
            "detections_per_frame": r.detections / max(r.frames, 1),
            "best_detection_on_gt": r.hits / max(r.scored, 1),
            "median_ms_per_frame": 1e3 * float(np.median(r.time_s)) if r.time_s else None,
            "sequences": {k: v.as_dict() for k, v in r.sequences.items()},
            "curves": {"precision": s.precision.round(6).tolist(),
                       "recall": s.recall.round(6).tolist(), "fpr": s.fpr.round(6).tolist()},
        }
    return out


def _bench_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", required=True, type=Path,
                   help="folder of <seq>/frames/*.jpg + <seq>/gt/*.png (DAVIS layout)")
    p.add_argument("--detectors", default="sr,ft,mss,centre_prior",
                   help="comma-separated detector names; NAME@VARIANT runs a variant "
                        "(e.g. dtdmi@literal = dtdmi with preset=literal)")
    p.add_argument("--params", nargs="*", default=[], metavar="DETECTOR:KEY=VALUE",
                   help="detector params, e.g. dtdmi:preset=literal ft:regions.threshold=otsu")
    p.add_argument("--sequences", default=None, help="comma-separated subset of sequences")
    p.add_argument("--fps", type=float, default=24.0,
                   help="frame rate for the frames' timestamps (DAVIS: 24)")
    p.add_argument("--out", type=Path, default=Path("bench_out"),
                   help="folder for results.md, results.json, pr_curves.png, roc_curves.png")
    p.add_argument("--save-maps", type=Path, default=None, metavar="DIR",
                   help="write each scored map as an 8-bit PNG to DIR/<detector>/<seq>/<stem>.png")
    p.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="only the first N frames of each sequence (quick checks)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run_bench(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    if not (args.fps > 0 and math.isfinite(args.fps)):
        raise UsageError(f"--fps: must be > 0, got {args.fps}")
    only = [s.strip() for s in args.sequences.split(",") if s.strip()] if args.sequences else None
    sequences = find_sequences(Path(args.data), only)
    if args.max_frames is not None:
        if args.max_frames < 1:
            raise UsageError(f"--max-frames: must be >= 1, got {args.max_frames}")
        n = args.max_frames
        sequences = [BenchSequence(s.name, s.frames[:n], s.gts[:n]) for s in sequences]
        empty = [s.name for s in sequences if s.n_scored == 0]
        if empty:
            raise UsageError(f"--max-frames {n}: no annotated frame left in {', '.join(empty)}")
    specs = parse_detector_specs(args.detectors, args.params)
    detectors = [registry.load("detectors", s.name, s.params) for s in specs]  # fail early
    console = Console(stderr=True)
    runs = [DetectorRun(s) for s in specs]
    total = sum(len(s.frames) for s in sequences) * len(specs)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=console,
                  disable=args.no_progress, transient=False) as progress:
        task = progress.add_task("bench", total=total)
        for spec, det, run in zip(specs, detectors, runs):
            for seq in sequences:
                progress.update(task, description=f"{spec.label:>16} {seq.name:<16}")
                save = Path(args.save_maps) / spec.label if args.save_maps else None
                run.sequences[seq.name] = run_detector_on_sequence(
                    det, seq, args.fps, run, save, on_frame=lambda: progress.advance(task))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "eaglemission bench " + " ".join(shlex.quote(a) for a in sys.argv[2:]) \
        if len(sys.argv) > 1 and sys.argv[1] == "bench" else "eaglemission bench"
    table = markdown_table(runs, [s.name for s in sequences])
    header = (f"# Saliency benchmark\n\nCommand: `{command}`\n\nData: `{args.data}` "
              f"({len(sequences)} sequences, {sum(s.n_scored for s in sequences)} scored frames). "
              "Protocol: per-image mean, maps min-max normalised per frame, 256 thresholds, "
              "max F with beta^2 = 0.3, AUC of the ROC, MAE (docs/detectors.md).\n\n")
    (out / "results.md").write_text(header + table)
    (out / "results.json").write_text(json.dumps(results_json(runs, sequences, args, command),
                                                 indent=1))
    plots = plot_curves(runs, out)
    print(table)
    console.print(f"wrote {out / 'results.md'}, {out / 'results.json'}, "
                  + ", ".join(str(p) for p in plots)
                  + (f"; maps under {args.save_maps}" if args.save_maps else ""))
    return 0


BENCH_COMMAND = Command(
    "score saliency detectors on <seq>/frames + <seq>/gt folders (max F, MAE, AUC, PR/ROC)",
    _bench_args, run_bench)


# ---------------------------------------------------------------------------------------------
# Detect
# ---------------------------------------------------------------------------------------------
def iter_input(path: Path, fps: float, max_frames: int | None) -> Iterator[tuple[str, Frame]]:
    """(stem, Frame) from a video file or an image folder; timestamps from the video or ``fps``."""
    if not path.exists():
        raise UsageError(f"INPUT {str(path)!r}: not found; give a video file or an image folder")
    n = 0
    if path.is_dir():
        files = _images_in(path)
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
            yield f"{i:06d}", Frame(img, frame_time_ns(i, rate), "input", i)
            i += 1
            n += 1
        if i == 0:
            raise UsageError(f"INPUT {str(path)!r}: the video has no readable frame")
    finally:
        cap.release()


def draw_overlay(image: np.ndarray, result: DetectionResult, *, alpha: float = 0.45) -> np.ndarray:
    """Heat map blended over the frame, region outlines, MBRs with corner 0..3 marked."""
    img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    sal8 = to_uint8(result.saliency)
    heat = cv2.applyColorMap(sal8, cv2.COLORMAP_JET)
    out = cv2.addWeighted(img, 1.0 - alpha, heat, alpha, 0.0)
    t8 = int(round(result.threshold * 255))
    mask = (sal8 > t8).astype(np.uint8) * 255
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(out, contours, -1, (255, 255, 255), 1, cv2.LINE_AA)
    scale = max(img.shape[:2]) / 1000.0
    for rank, det in enumerate(result.detections):
        colour = (0, 255, 0) if rank == 0 else (0, 255, 255)
        pts = np.round(det.corners_px).astype(np.int32)
        cv2.polylines(out, [pts], True, colour, 2 if rank == 0 else 1, cv2.LINE_AA)
        for k, (u, v) in enumerate(pts):
            cv2.circle(out, (int(u), int(v)), 5 if k == 0 else 3, (0, 0, 255) if k == 0 else colour,
                       -1, cv2.LINE_AA)
            cv2.putText(out, str(k), (int(u) + 4, int(v) - 4), cv2.FONT_HERSHEY_SIMPLEX,
                        0.5 * max(scale, 0.6), colour, 1, cv2.LINE_AA)
        cu, cv_ = det.center_px
        cv2.putText(out, f"#{rank} {det.score:.2f}", (int(cu), int(cv_)), cv2.FONT_HERSHEY_SIMPLEX,
                    0.5 * max(scale, 0.6), colour, 1, cv2.LINE_AA)
    cv2.putText(out, f"{len(result.detections)} detection(s), T={t8}", (8, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.6 * max(scale, 0.6), (255, 255, 255), 1, cv2.LINE_AA)
    return out


def detector_from_args(args: argparse.Namespace) -> tuple[str, dict[str, Any]]:
    """Detector name and params from ``--config`` (a mission file's ``detector`` section, or a
    mapping of params) overridden by ``--detector`` and ``--params``."""
    name: str | None = args.detector
    params: dict[str, Any] = {}
    if args.config is not None:
        from eaglemission.config import parse_yaml, read_config_text

        data = parse_yaml(read_config_text(args.config), source=str(args.config))
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


def _detect_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", type=Path, help="a video file or a folder of images")
    p.add_argument("--detector", default=None, help="detector plugin (see `eaglemission plugins`)")
    p.add_argument("--config", type=Path, default=None,
                   help="YAML: a mission file (its `detector` section is used) or detector params")
    p.add_argument("--params", nargs="*", default=[], metavar="KEY=VALUE",
                   help="detector params, e.g. regions.threshold=otsu downscale=2")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--fps", type=float, default=30.0,
                   help="frame rate for an image folder's timestamps (videos use their own)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    p.add_argument("--no-video", action="store_true", help="images only, no overlay.mp4")
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
    from rich.console import Console

    if not (args.fps > 0 and math.isfinite(args.fps)):
        raise UsageError(f"--fps: must be > 0, got {args.fps}")
    if args.max_frames is not None and args.max_frames < 1:
        raise UsageError(f"--max-frames: must be >= 1, got {args.max_frames}")
    name, params = detector_from_args(args)
    prior = prior_from_args(args)
    detector = registry.load("detectors", name, params)
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
                    result = detector.detect(frame, prior)
                except InputError as exc:
                    raise UsageError(f"frame {stem}: {exc}") from None
                times.append(time.perf_counter() - t)
                overlay = draw_overlay(frame.image, result)
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
                jl.write(json.dumps({
                    "frame": stem, "timestamp_ns": frame.timestamp_ns,
                    "threshold": result.threshold,
                    "detections": [{"score": d.score, "center_px": d.center_px,
                                    "corners_px": d.corners_px.tolist(), "size_px": d.size_px,
                                    "angle_deg": d.angle_deg, "area_px": d.area_px}
                                   for d in result.detections]}) + "\n")
                n += 1
                n_det += len(result.detections)
    finally:
        if writer is not None:
            writer.release()
    console.print(f"{name}: {n} frame(s), {n_det / max(n, 1):.2f} detection(s)/frame, "
                  f"median {1e3 * float(np.median(times)):.1f} ms/frame; overlays in {out}")
    return 0


DETECT_COMMAND = Command(
    "run a detector on a video or an image folder and write overlays (heat map, regions, MBRs)",
    _detect_args, run_detect)
