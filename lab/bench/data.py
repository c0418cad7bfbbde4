"""The datasets of ``eaglemission bench``: ``<seq>/frames/*.jpg`` with ``<seq>/gt/*.png`` masks
(the layout of ../shared/data/video_saliency/DAVIS2016) and/or ``<seq>/boxes.txt`` box
annotations (the layout of ../shared/data/uav_tracking); image and ground-truth reading."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from eaglemission.lab.bench.boxes import (
    BoxFormatError,
    box_from_mask,
    box_valid,
    crop_box,
    parse_boxes,
)

from eaglemission.commands.params import UsageError
from eaglemission.perception.inputs import images_in, read_image


@dataclass(frozen=True)
class BenchSequence:
    """One sequence: its frames, per-frame mask files and/or boxes (``boxes.txt``).

    ``gts[i]`` is the mask of frame ``i`` (None: no mask); ``boxes`` is (N, 4) pixel edges
    (:func:`eaglemission.lab.bench.boxes.parse_boxes`), a NaN row for a frame without the target,
    or None when the sequence has no ``boxes.txt`` (then mask sequences are box-scored against
    each mask's bounding box).
    """

    name: str
    frames: tuple[Path, ...]
    gts: tuple[Path | None, ...]  # same length; None: frame not annotated (run, not scored)
    boxes: np.ndarray | None = field(default=None, compare=False)

    @property
    def n_scored(self) -> int:
        if self.boxes is not None:
            return len(self.frames)
        return sum(g is not None for g in self.gts)

    def head(self, n: int) -> BenchSequence:
        """The first ``n`` frames."""
        return BenchSequence(self.name, self.frames[:n], self.gts[:n],
                             None if self.boxes is None else self.boxes[:n])


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
        frames = images_in(folder / "frames")
        if not frames:
            raise UsageError(f"sequence {name!r}: no frames in {str(folder / 'frames')!r}")
        gt_dir = folder / "gt"
        gt_by_stem = {p.stem: p for p in images_in(gt_dir)} if gt_dir.is_dir() else {}
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


def read_gt(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """Binary GT (``>= 128``), resized (nearest) to the frame's ``shape`` if needed."""
    g = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if g is None:
        raise UsageError(f"cannot read ground truth {str(path)!r}")
    if g.shape != shape:
        g = cv2.resize(g, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return g >= 128


def first_frame_crop(seq: BenchSequence) -> tuple[int, np.ndarray]:
    """(index, crop) of the first frame with a target box (``boxes.txt``, else the first
    non-empty mask's bounding box): the example image of ``bench --target-image first-frame``."""
    for i, fpath in enumerate(seq.frames):
        box = None
        gpath = seq.gts[i]
        if seq.boxes is not None:
            box = seq.boxes[i]
        elif gpath is not None:
            image = read_image(fpath)
            box = box_from_mask(read_gt(gpath, image.shape[:2]))
        if box is not None and box_valid(box):
            try:
                return i, crop_box(read_image(fpath), box)
            except ValueError:
                continue  # box outside the frame: try the next one
    raise UsageError(f"sequence {seq.name!r}: no frame with a target box to crop the target "
                     f"image from (--target-image first-frame)")
