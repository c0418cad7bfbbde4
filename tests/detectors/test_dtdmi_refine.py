"""DTDMI map refinements beyond the paper: colour propagation, following the previous best
detection, unpooled appearance bins (detectors/dtdmi/refine.py and their use)."""

from __future__ import annotations

import numpy as np
import pytest
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi.config import resolve
from eaglemission.detectors.dtdmi.engine import DTDMIEngine, propagate_by_colour
from eaglemission.detectors.dtdmi.refine import (
    colour_mean_saliency,
    propagated_saliency,
)

from eaglemission.types import Frame

RED = (30, 40, 210)
GREEN = (60, 140, 70)


def _frame(img: np.ndarray, i: int = 0, fps: float = 10.0) -> Frame:
    return Frame(img, int(1e9 + i * 1e9 / fps), "wide", i)


def test_colour_mean_saliency_hand_computed():
    lut = colour_mean_saliency([2, 0, 4], [1.0, 5.0, 2.0])
    assert lut.dtype == np.float32
    np.testing.assert_allclose(lut, [0.5, 0.0, 0.5])  # an empty bin gives 0, whatever its sum
    with pytest.raises(ValueError, match="same shape"):
        colour_mean_saliency([1, 2], [1.0])


def test_propagated_saliency_blends():
    s = np.array([[1.0, 0.0], [0.2, 0.4]], np.float32)
    p = np.array([[0.5, 0.5], [0.0, 1.0]], np.float32)
    np.testing.assert_array_equal(propagated_saliency(s, p, 0.0), s)
    np.testing.assert_array_equal(propagated_saliency(s, p, 1.0), p)
    np.testing.assert_allclose(propagated_saliency(s, p, 0.25), 0.75 * s + 0.25 * p, rtol=1e-6)
    with pytest.raises(ValueError, match="weight"):
        propagated_saliency(s, p, 1.5)
    with pytest.raises(ValueError, match="same shape"):
        propagated_saliency(s, p[:1], 0.5)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_colour_propagation_spreads_the_map_over_the_colour(backend):
    """Left half red, right half green; the map is 1 on the red top quarter only: the red bin's
    mean saliency is 0.5 (half of its pixels), the green's 0."""
    img = np.empty((40, 60, 3), np.uint8)
    img[:, :30] = RED
    img[:, 30:] = GREEN
    sal = np.zeros((40, 60), np.float32)
    sal[:20, :30] = 1.0
    eng = DTDMIEngine(DTDMIConfig(colour_propagation=0.5, backend=backend))
    eng.saliency(img, 1_000_000_000)  # allocates at this resolution
    out = propagate_by_colour(sal, img, 0.5, eng._k if eng.numba else None, eng._paint)
    assert out[5, 5] == pytest.approx(0.75)  # 0.5 x 1 + 0.5 x 0.5
    assert out[30, 5] == pytest.approx(0.25)  # 0.5 x 0 + 0.5 x 0.5: the rest of the red half
    assert out[:, 30:].max() == 0.0


def test_presets_keep_their_behaviour_unless_they_choose_a_refinement():
    for name in ("literal", "field"):
        r = resolve(DTDMIConfig(preset=name))
        assert r.colour_propagation == 0.0
    r = resolve(DTDMIConfig(preset="field", colour_propagation=0.3))
    assert r.colour_propagation == 0.3
    assert resolve(DTDMIConfig(preset="aerial")).colour_propagation == 0.0
    assert resolve(DTDMIConfig()).colour_propagation == 0.5  # default: chosen on DAVIS


def test_colour_propagation_changes_the_map_only_when_asked(rng):
    img = rng.randint(0, 256, (48, 64, 3)).astype(np.uint8)
    img[10:20, 10:30] = RED
    maps = []
    for cp in (0.0, 0.5):
        det = DTDMIDetector(DTDMIConfig(colour_propagation=cp, centre_sigma_frac=0.0))
        for i in range(3):
            res = det.detect(_frame(img, i))
        maps.append(res.saliency)
    assert maps[0].max() > 0
    assert not np.allclose(maps[0], maps[1])
    assert 0.0 <= maps[1].min() and maps[1].max() <= 1.0


def _two_boxes(rng: np.random.RandomState, left: bool, right_size: int) -> np.ndarray:
    img = np.empty((120, 200, 3), np.float32)
    img[...] = GREEN
    img += rng.randn(120, 200, 3).astype(np.float32) * 4
    img = np.clip(img, 0, 255).astype(np.uint8)
    if left:
        img[50:60, 30:42] = RED
    img[50:50 + right_size, 150:150 + right_size + 2] = RED
    return img


