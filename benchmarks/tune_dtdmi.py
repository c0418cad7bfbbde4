"""Score DTDMI configurations on a DAVIS-layout folder (the tuning script behind reports/detectors_and_tuning.md).

Usage::

    python benchmarks/tune_dtdmi.py [--data DIR] [--fps 24] '{"preset": "literal"}' '{}' ...

Each argument is a JSON object of DTDMIConfig overrides (``{"detector": "midbrain", ...}``
picks another of the DTDMI-family plugins); ``sr`` and ``centre`` score the references. Prints
pooled max-F (beta^2 = 0.3), AUC and MAE over all frames (per-image mean protocol of
eaglemission.lab.bench.metrics) and the ratio of max-F to OpenCV's spectral residual.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np
from eaglemission.lab.bench.metrics import CurveAccumulator, normalize_map

from eaglemission.types import Frame

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared/data/video_saliency/DAVIS2016"


def load(data: Path) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    seqs = {}
    for d in sorted(p for p in data.iterdir() if (p / "frames").is_dir()):
        frames = sorted((d / "frames").glob("*.jpg"))
        seqs[d.name] = [(cv2.imread(str(f)), cv2.imread(str(d / "gt" / (f.stem + ".png")),
                                                       cv2.IMREAD_GRAYSCALE) >= 128)
                        for f in frames]
    return seqs


def make(spec: str):
    if spec == "sr":
        sr = cv2.saliency.StaticSaliencySpectralResidual_create()
        return lambda img, t: sr.computeSaliency(img)[1].astype(np.float32), lambda: None
    if spec == "centre":
        cache: dict = {}

        def centre(img, t):
            h, w = img.shape[:2]
            if (h, w) not in cache:
                y, x = np.mgrid[0:h, 0:w]
                cache[(h, w)] = np.exp(-0.5 * (((y - (h - 1) / 2) / (0.25 * h)) ** 2
                                             + ((x - (w - 1) / 2) / (0.25 * w)) ** 2))
            return cache[(h, w)]
        return centre, lambda: None
    from eaglemission import registry

    over = json.loads(spec)
    name = over.pop("detector", "dtdmi")
    cls = registry.get("detectors", name)
    det = cls(cls.Config(**over))

    def run(img, t):
        return det.saliency(Frame(img, t, "cam", 0))
    return run, det.reset


def score(spec: str, seqs, fps: float) -> tuple[float, float, float, dict]:
    fn, reset = make(spec)
    total = CurveAccumulator()
    per = {}
    for name, items in seqs.items():
        reset()
        acc = CurveAccumulator()
        for i, (img, gt) in enumerate(items):
            sal = fn(img, int(1e9 + i * 1e9 / fps))
            acc.add(normalize_map(sal), gt)
        total.merge(acc)
        per[name] = round(acc.scores().max_f, 4)
    s = total.scores()
    return s.max_f, s.auc, s.mae, per


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--fps", type=float, default=24.0)
    ap.add_argument("--per-seq", action="store_true")
    ap.add_argument("specs", nargs="*", default=['{"preset": "literal"}', "{}"])
    a = ap.parse_args()
    cv2.setNumThreads(1)
    seqs = load(a.data)
    sr_f = score("sr", seqs, a.fps)[0]
    print(f"{'sr':60s} maxF {sr_f:.4f}")
    for spec in a.specs:
        t0 = time.perf_counter()
        f, au, m, per = score(spec, seqs, a.fps)
        print(f"{spec[:60]:60s} maxF {f:.4f} ({f / sr_f:.2f}x SR)  AUC {au:.4f}  MAE {m:.4f}  "
              f"[{time.perf_counter() - t0:.0f} s]", flush=True)
        if a.per_seq:
            print("   ", per)


if __name__ == "__main__":
    main()
