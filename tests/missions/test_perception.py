"""Perception of one frame (missions/perception.py): which estimator answered, whether a plane
fit replaced its position, what counts as a fine measurement. Small real plugins stand in for
the detector and the estimators; the plane fitter is the real ``top_plane``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eaglemission.estimators.top_plane import TopPlaneFitter
from eaglemission.missions.approach_config import PerceptionConfig
from eaglemission.missions.perception import (
    Perception,
    Provenance,
    Request,
    Tools,
    follow_candidate,
    inside_polygon,
)
from eaglemission.missions.target_state import PlaneState
from world_helpers import approach_pose, detection_from_polygon

from eaglemission.geometry import camera_pose_ned
from eaglemission.perception.appearance import TargetAppearance
from eaglemission.perception.keep import box_detection
from eaglemission.types import DetectionResult, EstimationFailed, Frame, TargetEstimate


class OneDetection:
    """A detector that always reports the same detection."""

    def __init__(self, det):
        self.det = det

    def detect(self, frame, prior=None):
        return DetectionResult(np.zeros(frame.image.shape[:2], np.float32), (self.det,),
                               frame.timestamp_ns, frame.camera_id, frame.seq)

    def reset(self):
        pass


class FixedEstimator:
    """Answers one position (or refuses) whatever the detection."""

    def __init__(self, position=None, source="fixed", std_m=0.4):
        self.position, self.source, self.std_m = position, source, std_m

    def estimate(self, detection, view):
        if self.position is None:
            return EstimationFailed("refused on purpose")
        return TargetEstimate(self.position, (0.0, 0.0, 3.0), view.timestamp_ns,
                              detection.camera_id, self.source, std_m=self.std_m)


@pytest.fixture
def scene(sitl_config):
    """The narrow camera 3 m from the target, its top face's outline as the detection."""
    model = sitl_config.cameras.narrow.to_model("narrow")
    target = sitl_config.target
    top = np.array([20.0, 1.0, -target.height_m])
    pos, q = approach_pose(top, 3.0, 35.0, 10.0)
    cam = camera_pose_ned(model, pos, q)
    corners = []
    for x, y in ((0.2, -0.125), (0.2, 0.125), (-0.2, 0.125), (-0.2, -0.125)):
        corners.append(top + (x, y, 0.0))
    px = model.project(cam.inverse().apply(np.asarray(corners)))
    det = detection_from_polygon(px, "narrow")
    from eaglemission.types import VehicleState

    state = VehicleState(10**9, tuple(pos), (0.0, 0.0, 0.0), tuple(q))
    frame = Frame(np.zeros((model.height_px, model.width_px, 3), np.uint8), 10**9, "narrow", 1)
    return model, target, top, det, state, frame


def _perceive(scene, coarse, fine, *, fitter=True, params=None, estimator="fine",
              thumbnails=True):
    model, target, top, det, state, frame = scene
    p = params or PerceptionConfig()
    tools = Tools(OneDetection(det), coarse, fine,
                  TopPlaneFitter(target=target) if fitter else None, None)  # no colour model
    req = Request(frame, model, state, estimator, None, True, None, PlaneState(0.0, 0.04))
    return Perception(p, target, thumbnails=thumbnails).perceive(req, tools)


def test_the_saliency_thumbnail_is_made_only_for_a_recording(scene) -> None:
    est = FixedEstimator((0.0, 0.0, 0.0))
    m = _perceive(scene, est, est)
    assert m.saliency_thumb is not None and m.saliency_thumb.dtype == np.uint8
    assert _perceive(scene, est, est, thumbnails=False).saliency_thumb is None


def test_a_fine_estimate_refined_by_the_plane_fit(scene) -> None:
    top = scene[2]
    m = _perceive(scene, FixedEstimator((0.0, 0.0, 0.0)), FixedEstimator((9.0, 9.0, 9.0)))
    assert m.provenance is Provenance.FINE and m.refined and m.fine_measurement
    # the position is the fit's (the estimators' values were far off), near the true top
    assert math.dist(m.estimate.position_ned_m, top) < 0.05
    assert m.estimate.source.startswith("fixed+fit:")


def test_a_fallback_keeps_its_provenance_and_without_a_fitter_its_down_weighting(scene) -> None:
    """The provenance is typed, not read from the source's name: a fallback stays FALLBACK; the
    plane fit's position (from the detection) counts as a fine measurement, weighted by the
    fit; an unrefined fallback is the coarse estimate, down-weighted, and does not count."""
    params = PerceptionConfig(fallback_std_factor=3.0)
    coarse = FixedEstimator((20.1, 1.1, -0.15), source="bearing", std_m=0.3)
    refined = _perceive(scene, coarse, FixedEstimator(None), params=params)
    assert refined.provenance is Provenance.FALLBACK and refined.refined
    assert refined.fine_measurement
    assert refined.estimate.std_m < 0.3  # the fit's, not 3 x the coarse one's
    plain = _perceive(scene, coarse, FixedEstimator(None), params=params, fitter=False)
    assert plain.provenance is Provenance.FALLBACK and not plain.refined
    assert not plain.fine_measurement and not plain.full_3d
    assert plain.estimate.std_m == pytest.approx(0.9)
    assert plain.estimate.position_ned_m == (20.1, 1.1, -0.15)


def test_without_a_fitter_the_estimators_positions_are_flown(scene) -> None:
    """Swapping estimators by config changes the flight: with ``estimators.fitter: null`` the
    estimator's own position is used (the plane fit replaces every estimator's position)."""
    a = _perceive(scene, FixedEstimator((0.0, 0.0, 0.0)), FixedEstimator((20.2, 1.0, -0.15)),
                  fitter=False)
    b = _perceive(scene, FixedEstimator((0.0, 0.0, 0.0)), FixedEstimator((19.0, 2.0, -0.15)),
                  fitter=False)
    assert a.estimate.position_ned_m != b.estimate.position_ned_m
    fa = _perceive(scene, FixedEstimator((0.0, 0.0, 0.0)), FixedEstimator((20.2, 1.0, -0.15)))
    fb = _perceive(scene, FixedEstimator((0.0, 0.0, 0.0)), FixedEstimator((19.0, 2.0, -0.15)))
    assert fa.estimate.position_ned_m == fb.estimate.position_ned_m


def test_no_estimator_no_estimate_and_a_refusal_says_why(scene) -> None:
    m = _perceive(scene, FixedEstimator(None), FixedEstimator(None))
    assert m.estimate is None and m.failure == "refused on purpose"
    assert m.detection is not None and m.raw_detections == 1
    d = _perceive(scene, FixedEstimator((0, 0, 0)), FixedEstimator((0, 0, 0)), estimator=None)
    assert d.estimate is None and d.failure is None and d.provenance is None


@pytest.mark.parametrize("predicted_on_target,fragment", [(True, False), (True, True),
                                                          (False, False)])
def test_close_range_prefers_the_colour_region_that_agrees_with_the_detection(
        scene, predicted_on_target, fragment) -> None:
    """Close range, a fine estimate asked: the target colour's region (the real
    :class:`TargetAppearance`) comes before the detector's region when one centre lies in the
    other's MBR (one box fit on the region that follows the target's edges); a region of the
    target's colour elsewhere (300 px above, where the prediction points) does not.
    ``fragment``: the detector's region is the lower third of the target, as a saliency region
    at the narrow image's bottom border near the grasp pose can be; the colour region's centre
    lies outside it (a fit of the fragment alone ends the grasp centimetres off)."""
    import cv2

    from eaglemission.perception.appearance import TargetAppearance

    model, target, top, det, state, frame = scene
    image = frame.image.copy()
    poly = np.asarray(det.corners_px, np.float64)
    colour = tuple(int(c) for c in target.color_bgr)
    if not predicted_on_target:  # the target painted, and a patch of its colour elsewhere
        cv2.fillPoly(image, [np.round(poly).astype(np.int32)], colour)
        poly = poly + (0.0, -300.0)  # clear of the target's outline, inside the gate
    outline_centre = det.center_px
    if fragment:  # the lowest third of the painted outline (image v grows downwards)
        v_cut = poly[:, 1].max() - (poly[:, 1].max() - poly[:, 1].min()) / 3.0
        low = cv2.intersectConvexConvex(
            poly.astype(np.float32), np.array([[-1e4, v_cut], [1e4, v_cut], [1e4, 1e4],
                                               [-1e4, 1e4]], np.float32))[1].reshape(-1, 2)
        det = detection_from_polygon(cv2.boxPoints(cv2.minAreaRect(low)), "narrow")
        assert not inside_polygon(tuple(poly.mean(axis=0)), det.corners_px)
    cv2.fillPoly(image, [np.round(poly).astype(np.int32)], colour)
    frame = Frame(image, frame.timestamp_ns, frame.camera_id, frame.seq)
    appearance = TargetAppearance.of_target(target)
    tools = Tools(OneDetection(det), FixedEstimator((0.0, 0.0, 0.0)),
                  FixedEstimator((9.0, 9.0, 9.0)), None, appearance)
    centre = tuple(float(x) for x in poly.mean(axis=0))
    req = Request(frame, model, state, "fine", centre, True, None, PlaneState(0.0, 0.04))
    m = Perception(PerceptionConfig(), target).perceive(req, tools)
    assert m.colour_tracked is predicted_on_target
    assert m.detection is not None
    if predicted_on_target:
        assert m.detection is not det and m.detection.hull_px is not None
        np.testing.assert_allclose(m.detection.center_px, outline_centre, atol=3.0)
    else:
        assert m.detection is det


def _textured_patch(seed: int, size: int = 30) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 255, (size, size, 3), dtype=np.uint8)


def test_a_candidate_is_followed_on_its_box_then_by_its_example_then_dropped() -> None:
    example = _textured_patch(1)
    image = np.full((240, 320, 3), 90, np.uint8)
    image[100:130, 200:230] = example  # the candidate, moved 4 px right since its last box
    appearance = TargetAppearance(image=example)
    frame = Frame(image, 1, "wide", 1)
    box = (196.0, 100.0, 226.0, 130.0)
    on_it = box_detection((200, 100, 230, 130), "wide", score=0.5)
    elsewhere = box_detection((20, 20, 50, 50), "wide", score=1.0)
    result = DetectionResult(np.zeros((240, 320), np.float32), (elsewhere, on_it), 1, "wide", 1)

    def anything(d):
        return True

    # a detection on the candidate's box wins over a better-ranked one elsewhere
    assert follow_candidate(result, box, frame, appearance, anything, 0.5) is on_it
    # no detection on it: the example found again next to the box
    only_elsewhere = DetectionResult(result.saliency, (elsewhere,), 1, "wide", 1)
    found = follow_candidate(only_elsewhere, box, frame, appearance, anything, 0.5)
    assert found is not None
    assert found.center_px == pytest.approx((214.5, 114.5), abs=1.5)
    # the candidate gone (plain ground where it was): None, the search starts over
    gone = Frame(np.full((240, 320, 3), 90, np.uint8), 2, "wide", 2)
    assert follow_candidate(only_elsewhere, box, gone, appearance, anything, 0.5) is None
    # without an example image only a detection on the box follows it
    assert follow_candidate(only_elsewhere, box, frame, None, anything, None) is None


class NoDetections:
    """A detector that finds nothing (the target fills the view at close range)."""

    def detect(self, frame, prior=None):
        return DetectionResult(np.zeros(frame.image.shape[:2], np.float32), (),
                               frame.timestamp_ns, frame.camera_id, frame.seq)

    def reset(self):
        pass


class DriftingTracker:
    """A tracker whose every update answers one box (the box it drifted to)."""

    def __init__(self, drifted):
        self.drifted, self.starts = drifted, []

    def start(self, frame, box_px):
        self.starts.append(tuple(box_px))

    def update(self, frame):
        return self.drifted


@pytest.mark.parametrize("drift_px", [0.0, 200.0])
def test_close_range_measures_the_colour_region_where_the_trackers_box_drifted_off_it(
        scene, drift_px) -> None:
    """At close range, the detector finding nothing: the tracker's box kept the target so far,
    and on this frame it moved ``drift_px`` to the right, off the target's colour region. The
    region near the kept box is measured (not the tracker's box), it becomes the kept box and
    the tracker restarts on it once the two overlap little."""
    import cv2

    from eaglemission.perception.keep import KeepConfig, TargetKeeper, box_of

    model, target, top, det, state, frame = scene
    image = frame.image.copy()
    poly = np.round(np.asarray(det.corners_px, np.float64)).astype(np.int32)
    cv2.fillPoly(image, [poly], tuple(int(c) for c in target.color_bgr))
    frame = Frame(image, frame.timestamp_ns, frame.camera_id, frame.seq)
    on_target = box_of(det)
    u0, v0, u1, v1 = on_target
    drifted = (u0 + drift_px, v0, u1 + drift_px, v1)
    tracker = DriftingTracker(drifted)
    keeper = TargetKeeper(tracker, KeepConfig(confirm_frames=1, detect_every_frames=1))
    keeper.step(frame, det, True)  # confirmed on the target: the tracker starts there
    assert keeper.keeping and tracker.starts == [on_target]
    tools = Tools(NoDetections(), FixedEstimator((0.0, 0.0, 0.0)),
                  FixedEstimator((9.0, 9.0, 9.0)), None, TargetAppearance.of_target(target),
                  keeper)
    req = Request(frame, model, state, "fine", None, True, None, PlaneState(0.0, 0.04))
    m = Perception(PerceptionConfig(), target).perceive(req, tools)
    assert m.colour_tracked and m.estimate is not None and not m.from_tracker
    np.testing.assert_allclose(m.detection.center_px, det.center_px, atol=3.0)
    assert m.estimate.position_ned_m == (9.0, 9.0, 9.0)  # the fine estimator's, on the region
    np.testing.assert_allclose(keeper.box, box_of(m.detection))
    if drift_px:
        assert len(tracker.starts) == 2  # restarted on the region
        np.testing.assert_allclose(tracker.starts[-1], box_of(m.detection))
    else:
        assert len(tracker.starts) == 1  # on the region already: it goes on

