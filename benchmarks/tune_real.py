"""Leave-sequences-out tuning of DTDMI on real footage; prints out-of-fold figures only.

    python benchmarks/tune_real.py uav                     # aerial grid on ../shared's UAV sequences
    python benchmarks/tune_real.py uav --target-image      # + the appearance prior with the
                                                           # first-frame crop (grid appearance)
    python benchmarks/tune_real.py davis                   # default-preset grid on DAVIS 2016
    python benchmarks/tune_real.py uav --grid my.json      # a JSON list of {"params": ..., "regions": ...}

Protocol (figures: reports/detectors_and_tuning.md, "Tuning on real footage"):

- **Folds**: the sequences, sorted by name, dealt into ``--folds`` folds (5 folds of 2 for the
  10 UAV and the 10 DAVIS sequences; fold k holds sequences k and k + 5). For every fold the grid
  point with the best training objective over the *other* folds' sequences is chosen and scored
  on the fold's own sequences; the printed figures pool these held-out scores (out of fold) and
  give their spread over the sequences. The preset that ships is the grid point chosen on all
  sequences; the out-of-fold figures estimate how that choice generalises.
- **Objective**: UAV, the fraction of target frames whose best detection is on target (pooled
  over the training frames; ties: fewer false detections); DAVIS, max F (beta^2 = 0.3) of the
  pooled per-image-mean curves (ties: AUC).
- **Search** on cached maps: every grid point's maps are computed once at the processing
  resolution (``downscale``, the mission's 2 by default: 640x360 for the UAV frames), every frame
  run (the detector is stateful) and every ``--score-step``-th frame scored; a grid point's
  variants (its region settings; with the target image, its appearance sections: the
  appearance prior's own state per variant) are applied to the cached maps. **Report**: the chosen configurations are then
  run through the whole detector (``registry.load(...).detect`` on every full-resolution frame,
  every frame scored, exactly as ``eaglemission bench``); only these figures are printed.
- **Target image** (``--target-image``, UAV): each sequence's first-frame box is cropped as the
  example image of the appearance prior after the detector; the first 10 % of the frames are
  not scored, for the runs without the image either (same frames).
- The footage has no metric scale: no target prior (size) is used; references (SR + the same
  regions, the mission's detector, the centre prior) are scored on the same frames.

Caches (``--cache``, default /tmp/eaglemission_tune) keep each grid point's per-sequence
scores, so a re-run only computes what is new.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import hashlib  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from eaglemission.lab.bench.boxes import (  # noqa: E402
    BoxScores,
    box_from_mask,
    score_frame,
    spread,
)
from eaglemission.lab.bench.data import (  # noqa: E402
    BenchSequence,
    find_sequences,
    first_frame_crop,
    read_gt,
)
from eaglemission.lab.bench.metrics import CurveAccumulator, normalize_map  # noqa: E402

from eaglemission import registry  # noqa: E402
from eaglemission.perception.appearance import AppearanceConfig, TargetAppearance  # noqa: E402
from eaglemission.perception.inputs import frame_time_ns  # noqa: E402
from eaglemission.perception.regions import RegionsConfig, find_regions  # noqa: E402
from eaglemission.types import DetectionResult, Frame  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
DATA = {"uav": SHARED / "uav_tracking", "davis": SHARED / "video_saliency" / "DAVIS2016"}
FPS = {"uav": 10.0, "davis": 24.0}  # UAV123@10fps; the UAVDT/DTB70 clips are treated alike
VERSION = 13  # bump when the detector code changes what a configuration computes


# ---------------------------------------------------------------------------------------------
# Grids
# ---------------------------------------------------------------------------------------------
def grid_aerial() -> list[dict[str, Any]]:
    """The aerial preset's grid: block contrast scale and luminance weight, colour cue weight,
    output saturation; regions: peak fraction. Fixed beforehand (docs/paper_choices.md, "aerial
    preset"): the S_M gain (2.5: S_M's median frame maximum on the block cue's scale), the
    regions' floor (20: it only has to keep empty frames silent) and elongation limit (5: a
    target is compact)."""
    out = []
    for rad, lw, cw, sat in itertools.product((0.004, 0.0055, 0.008), (0.3, 0.6), (0.0, 1.0),
                                              (1.0, 3.0)):
        params = {"preset": "aerial", "block_radius_frac": rad, "block_luminance_weight": lw,
                  "colour_weight": cw, "saturation": sat, "dynamic_gain": 2.5}
        regions = [{"peak_fraction": pf, "adaptive_floor": 20, "max_aspect": 5.0}
                   for pf in (0.7, 0.8, 0.9)]
        out.append({"params": params, "regions": regions})
    return out


def grid_aerial_round1() -> list[dict[str, Any]]:
    """The first round (15.6 % out of fold): also the S_M gain (0: no dynamic part), the floor
    and the elongation limit free; the choice flipped with the held-out sequences."""
    out = []
    for rad, lw, gain, cw, sat in itertools.product((0.004, 0.0055, 0.008), (0.3, 0.6),
                                                    (0.0, 2.5, 4.0), (0.0, 1.0), (1.0, 3.0)):
        params = {"preset": "aerial", "block_radius_frac": rad, "block_luminance_weight": lw,
                  "dynamic_gain": gain, "colour_weight": cw, "saturation": sat}
        if gain == 0.0:
            params["use_dynamic"] = False
        regions = [{"peak_fraction": pf, "adaptive_floor": fl, "max_aspect": ma}
                   for pf in (0.7, 0.8, 0.9) for fl in (20, 40) for ma in (None, 5.0)]
        out.append({"params": params, "regions": regions})
    return out


def grid_appearance() -> list[dict[str, Any]]:
    """With the target image: DTDMI's ``aerial`` preset without its dynamic part (a target static
    on the ground moves as the ground does), followed by the appearance prior
    (:mod:`eaglemission.perception.prior`). Searched: the example's exposure span, the weight of
    the detector's map, following, the regions' peak fraction. Fixed beforehand: unpooled colour
    bins, re-ranking exponent 8 over 12 candidates, the regions' floor (``--floor``: the lowest
    that keeps target-free real ground photos under 0.05 false detections per frame,
    benchmarks/bench_detectors.py --no-target)."""
    return [{"params": {"preset": "aerial", "use_dynamic": False},
             "appearance": appearance_variants()}]


def grid_appearance_sr() -> list[dict[str, Any]]:
    """:func:`grid_appearance` after OpenCV's spectral residual instead of DTDMI."""
    return [{"detector": "sr", "params": {}, "appearance": appearance_variants()}]


FLOOR = 40
"""The appearance prior's regions floor on 0..255 (``--floor``)."""


def appearance_variants() -> list[dict[str, Any]]:
    out = []
    for span, w, follow, pf in itertools.product((1.0, 1.5), (0.25, 0.75, 2.0), (0.0, 0.3),
                                                 (0.7, 0.8)):
        out.append({"example": {"exposure_span": span},
                    "prior": {"saliency_weight": w, "follow_weight": follow,
                              "regions": {"threshold": "adaptive", "adaptive_floor": FLOOR,
                                          "peak_fraction": pf, "max_aspect": 5.0}}})
    return out


def grid_default() -> list[dict[str, Any]]:
    """The default preset's grid on DAVIS: round 1's (:func:`grid_default_round1`) with and
    without the colour propagation (weight 0.5; 0: off)."""
    out = []
    for point in grid_default_round1():
        for cp in (0.0, 0.5):
            out.append({"params": {**point["params"], "colour_propagation": cp},
                        "regions": point["regions"]})
    return out


def grid_default_round1() -> list[dict[str, Any]]:
    """The default preset's grid on DAVIS: the block contrast cue added after Eq. (15) (weight 0:
    the previous default), the S_s exponent (0: S_s left out), smoothing, centre weight (max F
    does not depend on the regions)."""
    out = []
    for bw, se, blur, cs in itertools.product((0.0, 0.25, 0.5), (0.0, 0.5), (0.02, 0.03),
                                              (0.25, 0.3)):
        params = {"preset": "default", "static_exponent": se, "blur_sigma_frac": blur,
                  "centre_sigma_frac": cs, "downscale": 1}
        if bw > 0:
            params.update({"block_weight": bw, "block_fusion": "add", "block_radius_frac": 0.01,
                           "block_luminance_weight": 0.5})
        out.append({"params": params, "regions": [{}]})
    return out


GRIDS = {"aerial": grid_aerial, "aerial_round1": grid_aerial_round1,
         "appearance": grid_appearance, "appearance_sr": grid_appearance_sr,
         "default": grid_default, "default_round1": grid_default_round1}


# ---------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------
@dataclass
class Seq:
    bench: BenchSequence
    frames: list[np.ndarray] = field(default_factory=list)  # full resolution, BGR
    boxes: np.ndarray | None = None  # (N, 4) pixel edges (masks: their bounding boxes)
    masks: list[np.ndarray | None] = field(default_factory=list)
    crop: np.ndarray | None = None
    first_scored: int = 0

    @property
    def name(self) -> str:
        return self.bench.name


def load_data(kind: str, target_image: bool, head: float) -> list[Seq]:
    seqs = []
    for b in find_sequences(DATA[kind]):
        s = Seq(b)
        for i, f in enumerate(b.frames):
            img = cv2.imread(str(f))
            s.frames.append(img)
            s.masks.append(read_gt(b.gts[i], img.shape[:2]) if b.gts[i] is not None else None)
        if b.boxes is not None:
            s.boxes = b.boxes
        else:
            s.boxes = np.array([box_from_mask(m) if m is not None else np.full(4, np.nan)
                                for m in s.masks])
        s.first_scored = math.ceil(head * len(s.frames) - 1e-9)
        if target_image:
            i0, s.crop = first_frame_crop(b)
            s.first_scored = max(s.first_scored, i0 + 1)
        seqs.append(s)
    return seqs


def folds_of(names: list[str], k: int) -> list[list[str]]:
    """Sorted names dealt round-robin into k folds (k = 5, 10 names: fold i = names i, i + 5)."""
    return [names[i::k] for i in range(k)]


# ---------------------------------------------------------------------------------------------
# Scores
# ---------------------------------------------------------------------------------------------
@dataclass
class SeqScore:
    box: BoxScores
    curves: CurveAccumulator | None = None

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"box": {k: getattr(self.box, k) for k in (
            "frames", "target_frames", "peak_hits", "best_hits", "any_frames", "sum_iou",
            "detections", "false_detections")}}
        if self.curves is not None:
            c = self.curves
            d["curves"] = {"p": c.sum_precision.tolist(), "r": c.sum_recall.tolist(),
                           "f": c.sum_fpr.tolist(), "n": c.n_curves, "mae": c.sum_mae,
                           "frames": c.n_frames, "empty": c.n_empty_gt}
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SeqScore:
        box = BoxScores(**d["box"])
        curves = None
        if "curves" in d:
            c = d["curves"]
            curves = CurveAccumulator(sum_precision=np.array(c["p"]), sum_recall=np.array(c["r"]),
                                      sum_fpr=np.array(c["f"]), n_curves=c["n"],
                                      sum_mae=c["mae"], n_frames=c["frames"],
                                      n_empty_gt=c["empty"])
        return cls(box, curves)


def pooled(scores: list[SeqScore]) -> SeqScore:
    box = BoxScores()
    curves = CurveAccumulator() if all(s.curves is not None for s in scores) else None
    for s in scores:
        box.merge(s.box)
        if curves is not None and s.curves is not None:
            curves.merge(s.curves)
    return SeqScore(box, curves)


def objective(kind: str, s: SeqScore) -> tuple[float, float]:
    if kind == "davis":
        assert s.curves is not None
        sc = s.curves.scores()
        return sc.max_f, sc.auc
    return s.box.on_target_rate, -s.box.false_per_frame


# ---------------------------------------------------------------------------------------------
# Search on cached maps
# ---------------------------------------------------------------------------------------------
def key_of(obj: Any) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def resolved_config(name: str, params: dict[str, Any]) -> dict[str, Any]:
    """The validated config (with a DTDMI preset's resolved values): what the cache keys on."""
    from dataclasses import asdict

    from eaglemission.detectors.dtdmi.config import DTDMIConfig, resolve

    cfg = registry.validate_params("detectors", name, params, path="tune")
    out = cfg.model_dump(mode="json")
    if isinstance(cfg, DTDMIConfig):
        out["resolved"] = asdict(resolve(cfg))
    return out


def make_detector(name: str, params: dict[str, Any], seq: Seq, use_image: bool,
                  appearance: dict[str, Any] | None = None) -> Any:
    """The detector, followed by the appearance prior (``appearance``: the ``appearance``
    section) with the sequence's first-frame crop when ``use_image``."""
    det = registry.load("detectors", name, params)
    if appearance is None or not use_image or seq.crop is None:
        return det
    cfg = AppearanceConfig.model_validate(appearance)
    return TargetAppearance(image=seq.crop, example=cfg.example).with_prior(det, cfg.prior)


def variants_of(point: dict[str, Any], use_image: bool) -> list[dict[str, Any]]:
    """A grid point's variants, each computed on the point's cached detector maps: the
    appearance sections (with the target image), else the detector's region settings."""
    if use_image and point.get("appearance"):
        return [{"appearance": a} for a in point["appearance"]]
    return [{"regions": r} for r in (point.get("regions") or [{}])]


def search_point(kind: str, point: dict[str, Any], seqs: list[Seq], use_image: bool,
                 step: int, cache: Path) -> list[tuple[dict[str, Any], dict[str, SeqScore]]]:
    """Per-sequence scores of every variant of a grid point (the detector's maps computed once
    per frame at the processing resolution)."""
    name = point.get("detector", "dtdmi")
    params = dict(point["params"])
    ds = int(params.get("downscale", 2))
    params["downscale"] = 1  # the cached maps are made at the processing resolution
    variants = variants_of(point, use_image)
    resolved = resolved_config(name, params)
    base_regions = resolved.get("regions", {})
    out_keys = [key_of({"kind": kind, "name": name, "config": resolved, "variant": v,
                        "ds": ds, "image": use_image, "step": step, "v": VERSION})
                for v in variants]
    files = [cache / f"{k}.json" for k in out_keys]
    if all(f.is_file() for f in files):
        return [(v, {n: SeqScore.from_json(x) for n, x in json.loads(f.read_text()).items()})
                for v, f in zip(variants, files)]
    results: list[dict[str, SeqScore]] = [{} for _ in variants]
    for seq in seqs:
        det = make_detector(name, params, seq, False)
        det.reset()
        accs = [SeqScore(BoxScores(), CurveAccumulator() if kind == "davis" else None)
                for _ in variants]
        # the appearance prior follows its previous best detection: every frame runs through
        # every variant's own prior (scored or not)
        priors = [make_detector(name, params, seq, True, v["appearance"])
                  if "appearance" in v else None for v in variants]
        regions = [RegionsConfig(**{**base_regions, **v["regions"]}) if "regions" in v else None
                   for v in variants]
        for i, full in enumerate(seq.frames):
            h, w = full.shape[:2]
            small = cv2.resize(full, (max(8, w // ds), max(8, h // ds)),
                               interpolation=cv2.INTER_AREA) if ds > 1 else full
            frame = Frame(small, frame_time_ns(i, FPS[kind]), "tune", i)
            sal = det.saliency(frame)
            scored = i >= seq.first_scored and (i - seq.first_scored) % step == 0
            if not scored and all(p is None for p in priors):
                continue
            # scored at the processing resolution: the box scaled down (edges: (e + 0.5) / s - 0.5)
            sx, sy = w / small.shape[1], h / small.shape[0]
            box = (seq.boxes[i] + 0.5) / [sx, sy, sx, sy] - 0.5
            sal_full = None
            if kind == "davis" and scored:
                sal_full = cv2.resize(sal, (w, h), interpolation=cv2.INTER_LINEAR)
            backs: dict[str, tuple[Any, int]] = {}
            for acc, v, pr, rc in zip(accs, variants, priors, regions):
                if pr is not None:
                    ex = key_of(v["appearance"].get("example", {}))
                    if ex not in backs:
                        backs[ex] = pr.back_projection(small)
                    res = pr.combine(frame, small, sal, *backs[ex])
                else:
                    dets, t = find_regions(sal, rc)
                    res = DetectionResult(sal, dets, 0, "t", i, t)
                if not scored:
                    continue
                acc.box.add(score_frame(res, box))
                if acc.curves is not None and seq.masks[i] is not None:
                    acc.curves.add(normalize_map(sal_full), seq.masks[i])
        for res_k, acc in zip(results, accs):
            res_k[seq.name] = acc
    for f, res_k in zip(files, results):
        f.write_text(json.dumps({n: v.to_json() for n, v in res_k.items()}))
    return list(zip(variants, results))


# ---------------------------------------------------------------------------------------------
# Report: the whole detector on held-out sequences
# ---------------------------------------------------------------------------------------------
def run_full(kind: str, name: str, params: dict[str, Any], seq: Seq, use_image: bool,
             cache: Path, appearance: dict[str, Any] | None = None) -> SeqScore:
    resolved = resolved_config(name, params)
    k = key_of({"full": 1, "kind": kind, "name": name, "config": resolved, "image": use_image,
                "appearance": appearance, "seq": seq.name, "first": seq.first_scored,
                "v": VERSION})
    f = cache / f"full_{k}.json"
    if f.is_file():
        return SeqScore.from_json(json.loads(f.read_text()))
    det = make_detector(name, params, seq, use_image, appearance)
    det.reset()
    acc = SeqScore(BoxScores(), CurveAccumulator() if kind == "davis" else None)
    for i, img in enumerate(seq.frames):
        res = det.detect(Frame(img, frame_time_ns(i, FPS[kind]), "bench", i))
        if i < seq.first_scored:
            continue
        acc.box.add(score_frame(res, seq.boxes[i]))
        if acc.curves is not None and seq.masks[i] is not None:
            acc.curves.add(normalize_map(res.saliency), seq.masks[i])
    f.write_text(json.dumps(acc.to_json()))
    return acc


def merged(point: dict[str, Any], variant: dict[str, Any]
           ) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """A grid point's detector params and appearance section with one of its variants."""
    p = dict(point["params"])
    p.setdefault("downscale", 2)
    if "regions" in variant and variant["regions"]:
        p["regions"] = {**p.get("regions", {}), **variant["regions"]}
    return p, variant.get("appearance")


def fmt_pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.1f}%"


def report_rows(kind: str, label: str, per_seq: dict[str, SeqScore], names: list[str]) -> str:
    tot = pooled([per_seq[n] for n in names])
    b = tot.box
    sp = spread([per_seq[n].box.on_target_rate for n in names])
    cells = [label, fmt_pct(b.on_target_rate),
             f"{fmt_pct(sp['mean'])} +- {fmt_pct(sp['std'])} ({fmt_pct(sp['min'])}-"
             f"{fmt_pct(sp['max'])})", fmt_pct(b.any_rate), f"{b.false_per_frame:.3f}",
             f"{b.mean_iou:.3f}", fmt_pct(b.peak_rate)]
    if kind == "davis" and tot.curves is not None:
        sc = tot.curves.scores()
        fs = spread([per_seq[n].curves.scores().max_f for n in names])  # type: ignore[union-attr]
        cells += [f"{sc.max_f:.4f}", f"{fs['mean']:.3f} +- {fs['std']:.3f} ({fs['min']:.3f}-"
                  f"{fs['max']:.3f})", f"{sc.auc:.4f}", f"{sc.mae:.4f}"]
    return "| " + " | ".join(cells) + " |"


def split_top_level(text: str) -> list[str]:
    """``a,b@{"x":1,"y":2}`` -> ``["a", 'b@{"x":1,"y":2}']`` (commas inside braces kept)."""
    out, depth, cur = [], 0, ""
    for ch in text:
        depth += (ch == "{") - (ch == "}")
        if ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
        else:
            cur += ch
    out.append(cur.strip())
    return [x for x in out if x]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("dataset", choices=sorted(DATA))
    ap.add_argument("--grid", default=None,
                    help="built-in grid name (" + ", ".join(GRIDS) + ") or a JSON file with a "
                         "list of {\"params\": {...}, \"regions\": [{...}, ...]} or "
                         "{\"params\": {...}, \"appearance\": [{...}, ...]}")
    ap.add_argument("--detector", default="dtdmi")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--score-step", type=int, default=2, help="search: score every n-th frame")
    ap.add_argument("--target-image", action="store_true",
                    help="UAV: each sequence's first-frame box as the appearance image")
    ap.add_argument("--references", default="sr,mission,centre_prior",
                    help="scored on the same frames: sr (+ the same regions as the chosen "
                         "configuration), mission (configs/sitl_synthetic.yaml's detector), "
                         "centre_prior, NAME@JSON, or noimage:NAME@JSON (without the target "
                         "image)")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eaglemission_tune"))
    ap.add_argument("--floor", type=int, default=FLOOR,
                    help="the appearance prior's regions floor on 0..255 (grids appearance*)")
    ap.add_argument("--per-sequence", action="store_true", help="print the per-sequence table")
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass
    if not DATA[a.dataset].is_dir():
        print(f"error: {DATA[a.dataset]} not found (../shared absent?)", file=sys.stderr)
        return 2
    kind = a.dataset
    grid_name = a.grid or ("default" if kind == "davis" else
                           "appearance" if a.target_image else "aerial")
    if grid_name in GRIDS:
        grid = GRIDS[grid_name]()
    else:
        grid = json.loads(Path(grid_name).read_text())
    for g in grid:
        g.setdefault("detector", a.detector)
        for variant in g.get("appearance", []):  # the floor fixed beforehand (--floor)
            regions = variant.setdefault("prior", {}).setdefault("regions", {})
            regions["adaptive_floor"] = a.floor
    head = 0.1 if a.target_image else 0.0
    a.cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    seqs = load_data(kind, a.target_image, head)
    names = [s.name for s in seqs]
    by_name = {s.name: s for s in seqs}
    folds = folds_of(names, a.folds)
    print(f"# tune_real {kind}: {len(seqs)} sequences, {sum(len(s.frames) for s in seqs)} frames "
          f"(loaded in {time.perf_counter() - t0:.0f} s); grid {grid_name}: {len(grid)} map "
          f"configurations x their region settings; {a.folds} folds: "
          + "; ".join(", ".join(f) for f in folds)
          + (" ; target image: first-frame crop, first 10% of frames not scored"
             if a.target_image else ""), flush=True)
    # -- search
    candidates: list[tuple[dict[str, Any], dict[str, Any], dict[str, SeqScore]]] = []
    for gi, point in enumerate(grid):
        t = time.perf_counter()
        for variant, per_seq in search_point(kind, point, seqs, a.target_image, a.score_step,
                                             a.cache):
            candidates.append((point, variant, per_seq))
        print(f"#   grid point {gi + 1}/{len(grid)} {json.dumps(point['params'])} "
              f"[{time.perf_counter() - t:.0f} s]", file=sys.stderr, flush=True)
    # -- choose per fold (training = the other folds), and on all sequences
    def best_on(train: list[str]) -> tuple[dict[str, Any], dict[str, Any]]:
        scored = [(objective(kind, pooled([c[2][n] for n in train])), i)
                  for i, c in enumerate(candidates)]
        _, i = max(scored)
        return candidates[i][0], candidates[i][1]

    chosen = {}
    for k, fold in enumerate(folds):
        train = [n for n in names if n not in fold]
        chosen[k] = best_on(train)
    final = best_on(names)
    # -- report with the whole detector
    oof: dict[str, SeqScore] = {}
    fold_of = {n: k for k, f in enumerate(folds) for n in f}
    for n in names:
        point, variant = chosen[fold_of[n]]
        params, appearance = merged(point, variant)
        oof[n] = run_full(kind, point["detector"], params, by_name[n], a.target_image, a.cache,
                          appearance)
    rows = {f"**{grid[0]['detector']} tuned, out of fold**": oof}
    refs: dict[str, dict[str, SeqScore]] = {}
    for ref in split_top_level(a.references):
        per: dict[str, SeqScore] = {}
        for n in names:
            point, variant = chosen[fold_of[n]]
            if ref == "sr":
                params, appearance = merged(point, variant)
                regions = (appearance or {}).get("prior", {}).get("regions") \
                    or params.get("regions", {})
                label = "sr + the same regions"
                per[n] = run_full(kind, "sr", {"regions": regions}, by_name[n], False, a.cache)
            elif ref == "mission":
                from eaglemission.config import load_config

                cfg = load_config(check_plugins=False)
                p = {**cfg.detector.params}
                p.setdefault("downscale", 2)
                label = (f"mission's detector ({cfg.detector.type} "
                         f"{json.dumps(cfg.detector.params)}"
                         + (" + appearance prior" if a.target_image else "") + ")")
                per[n] = run_full(kind, cfg.detector.type, p, by_name[n], a.target_image, a.cache,
                                  cfg.appearance.model_dump(mode="json"))
            elif ref == "centre_prior":
                label = "centre_prior"
                per[n] = run_full(kind, "centre_prior", {}, by_name[n], False, a.cache)
            else:  # NAME@JSON, or noimage:NAME@JSON (without the target image)
                plain = ref.startswith("noimage:")
                nm, _, js = ref.removeprefix("noimage:").partition("@")
                p = json.loads(js) if js else {}
                label = ref
                per[n] = run_full(kind, nm, p, by_name[n], a.target_image and not plain, a.cache)
        refs[label] = per
    rows.update(refs)
    head_txt = ("| detector | best detection on target | on target per sequence: mean +- std "
                "(min-max) | frames with any | false / frame | IoU of the best | saliency peak "
                "on target |")
    sep = "|---|---|---|---|---|---|---|"
    if kind == "davis":
        head_txt += " max F | max F per sequence: mean +- std (min-max) | AUC | MAE |"
        sep += "---|---|---|---|"
    print(f"\n## Out of fold ({kind}; the whole detector on every full-resolution frame"
          + (", first 10% unscored" if a.target_image else "") + ")\n")
    print(head_txt)
    print(sep)
    for label, per in rows.items():
        print(report_rows(kind, label, per, names))
    ref_sr = next((v for k, v in refs.items() if k.startswith("sr")), None)
    tuned = pooled(list(oof.values()))
    if ref_sr is not None:
        srp = pooled(list(ref_sr.values()))
        ratio = tuned.box.on_target_rate / srp.box.on_target_rate \
            if srp.box.on_target_rate > 0 else math.inf
        line = f"\nOn target: {ratio:.2f}x SR + regions"
        if kind == "davis" and tuned.curves is not None and srp.curves is not None:
            line += f"; max F {tuned.curves.scores().max_f / srp.curves.scores().max_f:.2f}x SR"
        print(line)
    print("\nChosen per fold (training: the other folds):\n")
    for k, fold in enumerate(folds):
        point, variant = chosen[k]
        print(f"- fold {k} ({', '.join(fold)}): {point['detector']} "
              f"{json.dumps(point['params'])} {json.dumps(variant)}")
    print(f"- all sequences (what ships): {final[0]['detector']} "
          f"{json.dumps(final[0]['params'])} {json.dumps(final[1])}")
    if a.per_sequence:
        labels = list(rows)
        print("\nPer sequence (out of fold): on target / any / false per frame"
              + (" / max F" if kind == "davis" else "") + "\n")
        print("| sequence | fold | " + " | ".join(labels) + " |")
        print("|---|---|" + "---|" * len(labels))
        for n in names:
            cells = []
            for lab in labels:
                s = rows[lab][n]
                c = (f"{fmt_pct(s.box.on_target_rate)} / {fmt_pct(s.box.any_rate)} / "
                     f"{s.box.false_per_frame:.2f}")
                if kind == "davis" and s.curves is not None:
                    c += f" / {s.curves.scores().max_f:.3f}"
                cells.append(c)
            print(f"| {n} | {fold_of[n]} | " + " | ".join(cells) + " |")
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
