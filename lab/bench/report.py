"""The reports of ``eaglemission bench``: markdown tables, ``results.json`` and the plots
(PR/ROC curves, box rates per sequence)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from eaglemission.lab.bench.boxes import BoxScores, spread
from eaglemission.lab.bench.data import BenchSequence
from eaglemission.lab.bench.runs import DetectorRun


def _fmt(x: float) -> str:
    return f"{x:.4f}"


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.1f}%"


def pooled_box_scores(run: DetectorRun, sequences: Sequence[str]) -> BoxScores:
    """The run's box metrics pooled over ``sequences`` (those it scored): the one source of
    every box figure the tables show."""
    pooled = BoxScores()
    for name in sequences:
        if name in run.box_sequences:
            pooled.merge(run.box_sequences[name])
    return pooled


def markdown_table(runs: Sequence[DetectorRun], sequences: Sequence[str]) -> str:
    """Curve tables (overall with ratios to ``sr`` when it ran, per-sequence max F) when any
    sequence has masks, then the box tables (overall, per sequence, spread over sequences).

    The curve table's "best detection on the mask" is the box metrics' ``on_mask_rate`` pooled
    over the same (mask) sequences: with only mask sequences, the box table's figure."""
    lines: list[str] = []
    curve_seqs = [n for n in sequences if any(n in r.sequences for r in runs)]
    if curve_seqs:
        ref = next((r for r in runs if r.spec.label == "sr" and r.has_curves), None)
        ref_f = ref.overall.scores().max_f if ref else None
        lines += ["| detector | max F (beta^2=0.3) | AUC | MAE | max F / SR | frames | "
                  "detections/frame | best detection on the mask | median ms/frame |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in runs:
            s = r.overall.scores()
            ratio = f"{s.max_f / ref_f:.3f}" if ref_f else "-"
            med = 1e3 * float(np.median(r.time_s)) if r.time_s else math.nan
            on_mask = pooled_box_scores(r, curve_seqs).on_mask_rate
            lines.append(f"| {r.spec.label} | {_fmt(s.max_f)} | {_fmt(s.auc)} | {_fmt(s.mae)} | "
                         f"{ratio} | {s.n_frames} | {r.detections / max(r.frames, 1):.2f} | "
                         f"{_pct(on_mask)} | {med:.1f} |")
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
    """Markdown lines of the box metrics (docs/detectors.md, "Box metrics")."""
    lines = ["Box metrics (on target = the best detection's centre inside the box grown 25 % a "
             "side; on the mask = its centre on a ground-truth mask pixel, mask sequences only; "
             "false = detections whose centre misses the grown box, per scored frame):", "",
             "| detector | saliency peak on target | best detection on target | best detection "
             "on the mask | IoU of the best | frames with any detection | false detections / "
             "frame | detections / frame | target frames | on target per sequence: mean +- std "
             "(min-max) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        b = pooled_box_scores(r, sequences)
        sp = spread([r.box_sequences[n].on_target_rate for n in sequences
                     if n in r.box_sequences])
        dpf = b.detections / b.frames if b.frames else math.nan
        lines.append(f"| {r.spec.label} | {_pct(b.peak_rate)} | {_pct(b.on_target_rate)} | "
                     f"{_pct(b.on_mask_rate)} | {b.mean_iou:.3f} | {_pct(b.any_rate)} | "
                     f"{b.false_per_frame:.3f} | {dpf:.2f} | {b.target_frames} | "
                     f"{_pct(sp['mean'])} +- {_pct(sp['std'])} ({_pct(sp['min'])}-"
                     f"{_pct(sp['max'])}) |")
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

    paths: list[Path] = []
    runs = [r for r in runs if r.has_curves]
    if not runs:
        return paths
    for kind in ("pr", "roc"):
        fig, ax = plt.subplots(figsize=(7.2, 5), dpi=120, layout="constrained")
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
        fig.legend(fontsize=8, loc="outside right upper", frameon=False)  # beside, not on, the curves
        p = out / f"{kind}_curves.png"
        fig.savefig(p)
        plt.close(fig)
        paths.append(p)
    return paths


def plot_box_rates(runs: Sequence[DetectorRun], sequences: Sequence[str], out: Path) -> Path:
    """Bars per sequence and overall: best detection on target (top) and false detections per
    frame (bottom), one colour per detector; the legend beside the axes, never on the bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in sequences if any(n in r.box_sequences for r in runs)] + ["overall"]
    x = np.arange(len(names))
    width = 0.8 / max(len(runs), 1)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(max(6.0, 0.9 * len(names) + 2) + 1.8, 7),
                                  dpi=110, sharex=True, layout="constrained")
    for k, r in enumerate(runs):
        rates = [r.box_sequences[n].on_target_rate if n in r.box_sequences else math.nan
                 for n in names[:-1]] + [r.box.on_target_rate]
        false = [r.box_sequences[n].false_per_frame if n in r.box_sequences else math.nan
                 for n in names[:-1]] + [r.box.false_per_frame]
        xk = x + (k - (len(runs) - 1) / 2) * width
        bars = ax.bar(xk, rates, width, label=r.spec.label)
        ax2.bar(xk, false, width, label=r.spec.label)
        colour = bars.patches[0].get_facecolor() if bars.patches else None
        for a, values in ((ax, rates), (ax2, false)):  # a measured 0 shows as a tick at 0
            zero = [i for i, v in enumerate(values) if v == 0]
            a.plot(xk[zero], np.zeros(len(zero)), "_", color=colour, ms=max(4.0, 60 * width),
                   mew=2.5)
    ax.set(ylabel="best detection on target", ylim=(0, 1.02),
           title="Box benchmark: on target (centre in the box grown 25 % a side)")
    ax2.set(ylabel="false detections / frame", ylim=(0, None))
    ax2.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    for a in (ax, ax2):
        a.grid(axis="y", alpha=0.3)
    fig.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="outside right upper",
               title="detector", title_fontsize=8, frameon=False)
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
                "sequences": {k: v.as_dict() for k, v in r.sequences.items()},
                "curves": {"precision": s.precision.round(6).tolist(),
                           "recall": s.recall.round(6).tolist(), "fpr": s.fpr.round(6).tolist()},
            })
        out["detectors"][r.spec.label] = entry
    return out
