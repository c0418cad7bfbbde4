"""The colour model of the target's example image: round trip, background weighting,
exposure."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from eaglemission.errors import InputError
from eaglemission.perception.colour_bins import NBINS, quantize_bgr
from eaglemission.perception.histogram import (
    AppearanceModel,
    appearance_posterior,
    border_mask,
    exposure_gains,
    kernel_weights,
    region_histogram,
    target_histogram,
    validate_example_image,
)

RED = (30, 40, 210)
BLUE = (200, 90, 20)
GREEN = (60, 140, 70)


def _bin(bgr) -> int:
    return int(quantize_bgr(np.array([[bgr]], np.uint8))[0, 0])


def _ground(rng: np.random.RandomState, h: int = 240, w: int = 320) -> np.ndarray:
    img = np.empty((h, w, 3), np.float32)
    img[...] = GREEN
    img += rng.randn(h, w, 3).astype(np.float32) * 6
    return np.clip(img, 0, 255).astype(np.uint8)


def test_posterior_hand_computed():
    q = np.array([0.5, 0.5, 0.0])
    p = np.array([0.9, 0.1, 0.0])
    a = appearance_posterior(q, p, prior=0.1)
    np.testing.assert_allclose(a, [0.5 / (0.5 + 9.0), 0.5 / (0.5 + 1.0), 0.0], rtol=1e-6)
    with pytest.raises(ValueError, match="prior"):
        appearance_posterior(q, p, prior=0.0)


def test_kernel_and_border():
    k = kernel_weights(5, 5)
    assert k[2, 2] == 1.0 and k[0, 0] == 0.0 and k.max() == 1.0
    m = border_mask(20, 10, 0.15)
    assert m[0].all() and m[:, 0].all() and not m[10, 5] and m.sum() == 20 * 10 - 14 * 6


def test_round_trip_crop_finds_its_colour_and_ignores_the_ground(rng):
    frame = _ground(rng)
    frame[100:120, 200:230] = RED
    crop = frame[95:125, 195:235].copy()  # a tight crop with a ground margin
    model = AppearanceModel.from_image(crop, prior=0.01)
    assert model.q.sum() == pytest.approx(1.0)
    # the red bin dominates the model although the crop is ~50 % ground
    assert model.q[_bin(RED)] > 10 * model.q[_bin(GREEN)]
    # back-projected on another frame with the target elsewhere
    other = _ground(rng)
    other[30:50, 40:70] = RED
    other[150:170, 250:280] = BLUE  # a distractor of another colour
    a = model.back_project(other)
    assert a.dtype == np.float32 and a.shape == other.shape[:2]
    assert a[40, 55] > 0.5
    assert float(np.median(a)) < 0.01  # the ground
    assert a[160, 265] == 0.0  # a colour absent from the example


def test_plain_background_photo_is_not_the_model():
    photo = np.full((60, 80, 3), 245, np.uint8)  # a box photographed on white paper
    photo[15:45, 15:65] = BLUE  # the object covers a third of the photo
    q_bg = target_histogram(photo)
    q_flat = target_histogram(photo, border_fraction=0.0)
    white = _bin((245, 245, 245))
    assert q_bg[_bin(BLUE)] > 2 * q_bg[white]
    assert q_bg[white] < 0.5 * q_flat[white]
    # a uniform example is all target
    uniform = target_histogram(np.full((10, 12, 3), BLUE, np.uint8))
    assert uniform[_bin(BLUE)] == pytest.approx(uniform.max())


def test_validate_example_image():
    grey = validate_example_image(np.zeros((4, 5), np.uint8))
    assert grey.shape == (4, 5, 3)
    with pytest.raises(InputError, match="uint8"):
        validate_example_image(np.zeros((4, 4, 3), np.float32))
    with pytest.raises(InputError, match="shape"):
        validate_example_image(np.zeros((4, 4, 4), np.uint8))
    with pytest.raises(InputError, match="numpy array"):
        validate_example_image([[1, 2]])
    with pytest.raises(InputError, match="3x3"):
        validate_example_image(np.zeros((2, 9, 3), np.uint8))


def test_appearance_model_ignores_a_frame_without_the_colour(rng):
    crop = np.full((10, 10, 3), RED, np.uint8)
    model = AppearanceModel.from_image(crop)
    frame = _ground(rng)
    hist = np.bincount(quantize_bgr(frame).ravel(), minlength=NBINS)
    assert float(model.lut(hist).max()) < 1e-3 or model.back_project(frame).max() < 0.05


def test_exposure_gains_cover_the_span_in_steps_under_one_bin():
    assert exposure_gains(1.0).tolist() == [1.0]
    g = exposure_gains(1.5)
    assert g[0] == pytest.approx(1 / 1.5) and g[-1] == pytest.approx(1.5)
    assert np.any(np.isclose(g, 1.0)) and len(g) % 2 == 1
    assert np.all(g[1:] / g[:-1] <= 1.05 + 1e-12)
    with pytest.raises(ValueError, match="span"):
        exposure_gains(0.9)
    with pytest.raises(InputError, match="exposure span"):
        AppearanceModel.from_image(np.full((8, 8, 3), RED, np.uint8), exposure_span=5.0)


@pytest.mark.parametrize("gain", [0.7, 0.85, 1.15, 1.4])
def test_exposure_span_finds_the_target_under_other_light(rng, gain):
    """The example is taken at one exposure; the frame's light is dimmer or brighter. The
    exact colours miss the target (a 4-bit bin is 16 levels); the span's model does not, and
    still ignores the ground."""
    frame = _ground(rng)
    frame[100:130, 200:240] = RED
    crop = frame[95:135, 195:245].copy()
    dim = cv2.convertScaleAbs(frame, alpha=gain)
    exact = AppearanceModel.from_image(crop, prior=0.1, pool=False)
    spanned = AppearanceModel.from_image(crop, prior=0.1, pool=False, exposure_span=1.5)
    on, off = np.zeros(frame.shape[:2], bool), np.ones(frame.shape[:2], bool)
    on[104:126, 204:236] = True
    off[90:140, 190:250] = False
    assert np.median(exact.back_project(dim)[on]) < 0.05
    assert np.median(spanned.back_project(dim)[on]) > 0.2
    assert np.percentile(spanned.back_project(dim)[off], 99) < 0.05
    # the frame's exposure is found, and a region of the dimmed target matches the example there
    counts = np.bincount(quantize_bgr(dim).ravel(), minlength=NBINS)
    k = spanned.select(counts)
    assert abs(np.log(exposure_gains(1.5)[k] / gain)) < np.log(1.1)
    region = np.array([[200.0, 100.0], [239.0, 100.0], [239.0, 129.0], [200.0, 129.0]])
    hist = region_histogram(dim, region, pool=False)
    assert spanned.match(hist, k) > 0.9 > exact.match(hist) + 0.3


def test_exposure_stays_at_gain_one_in_the_example_s_light(rng):
    frame = _ground(rng)
    frame[100:130, 200:240] = RED
    spanned = AppearanceModel.from_image(frame[95:135, 195:245].copy(), prior=0.1, pool=False,
                                         exposure_span=1.5)
    counts = np.bincount(quantize_bgr(frame).ravel(), minlength=NBINS)
    assert spanned.select(counts) == spanned.unit
    assert exposure_gains(1.5)[spanned.unit] == pytest.approx(1.0)
    np.testing.assert_array_equal(spanned.q, spanned.q_exposures[spanned.unit])
