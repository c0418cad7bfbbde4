"""DTDMI ``field`` preset: its equations, backends, and a static ground target in the synthetic
world (wide camera at reduced resolution): found during cruise and hover, quiet without it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.detectors.dtdmi import DTDMIConfig, DTDMIDetector
from eaglemission.detectors.dtdmi import equations as eq
from eaglemission.detectors.dtdmi.config import resolve
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import SyntheticWorldConfig

from eaglemission.config import TargetConfig
from eaglemission.geometry import CameraModel, CameraMount, euler_to_quat
from eaglemission.types import Frame

W, H = 320, 240
FPS = 30.0


# -- equations ---------------------------------------------------------------------------------
def test_lalphabeta_grey_is_achromatic_and_red_green_have_opposite_beta():
    lms = eq.rgb_to_lms(eq.srgb_to_linear(np.array([[0.5, 0.5, 0.5], [0.8, 0.15, 0.1],
                                                    [0.2, 0.5, 0.2]])))
    lab = eq.lms_to_lalphabeta(lms)
    # Eq. (1)'s rows sum to 1.0, 0.9993, 0.9973: grey is achromatic to within ~1e-3.
    assert np.all(np.abs(lab[0, 1:]) < 2e-3)
    assert lab[1, 2] > 0.1 and lab[2, 2] < -0.02  # beta = (log L - log M) / sqrt(2)
    # l = (log L + log M + log S) / sqrt(3)
    np.testing.assert_allclose(lab[:, 0], np.log10(lms).sum(axis=1) / math.sqrt(3), rtol=1e-12)


def test_srgb_decoding_hand_values():
    np.testing.assert_allclose(eq.srgb_to_linear([0.0, 0.04045, 0.5, 1.0]),
                               [0.0, 0.04045 / 12.92, 0.21404114, 1.0], rtol=1e-6)


def test_bin_contrast_at_the_cluster_means_is_eq2():
    rng = np.random.RandomState(5)
    centres = rng.rand(6, 3)
    counts = rng.randint(1, 100, 6).astype(float)
    # rtol 1e-7: the distances come from ||f||^2 + ||c||^2 - 2 f.c (a bin at a centre: ~1e-8)
    np.testing.assert_allclose(eq.bin_contrast_cue(centres, centres, counts),
                               eq.contrast_cue(centres, counts), rtol=1e-7)
    assert np.all(eq.bin_contrast_cue(centres, centres, np.zeros(6)) == 0)


def test_distribution_cue_hand_computed():
    # bin 0: pixels at (col, row) (0, 0) and (2, 0): variance 1, spread 1 px;
    # bin 1: one pixel (spread 0); bin 2: empty.
    mom = np.array([[2.0, 0.0, 4.0, 0.0], [5.0, 7.0, 25.0, 49.0], [0.0, 0.0, 0.0, 0.0]])
    n = np.array([2.0, 1.0, 0.0])
    cue = eq.distribution_cue(mom, n, diag_px=10.0, sigma_frac=0.1)
    np.testing.assert_allclose(cue, [math.exp(-1.0), 1.0, 0.0], rtol=1e-12)


def test_boost_fusion_leaves_static_map_when_nothing_moves():
    s_s = np.array([[0.2, 0.5]])
    np.testing.assert_array_equal(eq.boosted_saliency(s_s, np.zeros((1, 2)), 3.0), s_s)
    np.testing.assert_allclose(eq.boosted_saliency(s_s, np.array([[1.0, 0.0]]), 3.0),
                               [[0.8, 0.5]])


def test_field_knobs_do_not_touch_the_other_presets():
    for preset in ("literal", "default"):
        r = resolve(DTDMIConfig(preset=preset))
        assert (r.fusion, r.spread_sigma_frac, r.colour_space) == ("product", 0.0, "lms")
    r = resolve(DTDMIConfig(preset="field"))
    assert (r.fusion, r.colour_space, r.centre_sigma_frac, r.output_scale) == (
        "boost", "lalphabeta", 0.0, "absolute")


# -- the synthetic world -----------------------------------------------------------------------
def _setup(texture: str):
    model = CameraModel.from_lens(
        "wide", focal_length_mm=2.8, pixel_size_um=3.75 * 1280 / W, resolution_px=(W, H),
        mount=CameraMount(pitch_deg=-30.0, lever_arm_m=(0.10, -0.03, 0.05)))
    target = TargetConfig(length_m=0.40, width_m=0.25, height_m=0.15, color_bgr=(30, 40, 210))
    sim = SyntheticWorldConfig(seed=3, target_north_m=12.0, target_east_m=0.8, target_yaw_deg=20.0,
                           noise_sigma=2.0, frame_rate_hz=FPS, ground_texture=texture)
    world = SyntheticWorld(sim, target, seed=3, extent_m=60.0)
    empty = SyntheticWorld(sim.model_copy(update={"target_north_m": -30.0}), target, seed=3,
                           extent_m=60.0)
    return model, world, empty


def _poses():
    """Cruise north at 3 m/s from 6 m to 4.5 m short of the target, then hover, 5 m up."""
    for i in range(8):
        yield i, (3.0 + 0.1 * i, 0.0, -5.0), euler_to_quat(0.0, 0.0, 0.0)
    for i in range(8, 12):
        yield i, (3.8, 0.0, -5.0), euler_to_quat(0.1 * (i - 10), 0.0, 0.0)


def _on_target(det, poly, margin_px=3.0) -> bool:
    import cv2

    d = cv2.pointPolygonTest(np.asarray(poly, np.float32).reshape(-1, 1, 2),
                             (float(det.center_px[0]), float(det.center_px[1])), True)
    return d >= -margin_px


@pytest.mark.parametrize("texture", ["vegetation", "grass"])
def test_field_finds_the_static_ground_target_and_is_quiet_without_it(texture):
    model, world, empty = _setup(texture)
    det = DTDMIDetector(DTDMIConfig(preset="field"))
    det_free = DTDMIDetector(DTDMIConfig(preset="field"))
    default = DTDMIDetector(DTDMIConfig(centre_sigma_frac=0.0))
    visible = found = found_default = false_dets = 0
    for i, pos, q in _poses():
        stamp = int(1e9 + i * 1e9 / FPS)
        img, truth = world.render(model, pos, q, stamp)
        img_free, _ = empty.render(model, pos, q, stamp)
        res = det.detect(Frame(img, stamp, "wide", i))
        res_default = default.detect(Frame(img, stamp, "wide", i))
        false_dets += len(det_free.detect(Frame(img_free, stamp, "wide", i)).detections)
        if truth.target_visible:
            visible += 1
            found += bool(res.detections) and _on_target(res.detections[0],
                                                         truth.target_polygon_px)
            found_default += bool(res_default.detections) and _on_target(
                res_default.detections[0], truth.target_polygon_px)
    assert visible >= 10
    assert found >= visible - 1, f"field found the target in {found}/{visible} frames"
    assert false_dets == 0
    # the reason for the preset: the DAVIS default (product with S_M) misses it
    assert found_default < visible // 2


def test_field_numba_equals_numpy_backend():
    model, world, _ = _setup("soil")
    dets = {b: DTDMIDetector(DTDMIConfig(preset="field", backend=b)) for b in ("numba", "numpy")}
    for i, pos, q in list(_poses())[:4]:
        stamp = int(1e9 + i * 1e9 / FPS)
        img, _ = world.render(model, pos, q, stamp)
        maps = {b: d.saliency(Frame(img, stamp, "wide", i)) for b, d in dets.items()}
        np.testing.assert_allclose(maps["numba"], maps["numpy"], atol=1e-5)


def test_pool_colour_bins_sums_the_26_neighbours():
    v = np.zeros(4096)
    corner, far, inner = 0, 4095, (5 << 8) | (5 << 4) | 5
    v[corner], v[far], v[inner] = 1.0, 2.0, 1.0
    from eaglemission.perception.colour_bins import pool_colour_bins

    p = pool_colour_bins(v)
    assert p.sum() == 8 * 1.0 + 8 * 2.0 + 27 * 1.0  # corners have 7 neighbours, inner 26
    assert p[(6 << 8) | (6 << 4) | 6] == 1.0 and p[(7 << 8) | (5 << 4) | 5] == 0.0
    assert p[corner] == 1.0 and p[(1 << 8) | (1 << 4) | 1] == 1.0
    cols = pool_colour_bins(np.stack([v, 2 * v], axis=1))
    np.testing.assert_array_equal(cols[:, 1], 2 * p)
