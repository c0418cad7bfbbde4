"""One short DAVIS sequence (skips when ../shared is absent): DTDMI beats SR on it."""

from __future__ import annotations

import cv2
import numpy as np
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.lab.bench.metrics import CurveAccumulator, normalize_map

from eaglemission.types import Frame


def test_dtdmi_default_beats_spectral_residual_on_a_short_davis_sequence(davis):
    cv2.setNumThreads(1)
    seq = davis / "car-shadow"
    frames = sorted((seq / "frames").glob("*.jpg"))[:16]
    det = DTDMIDetector(DTDMIConfig())
    sr = cv2.saliency.StaticSaliencySpectralResidual_create()
    acc_d, acc_s = CurveAccumulator(), CurveAccumulator()
    for i, f in enumerate(frames):
        img = cv2.imread(str(f))
        gt = cv2.imread(str(seq / "gt" / (f.stem + ".png")), cv2.IMREAD_GRAYSCALE) >= 128
        res = det.detect(Frame(img, int(1e9 + i * 1e9 / 24), "davis", i))
        assert res.saliency.shape == gt.shape
        if i == 0:
            continue  # first frame: no motion yet
        acc_d.add(normalize_map(res.saliency), gt)
        acc_s.add(normalize_map(sr.computeSaliency(img)[1].astype(np.float32)), gt)
    f_d, f_s = acc_d.scores().max_f, acc_s.scores().max_f
    assert f_d > 1.2 * f_s, (f_d, f_s)
