"""``eaglemission bench`` and ``eaglemission detect``: saliency benchmark and overlay tool.

``bench`` scores detectors on folders laid out as ``<seq>/frames/*.jpg`` + ``<seq>/gt/*.png``
(the layout of ../shared/data/video_saliency/DAVIS2016) with the per-image-mean protocol of
:mod:`eaglemission.detectors.metrics`, and on ``<seq>/boxes.txt`` box annotations (the layout of
../shared/data/uav_tracking) with the box metrics of :mod:`eaglemission.detectors.boxes`, and
writes markdown + JSON tables and plots.
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
from eaglemission.detectors.boxes import (
    BoxFormatError,
    BoxScores,
    box_from_mask,
    box_valid,
    crop_box,
    parse_boxes,
    score_frame,
    spread,
)
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
    """One sequence: its frames, per-frame mask files and/or boxes (``boxes.txt``).

    ``gts[i]`` is the mask of frame ``i`` (None: no mask); ``boxes`` is (N, 4) pixel edges
    (:func:`eaglemission.detectors.boxes.parse_boxes`), a NaN row for a frame without the target,
    or None when the sequence has no ``boxes.txt`` (then mask sequences are box-scored against
    each mask's bounding box).
    """

    name: str
    frames: tuple[Path, ...]
    gts: tuple[Path | None, ...]  # same length; None: frame not annotated (run, not scored)
    boxes: np.ndarray | None = field(default=None, compare=False)

    @property
    def has_masks(self) -> bool:
        return any(g is not None for g in self.gts)

    @property
    def n_scored(self) -> int:
        if self.boxes is not None:
            return len(self.frames)
        return sum(g is not None for g in self.gts)

    def head(self, n: int) -> BenchSequence:
        """The first ``n`` frames."""
        return BenchSequence(self.name, self.frames[:n], self.gts[:n],
                             None if self.boxes is None else self.boxes[:n])


def _images_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file())


def _sequence_dirs(data: Path, max_depth: int = 3) -> dict[str, Path]:
    """Folders holding a ``frames/`` subfolder, up to ``max_depth`` levels below ``data`` (the UAV
    sets nest ``<dataset>/<seq>/``), named by their path relative to ``data``; ``data`` itself
    when it is one sequence."""
    if (data / "frames").is_dir():
        return {data.name: data}
    found: dict[str, Path] = {}

    def walk(folder: Path, depth: int) -> None:
        for p in sorted(folder.iterdir()):
            if not p.is_dir() or p.name.startswith("."):
                continue
            if (p / "frames").is_dir():
                found[p.relative_to(data).as_posix()] = p
            elif depth < max_depth:
                walk(p, depth + 1)

    walk(data, 1)
    return found


def _select(found: dict[str, Path], only: Sequence[str], data: Path) -> dict[str, Path]:
    """``--sequences`` items: a full name (``UAVDT/S0601``) or its last part (``S0601``)."""
    chosen: dict[str, Path] = {}
    missing = []
    for s in only:
        if s in found:
            chosen[s] = found[s]
            continue
        tail = [k for k in found if k.rpartition("/")[2] == s]
        if len(tail) == 1:
            chosen[tail[0]] = found[tail[0]]
        elif len(tail) > 1:
            raise UsageError(f"--sequences: {s!r} is ambiguous in {str(data)!r}: "
                             f"{', '.join(tail)}")
        else:
            missing.append(s)
    if missing:
        raise UsageError(f"--sequences: {', '.join(missing)} not found in {str(data)!r}; "
                         f"available: {', '.join(found) or 'none'}")
    return chosen


def find_sequences(data: Path, only: Sequence[str] | None = None, *,
                   box_origin: int = 1) -> list[BenchSequence]:
    """Sequences of ``data``, sorted by name: ``<seq>/frames/*`` with ``<seq>/gt/<stem>.png``
    masks and/or ``<seq>/boxes.txt`` (one ``x,y,w,h`` line per frame, ``box_origin``-based)."""
    if not data.exists():
        raise UsageError(f"--data {str(data)!r}: folder not found; give a folder of "
                         f"<seq>/frames/*.jpg + <seq>/gt/*.png or <seq>/boxes.txt")
    if not data.is_dir():
        raise UsageError(f"--data {str(data)!r}: is a file, not a folder of sequences")
    found = _sequence_dirs(data)
    if only:
        found = _select(found, only, data)
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
        boxes = None
        box_file = folder / "boxes.txt"
        if box_file.is_file():
            try:
                boxes = parse_boxes(box_file.read_text(), origin=box_origin,
                                    source=str(box_file))
            except BoxFormatError as exc:
                raise UsageError(str(exc)) from None
            if len(boxes) != len(frames):
                raise UsageError(f"sequence {name!r}: {str(box_file)!r} has {len(boxes)} "
                                 f"box line(s) for {len(frames)} frame(s); write one x,y,w,h "
                                 f"line (or nan,nan,nan,nan) per frame, in frame order")
        if boxes is None and not any(g is not None for g in gts):
            raise UsageError(f"sequence {name!r}: no ground truth: expected "
                             f"{str(gt_dir)!r}/<frame stem>.png or {str(box_file)!r}")
        out.append(BenchSequence(name, tuple(frames), gts, boxes))
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


def first_frame_crop(seq: BenchSequence) -> tuple[int, np.ndarray]:
    """(index, crop) of the first frame with a target box (``boxes.txt``, else the first
    non-empty mask's bounding box): the example image of ``bench --target-image first-frame``."""
    for i, fpath in enumerate(seq.frames):
        box = None
        if seq.boxes is not None:
            box = seq.boxes[i]
        elif seq.gts[i] is not None:
            image = read_image(fpath)
            box = box_from_mask(read_gt(seq.gts[i], image.shape[:2]))
        if box is not None and box_valid(box):
            try:
                return i, crop_box(read_image(fpath), box)
            except ValueError:
                continue  # box outside the frame: try the next one
    raise UsageError(f"sequence {seq.name!r}: no frame with a target box to crop the target "
                     f"image from (--target-image first-frame)")


def read_target_image(path: Path) -> np.ndarray:
    """``--target-image PATH``: a BGR uint8 image (a tight crop or a photo on a plain
    background)."""
    if not path.is_file():
        raise UsageError(f"--target-image {str(path)!r}: not found; give an image file (a tight "
                         f"crop of the target, or a photo of it on a plain background)")
    return read_image(path)


# ---------------------------------------------------------------------------------------------
# Bench
# ---------------------------------------------------------------------------------------------
@dataclass
class DetectorRun:
    spec: DetectorSpec
    sequences: dict[str, SequenceScores] = field(default_factory=dict)
    overall: CurveAccumulator = field(default_factory=CurveAccumulator)
    box_sequences: dict[str, BoxScores] = field(default_factory=dict)
    box: BoxScores = field(default_factory=BoxScores)
    detections: int = 0
    frames: int = 0
    hits: int = 0  # scored mask frames whose best detection's centre lies on the GT mask
    scored: int = 0
    time_s: list[float] = field(default_factory=list)

    @property
    def has_curves(self) -> bool:
        return self.overall.n_frames > 0


def run_detector_on_sequence(detector: Any, seq: BenchSequence, fps: float, run: DetectorRun,
                             save_dir: Path | None, on_frame: Any = None, *,
                             first_scored: int = 0) -> tuple[SequenceScores | None, BoxScores]:
    """Run one detector over a sequence (state reset first) and score it.

    Every frame is run (the detector's state sees the whole sequence); frames before
    ``first_scored`` are not scored. Mask frames feed the curves (max F, AUC, MAE) and the box
    metrics against the mask's bounding box; ``boxes.txt`` frames feed the box metrics.
    """
    detector.reset()
    acc = CurveAccumulator()
    boxes = BoxScores()
    for i, (fpath, gpath) in enumerate(zip(seq.frames, seq.gts)):
        image = read_image(fpath)
        frame = Frame(image, frame_time_ns(i, fps), "bench", i)
        t = time.perf_counter()
        result: DetectionResult = detector.detect(frame)
        run.time_s.append(time.perf_counter() - t)
        run.detections += len(result.detections)
        run.frames += 1
        if i >= first_scored:
            box = None
            if gpath is not None:
                sal01 = normalize_map(result.saliency)
                gt = read_gt(gpath, image.shape[:2])
                acc.add(sal01, gt)
                run.scored += 1
                run.hits += best_on_gt(result, gt)
                box = box_from_mask(gt)
                if save_dir is not None:
                    out = save_dir / seq.name / f"{fpath.stem}.png"
                    out.parent.mkdir(parents=True, exist_ok=True)
                    cv2.imwrite(str(out), quantize(sal01))
            if seq.boxes is not None:
                box = seq.boxes[i]
            if box is not None:
                boxes.add(score_frame(result, box))
        if on_frame is not None:
            on_frame()
    run.overall.merge(acc)
    run.box.merge(boxes)
    return (acc.scores() if acc.n_frames else None), boxes


def best_on_gt(result: DetectionResult, gt: np.ndarray) -> bool:
    """Whether the best detection's centre falls on a ground-truth pixel."""
    if result.best is None:
        return False
    u, v = (int(round(c)) for c in result.best.center_px)
    return bool(0 <= v < gt.shape[0] and 0 <= u < gt.shape[1] and gt[v, u])


def _fmt(x: float) -> str:
    return f"{x:.4f}"


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.1f}%"


def markdown_table(runs: Sequence[DetectorRun], sequences: Sequence[str]) -> str:
    """Curve tables (overall with ratios to ``sr`` when it ran, per-sequence max F) when any
    sequence has masks, then the box tables (overall, per sequence, spread over sequences)."""
    lines: list[str] = []
    curve_seqs = [n for n in sequences if any(n in r.sequences for r in runs)]
    if curve_seqs:
        ref = next((r for r in runs if r.spec.label == "sr" and r.has_curves), None)
        ref_f = ref.overall.scores().max_f if ref else None
        lines += ["| detector | max F (beta^2=0.3) | AUC | MAE | max F / SR | frames | "
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
        for name in curve_seqs:
            cells = []
            for r in runs:
                s = r.sequences[name]
                cells.append(f"{s.max_f:.3f} / {s.auc:.3f} / {s.mae:.3f}")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += box_tables(runs, sequences)
    return "\n".join(lines) + "\n"


def box_tables(runs: Sequence[DetectorRun], sequences: Sequence[str]) -> list[str]:
    """Markdown lines of the box metrics (docs/detectors.md, "Box benchmarks")."""
    lines = ["Box metrics (on target = centre inside the box grown 25 % a side; false = "
             "detections whose centre misses it, per scored frame):", "",
             "| detector | saliency peak on target | best detection on target | IoU of the best "
             "| frames with any detection | false detections / frame | detections / frame | "
             "target frames | on target per sequence: mean +- std (min-max) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        b = r.box
        sp = spread([r.box_sequences[n].on_target_rate for n in sequences
                     if n in r.box_sequences])
        dpf = b.detections / b.frames if b.frames else math.nan
        lines.append(f"| {r.spec.label} | {_pct(b.peak_rate)} | {_pct(b.on_target_rate)} | "
                     f"{b.mean_iou:.3f} | {_pct(b.any_rate)} | {b.false_per_frame:.3f} | "
                     f"{dpf:.2f} | {b.target_frames} | {_pct(sp['mean'])} +- "
                     f"{_pct(sp['std'])} ({_pct(sp['min'])}-{_pct(sp['max'])}) |")
    lines += ["", "Per sequence, best detection on target / frames with any / false per frame "
              "(saliency peak on target):", "",
              "| sequence | frames | " + " | ".join(r.spec.label for r in runs) + " |",
              "|---|---|" + "---|" * len(runs)]
    for name in sequences:
        first = next((r.box_sequences[name] for r in runs if name in r.box_sequences), None)
        if first is None:
            continue
        cells = []
        for r in runs:
            b = r.box_sequences[name]
            cells.append(f"{_pct(b.on_target_rate)} / {_pct(b.any_rate)} / "
                         f"{b.false_per_frame:.2f} ({_pct(b.peak_rate)})")
        lines.append(f"| {name} | {first.target_frames}/{first.frames} | " + " | ".join(cells)
                     + " |")
    return lines


def plot_curves(runs: Sequence[DetectorRun], out: Path) -> list[Path]:
    """PR and ROC curves of the pooled per-image-mean curves (as the paper's Figs. 10-11)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    runs = [r for r in runs if r.has_curves]
    if not runs:
        return paths
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


def plot_box_rates(runs: Sequence[DetectorRun], sequences: Sequence[str], out: Path) -> Path:
    """Bars per sequence: best detection on target (filled) and false detections per frame
    (hatched, right axis), one colour per detector."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in sequences if any(n in r.box_sequences for r in runs)] + ["overall"]
    x = np.arange(len(names))
    width = 0.8 / max(len(runs), 1)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(max(6.0, 0.9 * len(names) + 2), 7), dpi=110,
                                  sharex=True)
    for k, r in enumerate(runs):
        rates = [r.box_sequences[n].on_target_rate if n in r.box_sequences else math.nan
                 for n in names[:-1]] + [r.box.on_target_rate]
        false = [r.box_sequences[n].false_per_frame if n in r.box_sequences else math.nan
                 for n in names[:-1]] + [r.box.false_per_frame]
        ax.bar(x + (k - (len(runs) - 1) / 2) * width, rates, width, label=r.spec.label)
        ax2.bar(x + (k - (len(runs) - 1) / 2) * width, false, width, label=r.spec.label)
    ax.set(ylabel="best detection on target", ylim=(0, 1.02),
           title="Box benchmark: on target (centre in the box grown 25 % a side)")
    ax2.set(ylabel="false detections / frame")
    ax2.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    for a in (ax, ax2):
        a.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = out / "box_on_target.png"
    fig.savefig(p)
    plt.close(fig)
    return p


def results_json(runs: Sequence[DetectorRun], sequences: Sequence[BenchSequence], args: Any,
                 command: str) -> dict[str, Any]:
    names = [s.name for s in sequences]
    out: dict[str, Any] = {
        "command": command,
        "protocol": ("per-image mean; each map min-max normalised per frame, quantised to 0..255, "
                     "thresholds t = 0..255 as map >= t; max F with beta^2 = 0.3 (Eq. 17); AUC "
                     "by trapezoids with (0,0) and (1,1); MAE on the normalised map; GT = mask >= 128"),
        "box_protocol": ("on target: the best-ranked detection's centre inside the box grown "
                         "25% of its size on each side; IoU of its rotated MBR with the box; "
                         "saliency peak on target: the map's maximum reached inside the grown "
                         "box; false: detections whose centre misses the grown box (all of a "
                         "frame without the target), per scored frame; boxes.txt is "
                         f"{getattr(args, 'box_origin', 1)}-based; mask sequences use each "
                         "mask's bounding box"),
        "data": str(args.data),
        "fps": args.fps,
        "target_image": getattr(args, "target_image", None),
        "unscored_head": getattr(args, "unscored_head", None),
        "sequences": {s.name: {"frames": len(s.frames), "scored": s.n_scored,
                               "annotation": "masks" if s.boxes is None else "boxes"}
                      for s in sequences},
        "detectors": {},
    }
    for r in runs:
        entry: dict[str, Any] = {
            "plugin": r.spec.name,
            "params": r.spec.params,
            "detections_per_frame": r.detections / max(r.frames, 1),
            "median_ms_per_frame": 1e3 * float(np.median(r.time_s)) if r.time_s else None,
            "box": {"overall": r.box.as_dict(),
                    "sequences": {k: v.as_dict() for k, v in r.box_sequences.items()},
                    "on_target_spread": spread([r.box_sequences[n].on_target_rate
                                                for n in names if n in r.box_sequences]),
                    "false_per_frame_spread": spread([r.box_sequences[n].false_per_frame
                                                      for n in names if n in r.box_sequences])},
        }
        if r.has_curves:
            s = r.overall.scores()
            entry.update({
                "overall": s.as_dict(),
                "best_detection_on_gt": r.hits / max(r.scored, 1),
                "sequences": {k: v.as_dict() for k, v in r.sequences.items()},
                "curves": {"precision": s.precision.round(6).tolist(),
                           "recall": s.recall.round(6).tolist(), "fpr": s.fpr.round(6).tolist()},
            })
        out["detectors"][r.spec.label] = entry
    return out


def _bench_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", required=True, type=Path,
                   help="folder of <seq>/frames/*.jpg + <seq>/gt/*.png (DAVIS layout) and/or "
                        "<seq>/boxes.txt (one x,y,w,h line per frame, nan = no target); "
                        "sequences may be nested (<dataset>/<seq>)")
    p.add_argument("--detectors", default="sr,ft,mss,centre_prior",
                   help="comma-separated detector names; NAME@VARIANT runs a variant "
                        "(e.g. dtdmi@literal = dtdmi with preset=literal)")
    p.add_argument("--params", nargs="*", default=[], metavar="DETECTOR:KEY=VALUE",
                   help="detector params, e.g. dtdmi:preset=literal ft:regions.threshold=otsu")
    p.add_argument("--sequences", default=None,
                   help="comma-separated subset of sequences (full name or its last part)")
    p.add_argument("--fps", type=float, default=24.0,
                   help="frame rate for the frames' timestamps (DAVIS: 24)")
    p.add_argument("--out", type=Path, default=Path("bench_out"),
                   help="folder for results.md, results.json and the plots")
    p.add_argument("--save-maps", type=Path, default=None, metavar="DIR",
                   help="write each scored map as an 8-bit PNG to DIR/<detector>/<seq>/<stem>.png")
    p.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="only the first N frames of each sequence (quick checks)")
    p.add_argument("--box-origin", type=int, choices=(0, 1), default=1,
                   help="index of the first pixel in boxes.txt: 1 (MATLAB/OTB style, the UAV "
                        "sets; default) or 0")
    p.add_argument("--target-image", default=None, metavar="PATH|first-frame",
                   help="an example image of the target for detectors that use one (context "
                        "`appearance`): an image file, or `first-frame` = crop each sequence's "
                        "first target box (its first 10%% of frames are then not scored)")
    p.add_argument("--unscored-head", type=float, default=None, metavar="FRACTION",
                   help="do not score the first FRACTION of each sequence's frames (default 0.1 "
                        "with --target-image first-frame, else 0); give 0.1 to a run without "
                        "the image to score the same frames")
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
    first_frame = args.target_image == "first-frame"
    head = args.unscored_head if args.unscored_head is not None else (0.1 if first_frame else 0.0)
    if not 0 <= head < 1:
        raise UsageError(f"--unscored-head: must be in [0, 1), got {head}")
    args.unscored_head = head
    only = [s.strip() for s in args.sequences.split(",") if s.strip()] if args.sequences else None
    sequences = find_sequences(Path(args.data), only, box_origin=args.box_origin)
    if args.max_frames is not None:
        if args.max_frames < 1:
            raise UsageError(f"--max-frames: must be >= 1, got {args.max_frames}")
        n = args.max_frames
        sequences = [s.head(n) for s in sequences]
        empty = [s.name for s in sequences if s.n_scored == 0]
        if empty:
            raise UsageError(f"--max-frames {n}: no annotated frame left in {', '.join(empty)}")
    fixed_image = None
    if args.target_image is not None and not first_frame:
        fixed_image = read_target_image(Path(args.target_image))
    crops = {s.name: first_frame_crop(s) for s in sequences} if first_frame else {}
    specs = parse_detector_specs(args.detectors, args.params)
    context = {"appearance": fixed_image} if fixed_image is not None else {}
    detectors = [registry.load("detectors", s.name, s.params, **context)
                 for s in specs]  # fail early
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
                first_scored = math.ceil(head * len(seq.frames) - 1e-9)
                if first_frame:
                    i0, crop = crops[seq.name]
                    first_scored = max(first_scored, i0 + 1)
                    det = registry.load("detectors", spec.name, spec.params, appearance=crop)
                curves, boxes = run_detector_on_sequence(
                    det, seq, args.fps, run, save, on_frame=lambda: progress.advance(task),
                    first_scored=first_scored)
                if curves is not None:
                    run.sequences[seq.name] = curves
                run.box_sequences[seq.name] = boxes
    if all(r.box.frames == 0 for r in runs):
        raise UsageError("no frame was scored (--unscored-head too large for these sequences?)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = "eaglemission bench " + " ".join(shlex.quote(a) for a in sys.argv[2:]) \
        if len(sys.argv) > 1 and sys.argv[1] == "bench" else "eaglemission bench"
    names = [s.name for s in sequences]
    table = markdown_table(runs, names)
    scored = sum(r.box.frames for r in runs[:1])
    header = (f"# Saliency benchmark\n\nCommand: `{command}`\n\nData: `{args.data}` "
              f"({len(sequences)} sequences, {scored} scored frames"
              + (f"; target image: {args.target_image}" if args.target_image else "")
              + (f"; first {100 * head:.0f}% of each sequence not scored" if head else "")
              + "). Protocol: per-image mean, maps min-max normalised per frame, 256 "
              "thresholds, max F with beta^2 = 0.3, AUC of the ROC, MAE; box metrics as in "
              "docs/detectors.md.\n\n")
    (out / "results.md").write_text(header + table)
    (out / "results.json").write_text(json.dumps(results_json(runs, sequences, args, command),
                                                 indent=1))
    plots = plot_curves(runs, out) + [plot_box_rates(runs, names, out)]
    print(table)
    console.print(f"wrote {out / 'results.md'}, {out / 'results.json'}, "
                  + ", ".join(str(p) for p in plots)
                  + (f"; maps under {args.save_maps}" if args.save_maps else ""))
    return 0


BENCH_COMMAND = Command(
    "score saliency detectors on <seq>/frames + <seq>/gt masks or <seq>/boxes.txt (max F, MAE, "
    "AUC, PR/ROC; on target, IoU, false detections)",
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
                   help="YAML: a mission file (its `detector` section is used) or detector params")
    p.add_argument("--params", nargs="*", default=[], metavar="KEY=VALUE",
                   help="detector params, e.g. regions.threshold=otsu downscale=2")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--fps", type=float, default=30.0,
                   help="frame rate for an image folder's timestamps (videos use their own)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after N frames")
    p.add_argument("--no-video", action="store_true", help="images only, no overlay.mp4")
    p.add_argument("--target-image", default=None, metavar="PATH",
                   help="an example image of the target (a tight crop, or a photo on a plain "
                        "background) for detectors that use one; default: the --config mission "
                        "file's target.appearance_image")
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
    appearance = target_image_from_args(args)
    detector = registry.load("detectors", name, params,
                             **({"appearance": appearance} if appearance is not None else {}))
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
                    "detections": [{"rank": k, "score": d.score, "center_px": d.center_px,
                                    "corners_px": d.corners_px.tolist(), "size_px": d.size_px,
                                    "angle_deg": d.angle_deg, "area_px": d.area_px}
                                   for k, d in enumerate(result.detections)]}) + "\n")
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
