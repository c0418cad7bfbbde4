"""The fused numba kernels equal the plain numpy equations within 1e-5 (small images)."""

from __future__ import annotations

import numpy as np
import pytest
from dtdmi_scenes import moving_scene
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi.kernels import midbrain_step_fused
from eaglemission.detectors.dtdmi.midbrain_step import midbrain_step_numpy


@pytest.mark.parametrize("radius", [0, 1, 2, 5])
def test_fused_step_equals_numpy_reference(radius):
    rng = np.random.RandomState(21)
    h, w = 23, 37  # odd sizes: borders on every side
    gd_a = np.zeros((h, w), np.float32)
    gp_a = np.zeros((h, w), np.float32)
    gd_b, gp_b = gd_a.copy(), gp_a.copy()
    o = np.zeros((h, w), np.float32)
    sm_b = np.zeros((h, w), np.float32)
    for i, gain in enumerate([0.0, 0.3, 0.5, 1.0]):
        grey = rng.rand(h, w).astype(np.float32)
        tau = np.inf if gain == 0 else 1.0 / gain
        sm_a, gd_a, gp_a = midbrain_step_numpy(grey, gd_a, gp_a, tau, radius, 1e-20)
        midbrain_step_fused(grey, gd_b, gp_b, gain, radius, o, sm_b, 1e-20)
        np.testing.assert_allclose(gd_b, gd_a, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(gp_b, gp_a, rtol=1e-5, atol=1e-7)
        scale = max(float(sm_a.max()), 1e-30)
        np.testing.assert_allclose(sm_b / scale, sm_a / scale, rtol=1e-5, atol=1e-5)
        if i > 0:
            assert sm_a.max() > 0


@pytest.mark.parametrize("preset", ["literal", "default"])
def test_detector_numba_and_numpy_backends_agree(preset):
    rng = np.random.RandomState(22)
    scene = moving_scene(rng, n=4, h=40, w=56, size=10)
    a = DTDMIDetector(DTDMIConfig(preset=preset, backend="numpy"))
    b = DTDMIDetector(DTDMIConfig(preset=preset, backend="numba"))
    for f, _ in scene:
        np.testing.assert_allclose(b.saliency(f), a.saliency(f), atol=1e-5)
