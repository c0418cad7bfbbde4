"""Fuzzing frames (tests/fuzz/fuzz_frames.py): any shape, dtype and NaN into the frame checks
and every registered detector."""

from __future__ import annotations

import random

import numpy as np
import pytest
from eaglemission.drivers.cameras.genicam import to_bgr
from fuzz_frames import (
    check_detector,
    check_frame_checks,
    detector_names,
    new_detector,
    random_frame_image,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eaglemission.errors import FrameError

FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])


@settings(FUZZ, max_examples=150)
@given(st.randoms(use_true_random=False))
def test_frame_checks_take_any_array(rand: random.Random) -> None:
    assert check_frame_checks(rand)


@pytest.mark.parametrize("name", detector_names())
@settings(FUZZ, max_examples=6)
@given(rand=st.randoms(use_true_random=False))
def test_detectors_take_any_frame_sequence(name: str, rand: random.Random) -> None:
    det = new_detector(name)
    for seq in range(4):
        assert check_detector(name, det, random_frame_image(rand, max_side=80), seq)


@pytest.mark.parametrize("w,h", [(0, 0), (0, 8), (16, 0)])
def test_an_empty_genicam_buffer_is_a_frame_error(w: int, h: int) -> None:
    """A fuzzing case: a 0-pixel frame is a FrameError before cv2.cvtColor (which raises
    cv2.error on it)."""
    with pytest.raises(FrameError, match="WRONG_SIZE"):
        to_bgr(np.zeros(0, np.uint8), w, h, "BayerRG8")
