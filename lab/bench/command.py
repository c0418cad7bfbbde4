"""``eaglemission bench``: score saliency detectors on folders laid out as ``<seq>/frames/*.jpg``
+ ``<seq>/gt/*.png`` (the layout of ../shared/data/video_saliency/DAVIS2016) with the
per-image-mean protocol of :mod:`eaglemission.lab.bench.metrics`, and on ``<seq>/boxes.txt`` box
annotations (the layout of ../shared/data/uav_tracking) with the box metrics of
:mod:`eaglemission.lab.bench.boxes`; writes markdown + JSON tables and plots. See
docs/detectors.md."""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from pathlib import Path

from eaglemission.lab.bench.data import find_sequences, first_frame_crop
from eaglemission.lab.bench.report import (
    markdown_table,
    plot_box_rates,
    plot_curves,
    results_json,
)
from eaglemission.lab.bench.runs import DetectorRun, run_detector_on_sequence

from eaglemission.commands import Command
from eaglemission.commands.params import UsageError, build_spec, parse_detector_specs
from eaglemission.perception.inputs import read_target_image


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
    p.add_argument("--mission", type=Path, default=None, metavar="CONFIG",
                   help="box sequences: score the mission's perception (acquire and keep) of "
                        "this mission file, acquisition alone, keeping from the confirmation "
                        "on, without the example image, SR + regions, and CSRT and KCF "
                        "started on the first box; the example image is each sequence's first "
                        "box's crop (docs/detectors.md, \"Acquire and keep\")")
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
    if args.mission is not None:
        return run_perception_bench(args)
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
    sample = fixed_image if fixed_image is not None else (
        next(iter(crops.values()))[1] if crops else None)
    detectors = [build_spec(s, sample) for s in specs]  # fail early
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
                    det = build_spec(spec, crop)
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


def run_perception_bench(args: argparse.Namespace) -> int:
    """``bench --mission CONFIG``: :mod:`.perception`'s rows on box sequences."""
    from eaglemission.lab.bench.perception import bench_sequence, report

    from eaglemission.config import load_config
    from eaglemission.errors import ConfigError

    try:
        cfg = load_config(args.mission)
    except ConfigError as exc:
        raise UsageError(f"--mission {args.mission}: {exc}") from None
    only = [s.strip() for s in args.sequences.split(",") if s.strip()] if args.sequences else None
    sequences = [s for s in find_sequences(Path(args.data), only, box_origin=args.box_origin)
                 if s.boxes is not None]
    if not sequences:
        raise UsageError(f"--mission: no box-annotated sequence (<seq>/boxes.txt) under "
                         f"{args.data}")
    if args.max_frames is not None:
        sequences = [s.head(args.max_frames) for s in sequences]
    per_seq = {}
    for seq in sequences:
        per_seq[seq.name] = bench_sequence(seq, cfg, args.fps)
        print(f"# {seq.name}: " + ", ".join(f"{k.strip()} {v.hits}/{v.frames}"
                                            for k, v in per_seq[seq.name].items()),
              file=sys.stderr, flush=True)
    text = report(per_seq)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "perception.md").write_text(f"# The mission's perception on {args.data}\n\n"
                                       f"Mission file: `{args.mission}`\n\n" + text + "\n")
    print(text)
    return 0


BENCH_COMMAND = Command(
    "score saliency detectors on <seq>/frames + <seq>/gt masks or <seq>/boxes.txt (max F, MAE, "
    "AUC, PR/ROC; on target, IoU, false detections)",
    _bench_args, run_bench)
