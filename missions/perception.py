"""Perception of one frame, one pipeline of named stages (paper Sec. 3.2 and the additions
docs/architecture.md lists, "Perception"). Pure given its inputs; it runs in a worker thread and
returns an immutable :class:`Measurement`, the only thing that crosses back to the event loop.

1. **detect** (:func:`detect`): the camera's detector (``Detector``; with an example image of
   the target, followed by the appearance prior: :mod:`eaglemission.perception.prior`), on
   every frame while searching, every few frames while a target is kept (every frame at close
   range); a map that is not finite is an anomaly and gives no detections.
2. **choose the target**: the detector's candidate (:func:`choose_detection`: the plausible
   detection nearest the predicted pixel, its size from the camera's pose, the target's
   colour); once confirmed, the keeper keeps it between the detector's frames with a tracker
   (:mod:`eaglemission.perception.keep`); at close range the region of the target's colour
   (:func:`target_candidates`): the candidates in order of preference, each with where it came
   from.
3. **measure its pose** (:meth:`Perception.measure`): the state's estimator (``Estimator``: fine,
   or a down-weighted coarse FALLBACK when the fine one refuses), then the fit of the target's box
   on the plane of its top (``PlaneFitter``, with the apparent-size range at close range; none
   when the ``estimators.fitter`` section is null) gives the position; the first candidate that
   yields a measurement is the frame's.

Filtering over time is :mod:`.tracking`'s.
"""

from __future__ import annotations

import enum
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import cv2
import numpy as np
from eaglemission.missions.approach_config import PerceptionConfig
from eaglemission.missions.target_state import (
    PlaneState,
    fit_std_m,
    plane_down_m,
    size_range_scale,
)
from numpy.typing import NDArray

from eaglemission.config import TargetConfig
from eaglemission.geometry import CameraModel, camera_pose_ned
from eaglemission.interfaces import CameraView, Detector, Estimator, PlaneFitter
from eaglemission.perception.appearance import TargetAppearance
from eaglemission.perception.keep import TargetKeeper, box_detection, box_of, on_box
from eaglemission.recording.foxglove import saliency_thumbnail
from eaglemission.types import (
    Detection,
    DetectionResult,
    Frame,
    TargetEstimate,
    TargetPrior,
    VehicleState,
)


class Provenance(enum.Enum):
    """Which estimator accepted the detection (a plane fit may then replace its position:
    ``Measurement.refined``; the provenance stays what it was)."""

    COARSE = "coarse"
    FINE = "fine"
    FALLBACK = "fallback"
    """The fine estimator refused the detection; the coarse one's estimate, down-weighted."""


@dataclass(frozen=True, slots=True)
class FitHint:
    """Heading and region model of the last complete close view: they constrain cut views
    (the heading is the colour outline's when it fits the target, ``silhouette_yaw_deg``, else
    the plane fit's).
    ``silhouette_iou``: how well the target's shape explains that view's region outline
    (:attr:`~eaglemission.types.PlaneFit.silhouette_iou`), for the shape check."""

    yaw_deg: float
    region: str
    silhouette_iou: float | None = None
    silhouette_yaw_deg: float | None = None
    span_deg: float | None = None
    """Cut views are fitted within +- this of ``yaw_deg`` (None: the fitter's step)."""


def colour_outline(det: Detection, frame: Frame, appearance: TargetAppearance | None,
                   tracked: bool) -> NDArray[np.float64] | None:
    """The outline the shape check compares with the target's (``silhouette_iou``): that of the
    target colour's region, the whole silhouette (the top and the shaded sides share its
    chromaticity), not the detector's region (a saliency threshold may cut a shaded face:
    measured, true targets' outlines then fit at IoU ~0.7); the colour region must be the
    detection's object (its centre inside the detection's MBR). None without the target's
    colour (the check is then not made)."""
    if appearance is None or not appearance.has_colour:
        return None
    col = det if tracked else appearance.colour_region(frame, det.center_px)
    if col is None or col.hull_px is None:
        return None
    if not inside_polygon(col.center_px, det.corners_px):
        return None
    hull: NDArray[np.float64] = np.asarray(col.hull_px, dtype=np.float64)
    return hull


@dataclass(frozen=True, slots=True)
class Tools:
    """The plugins perception uses for one camera."""

    detector: Detector
    coarse: Estimator
    fine: Estimator
    fitter: PlaneFitter | None = None
    appearance: TargetAppearance | None = None
    keeper: TargetKeeper | None = None
    """Keeps the confirmed target between the detector's frames (None: the detector on every
    frame alone); its state is this camera's, touched only by its perception."""


@dataclass(frozen=True, slots=True)
class Request:
    """Everything one frame's perception needs, frozen on the loop thread."""

    frame: Frame
    model: CameraModel
    state: VehicleState | None
    """The vehicle's estimated state at the frame's mid-exposure (None: outside the history)."""
    estimator: str | None
    """``"coarse"``, ``"fine"`` or None (detect only)."""
    predicted_px: tuple[float, float] | None
    close_range: bool
    fit_hint: FitHint | None
    plane: PlaneState
    keep_epoch: int = 0
    """Changes when the mission drops its target (lost, rejected): the keeper lets it go."""
    candidate_box: tuple[float, float, float, float] | None = None
    """While searching, the keeper's candidate awaiting confirmation (followed first)."""
    occluder_px: NDArray[np.float32] | None = None
    """Where the arm's tool covers this camera's view (a convex polygon; None: nowhere): the
    plane fit leaves it out of its models."""


@dataclass(frozen=True, slots=True)
class Measurement:
    """What one frame gave. ``estimate`` is None with ``failure`` saying why (or nothing was
    asked); ``fit_hint`` is a new hint from a complete close view."""

    camera_id: str
    frame: Frame
    state: VehicleState | None
    role: str | None
    """The request's estimator role (``"coarse"``, ``"fine"`` or None)."""
    detection: Detection | None
    raw_detections: int
    colour_tracked: bool
    estimate: TargetEstimate | None
    provenance: Provenance | None
    refined: bool
    """The position is the plane fit of the detection (not the estimator's own)."""
    failure: str | None
    fit_hint: FitHint | None
    perception_ms: float
    anomaly: str | None = None
    """What was wrong with the detector's output (a non-finite map): its detections ignored."""
    saliency_thumb: NDArray[np.uint8] | None = None
    """The detector's map, 160 px wide, 0..255 (recordings: ``/camera/<id>/saliency``; None
    when nothing records it)."""
    detector_ran: bool = True
    """The detector ran on this frame (while keeping, it re-checks every few frames)."""
    kept: bool = False
    """``detection`` is the keeper's confirmed target (else a candidate, or nothing)."""
    from_tracker: bool = False
    """``detection`` is the tracker's box (the detector did not run, or had nothing on it)."""

    @property
    def fine_measurement(self) -> bool:
        """A close-range position to trust: the fine estimator's, or any plane fit of the
        detection (a fallback the fit explains is as good: docs/mission.md, "fallbacks")."""
        return self.estimate is not None and (self.provenance is Provenance.FINE or self.refined)

    @property
    def full_3d(self) -> bool:
        """The estimate may be used in full 3-D close in (a PnP pose or a plane fit with the
        apparent-size range), not only as a direction."""
        return (self.estimate is not None and self.estimate.full_3d
                and (self.provenance is Provenance.FINE or self.refined))


def touches_border(det: Detection, width_px: int, height_px: int, border_px: float) -> bool:
    c = det.corners_px
    return bool((c[:, 0] < border_px).any() or (c[:, 1] < border_px).any()
                or (c[:, 0] > width_px - 1 - border_px).any()
                or (c[:, 1] > height_px - 1 - border_px).any())


def expected_area_px(model: CameraModel, state: VehicleState, center_px: tuple[float, float],
                     length_m: float, width_m: float, height_m: float) -> float | None:
    """Image area a target of this size would have if it were where the detection's centre ray
    meets the plane of its top face (flat ground); None when the ray does not meet it."""
    pose = camera_pose_ned(model, state.position_ned_m, state.attitude_q)
    ray = pose.R @ model.rays_optical(np.asarray([center_px], dtype=np.float64))[0]
    drop = -height_m - float(pose.t[2])
    if ray[2] <= 1e-3 or drop <= 0:
        return None
    dist = drop / float(ray[2])
    sin_el = float(ray[2])
    cos_el = math.sqrt(max(0.0, 1.0 - sin_el * sin_el))
    f2 = model.fx * model.fy
    return f2 * (length_m * width_m * sin_el + max(length_m, width_m) * height_m * cos_el) / dist**2


def plausible_size(det: Detection, model: CameraModel, state: VehicleState | None,
                   target: TargetConfig, lo: float = 0.2, hi: float = 5.0) -> bool:
    """The paper filters the MBR by the target's known size and shape; with the camera's pose
    the expected size is known at every pixel (ray to the target plane)."""
    if state is None:
        return True
    exp = expected_area_px(model, state, det.center_px, target.length_m, target.width_m,
                           target.height_m)
    if exp is None:
        return False
    return lo * exp <= det.area_px <= hi * exp


def select_detection(result: DetectionResult, predicted_px: tuple[float, float] | None,
                     width_px: int, height_px: int, border_px: float, gate_px: float,
                     plausible: Callable[[Detection], bool] | None = None,
                     allow_cut: bool = False,
                     match: Callable[[Detection], float] | None = None,
                     match_min: float = 0.0) -> Detection | None:
    """The detection to use: the one nearest the predicted target pixel when there is a
    prediction (within ``gate_px``), else the one ``match`` scores highest when that score
    reaches ``match_min``, else the best-ranked; truncated ones (unless ``allow_cut``) and
    (with ``plausible``, a predicate) ones of an impossible size are skipped."""
    dets = [d for d in result.detections
            if (allow_cut or not touches_border(d, width_px, height_px, border_px))
            and (plausible is None or plausible(d))]
    if not dets:
        return None
    if predicted_px is not None and np.isfinite(predicted_px).all():
        dist = [math.hypot(d.center_px[0] - predicted_px[0], d.center_px[1] - predicted_px[1])
                for d in dets]
        i = int(np.argmin(dist))
        return dets[i] if dist[i] <= gate_px else None
    if match is not None:
        scores = [match(d) for d in dets]
        i = int(np.argmax(scores))
        if scores[i] >= match_min:
            return dets[i]
    return dets[0]


def regions_agree(a: Detection, b: Detection) -> bool:
    """One region's centre lies inside the other's MBR: the same object, whole or in part (near
    the grasp pose a saliency region can be a fragment of the target at the image border, whose
    centre is then outside the fragment; each centre inside the other refused the colour
    region there: docs/mission.md, "Design choices", "Blind final metres")."""
    return (inside_polygon(a.center_px, b.corners_px)
            or inside_polygon(b.center_px, a.corners_px))


def inside_polygon(point_px: tuple[float, float], corners_px: NDArray[np.float64]) -> bool:
    """``point_px`` inside or on the polygon ``corners_px`` ((N, 2) u, v)."""
    poly = np.asarray(corners_px, dtype=np.float32).reshape(-1, 1, 2)
    return cv2.pointPolygonTest(poly, (float(point_px[0]), float(point_px[1])), False) >= 0


Measured = tuple[TargetEstimate | None, "Provenance | None", bool, str | None, "FitHint | None"]
"""What :meth:`Perception.measure` gives: (estimate, provenance, refined, failure, new fit
hint)."""
NOT_MEASURED: Measured = (None, None, False, None, None)


def not_run(frame: Frame) -> DetectionResult:
    """A frame the detector did not see (the keeper's tracker covers it): no map, nothing."""
    return DetectionResult(np.zeros((0, 0), np.float32), (), frame.timestamp_ns,
                           frame.camera_id, frame.seq)


def detect(detector: Detector, frame: Frame) -> tuple[DetectionResult, str | None]:
    """Stage 1: the detector's result, and ``"nan_map"`` when its map or a region is not finite
    (those detections dropped: a detector fault must not steer the vehicle)."""
    result = detector.detect(frame, _prior(frame.camera_id))
    if not bool(np.isfinite(result.saliency).all()):
        return replace(result, detections=()), "nan_map"
    if any(not np.isfinite(d.corners_px).all() for d in result.detections):
        return replace(result, detections=tuple(
            d for d in result.detections if np.isfinite(d.corners_px).all())), "nan_map"
    return result, None


def choose_detection(result: DetectionResult, req: Request,
                     appearance: TargetAppearance | None, p: PerceptionConfig,
                     target: TargetConfig, has_fitter: bool) -> Detection | None:
    """Stage 2a, the detector's candidate: the plausible detection nearest the predicted pixel
    (``gate_px``: a quarter of the image); plausible = of the size the camera's pose expects
    (``size_ratio_range``) and, when the target's colour is known (``target.color_bgr``), of
    the target's colour; cut by the image border only at close range with a plane fit that
    has the heading of an earlier complete view. With no prediction: the one where the example
    image itself matches best (:meth:`TargetAppearance.example_match`, at least
    ``appearance.example.match_min_ncc``), else the best-ranked."""
    frame, model, state = req.frame, req.model, req.state
    colour = appearance if appearance is not None and appearance.has_colour else None
    gate_px = 0.25 * max(model.width_px, model.height_px)

    def plausible(d: Detection) -> bool:
        return (plausible_size(d, model, state, target, *p.size_ratio_range)
                and (colour is None or colour.colour_matches(frame, d)))

    allow_cut = req.close_range and has_fitter and req.fit_hint is not None
    match = None
    min_ncc = None if appearance is None else appearance.example_config.match_min_ncc
    if req.predicted_px is None and min_ncc is not None and appearance is not None \
            and appearance.image is not None:
        image = np.asarray(frame.image)

        def match(d: Detection) -> float:
            return appearance.example_match(image, d.center_px)

    if req.predicted_px is None and req.candidate_box is not None:
        followed = follow_candidate(result, req.candidate_box, frame, appearance, plausible,
                                    min_ncc)
        if followed is not None:
            return followed
    det = select_detection(result, req.predicted_px, model.width_px, model.height_px,
                           p.image_border_px, gate_px, plausible, allow_cut=allow_cut,
                           match=match, match_min=min_ncc or 0.0)
    if match is None or min_ncc is None or appearance is None or appearance.image is None:
        return det
    # searching: the example itself, where it matches the whole frame best, when it matches
    # better than the detector's candidate (a small target the detector misses or confuses
    # with its neighbours); only where the camera can see the target at the example's size
    if state is not None and not example_size_plausible(model, state, target,
                                                        appearance.image.shape):
        return det
    found = appearance.locate_example(np.asarray(frame.image))
    if found is None:
        return det
    # scored as the detector's candidate is (the local match), so the two compare
    u0, v0, u1, v1 = found[0]
    score = appearance.example_match(np.asarray(frame.image), ((u0 + u1) / 2, (v0 + v1) / 2))
    if score < min_ncc or (det is not None and match(det) >= score):
        return det
    return box_detection(found[0], frame.camera_id, score=score)


def follow_candidate(result: DetectionResult, box: tuple[float, float, float, float],
                     frame: Frame, appearance: TargetAppearance | None,
                     plausible: Callable[[Detection], bool], min_ncc: float | None
                     ) -> Detection | None:
    """Stage 2a while a candidate awaits confirmation: the best-ranked plausible detection on
    its box, else (with an example image) the example found again near it with at least
    ``min_ncc``; None: the candidate is gone (the search starts over)."""
    for d in result.detections:
        if on_box(d.center_px, box) and plausible(d):
            return d
    if appearance is None or appearance.image is None or min_ncc is None:
        return None
    found = appearance.locate_example_near(np.asarray(frame.image), box)
    if found is None or found[1] < min_ncc:
        return None
    return box_detection(found[0], frame.camera_id, score=found[1])


def example_size_plausible(model: CameraModel, state: VehicleState, target: TargetConfig,
                           example_shape: tuple[int, ...]) -> bool:
    """Whether the target seen at the image's centre has about the example's size (within a
    factor 4 in area): where it cannot, the example is not looked for at its own size."""
    centre = ((model.width_px - 1) / 2, (model.height_px - 1) / 2)
    exp = expected_area_px(model, state, centre, target.length_m, target.width_m,
                           target.height_m)
    area = float(example_shape[0] * example_shape[1])
    return exp is not None and 0.25 * exp <= area <= 4.0 * exp


def target_candidates(det: Detection | None, req: Request,
                      appearance: TargetAppearance | None, from_tracker: bool = False
                      ) -> Iterator[tuple[Detection | None, bool]]:
    """Stage 2b: the candidates for the target in this frame, best first, each with whether it
    is the target colour's region (True) or not (False); the pose stage measures the first it
    can. ``det``: the detector's candidate, or the kept target (``from_tracker``: the
    tracker's box).

    At close range, when the target's colour is known, the region of the target's colour near
    the predicted pixel comes first when there is no other candidate, when the fine estimator
    is asked and the regions agree (:func:`regions_agree`: the colour region follows the
    target's edges, a saliency threshold need not), or when ``det`` is only the tracker's box
    (at close range the target fills much of the view with little texture and the tracker's
    box drifts off it; the colour region is measured on this frame); otherwise after ``det``,
    when that one cannot be measured.
    """
    frame = req.frame
    colour = appearance if appearance is not None and appearance.has_colour else None
    near = req.predicted_px
    if not (req.close_range and colour is not None and near is not None
            and bool(np.isfinite(near).all())):
        yield det, False
        return
    if det is None or req.estimator == "fine" or from_tracker:
        region = colour.colour_region(frame, near)
        agree = region is not None and (det is None or regions_agree(region, det))
        if region is not None and (agree or from_tracker):
            yield region, True
            if not agree:
                yield det, False
            return
        yield det, False
        if det is not None and region is not None:
            yield region, True
        return
    yield det, False
    region = colour.colour_region(frame, near)
    if region is not None:
        yield region, True


def _prior(camera_id: str, wide_id: str = "wide") -> TargetPrior:
    return TargetPrior(min_area_px=12.0 if camera_id == wide_id else 100.0)


class Perception:
    """Runs one frame through the tools (:meth:`perceive`; pure apart from the detectors'
    temporal state, which only this camera's perception touches)."""

    def __init__(self, params: PerceptionConfig, target: TargetConfig, *,
                 thumbnails: bool = True) -> None:
        self.p = params
        self.target = target
        #: make each map's :attr:`Measurement.saliency_thumb` (~0.7 ms per 1280x960 frame,
        #: on the frame-to-setpoint path): only for a recording
        self.thumbnails = thumbnails
        self._epochs: dict[str, int] = {}
        """Per camera, the request's ``keep_epoch`` its keeper last saw."""

    def perceive(self, req: Request, tools: Tools) -> Measurement:
        t0 = time.perf_counter()
        frame, state = req.frame, req.state
        keeper = tools.keeper
        if keeper is not None and req.keep_epoch != self._epochs.get(frame.camera_id, 0):
            keeper.reset()  # the mission dropped its target: so does the keeper
            self._epochs[frame.camera_id] = req.keep_epoch
        ran = keeper is None or keeper.detector_due(req.close_range)
        result, anomaly = detect(tools.detector, frame) if ran else (not_run(frame), None)
        unaided = req
        kept_box = keeper.box if keeper is not None and req.predicted_px is None else None
        if kept_box is not None:
            u0, v0, u1, v1 = kept_box  # the kept target is where to look
            req = replace(req, predicted_px=((u0 + u1) / 2, (v0 + v1) / 2))
        elif keeper is not None and keeper.candidate is not None:
            req = replace(req, candidate_box=keeper.candidate)
        det = choose_detection(result, req, tools.appearance, self.p, self.target,
                               tools.fitter is not None)
        if det is None and ran and kept_box is not None and result.detections:
            # nothing near the kept box: the keeper hears of the detector's choice elsewhere
            # (it moves there only as its switching rule allows)
            det = choose_detection(result, unaided, tools.appearance, self.p, self.target,
                                   tools.fitter is not None)
        likeness = None
        if tools.appearance is not None and tools.appearance.image is not None:
            image, appearance = np.asarray(frame.image), tools.appearance

            def likeness(centre_px: tuple[float, float]) -> float:
                return appearance.example_match(image, centre_px)

        kept = None if keeper is None else keeper.step(frame, det, ran, likeness)
        if kept is not None:
            det = kept.detection
        tracked = kept is not None and kept.from_tracker
        chosen: tuple[Detection | None, bool, Measured] | None = None
        for cand, colour in target_candidates(det, req, tools.appearance, tracked):
            measured = self.measure(cand, req, tools, colour)
            if chosen is None or measured[0] is not None:
                chosen = (cand, colour, measured)  # the first, unless a later one measures
            if measured[0] is not None:
                break
        det, from_colour, out = chosen or (None, False, NOT_MEASURED)
        if tracked and from_colour and out[0] is not None and det is not None:
            assert keeper is not None
            keeper.correct(frame, box_of(det))  # the tracker follows the measured region
        est, prov, refined, failure, hint = out
        return Measurement(frame.camera_id, frame, state, req.estimator, det,
                           len(result.detections), from_colour,
                           est, prov, refined, failure, hint,
                           (time.perf_counter() - t0) * 1e3, anomaly,
                           None if anomaly or not self.thumbnails or not ran
                           else saliency_thumbnail(result.saliency),
                           ran, kept is not None and det is kept.detection,
                           kept is not None and kept.from_tracker and det is kept.detection)

    def measure(self, det: Detection | None, req: Request, tools: Tools, tracked: bool
                ) -> Measured:
        """Stage 3, the pose of one candidate: (estimate, provenance, refined, failure, new fit
        hint); the estimate is None when nothing was asked or the candidate cannot be measured
        (``failure`` says why)."""
        if det is None or req.estimator is None or req.state is None:
            return NOT_MEASURED
        view = CameraView(req.model, req.state, req.frame.timestamp_ns)
        primary = tools.fine if req.estimator == "fine" else tools.coarse
        est = primary.estimate(det, view)
        prov = Provenance.FINE if req.estimator == "fine" else Provenance.COARSE
        if not est and req.estimator == "fine":
            # the fine estimator refused (e.g. reprojection error): keep tracking with the
            # coarse estimate of the same detection, with less weight
            failed = est
            est = tools.coarse.estimate(det, view)
            if est:
                assert isinstance(est, TargetEstimate)
                est = replace(est, std_m=est.std_m * self.p.fallback_std_factor,
                              source=f"{est.source} (fine failed: {failed})")
                prov = Provenance.FALLBACK
        if not est:
            return None, None, False, str(est), None
        assert isinstance(est, TargetEstimate)
        if tools.fitter is None:
            return est, prov, False, None, None
        return self._refine(est, prov, det, view, req, tools.fitter, tracked, tools.appearance)

    def _refine(self, est: TargetEstimate, prov: Provenance, det: Detection, view: CameraView,
                req: Request, fitter: PlaneFitter, tracked: bool,
                appearance: TargetAppearance | None = None) -> Measured:
        """Replace the estimate's position by the top-plane fit of its detection (top face or
        box silhouette, whichever explains the MBR). In the final approach a detection no
        model explains (part of the target, a merged blob) is refused; earlier the estimator's
        value is kept. The fitted position comes from the detection, not from the estimator
        that accepted it, so its weight is the fit's whatever the provenance (a refined
        fallback is as good as a refined fine estimate: docs/mission.md, "fallbacks")."""
        p = self.p
        m = view.model
        cam = view.camera_pose_ned
        cut = touches_border(det, m.width_px, m.height_px, p.image_border_px)
        hint = req.fit_hint
        if cut and hint is None:
            return (None, None, False, "plane fit: the detection is cut by the image border and "
                    "no complete view gave the target's heading yet", None)
        yaw_hint = hint.yaw_deg if (cut and hint is not None) else None
        yaw_span = hint.span_deg if (cut and hint is not None) else None
        region_hint = hint.region if (cut and hint is not None) else None
        if tracked:
            # a colour region is the whole silhouette: the top and the shaded sides share the
            # target's chromaticity (not the detector's region of the earlier views)
            region_hint = "box"
        plane_ground = plane_down_m(0.0, req.plane)
        whole = req.close_range and not cut
        outline = colour_outline(det, req.frame, appearance, tracked) if whole else None
        fit = fitter.fit(det if outline is None else replace(det, hull_px=outline), view,
                         plane_down_m=plane_ground, yaw_hint_deg=yaw_hint,
                         region_hint=region_hint, iterations=8 if cut else 4,
                         silhouette=outline is not None, yaw_hint_span_deg=yaw_span,
                         occluder_px=req.occluder_px)
        new_hint = None
        if fit is not None and not cut and fit.cost <= p.plane_fit_max_cost and req.close_range:
            # the heading for the cut views to come: the outline's when it fits the target
            # (within a few degrees; the MBR fit's, on a 15 deg grid, mirrors now and then)
            yaw, span = fit.yaw_deg, None
            if (fit.silhouette_yaw_deg is not None and fit.silhouette_iou is not None
                    and fit.silhouette_iou >= p.silhouette_heading_min_iou):
                yaw, span = fit.silhouette_yaw_deg, p.silhouette_heading_span_deg
            new_hint = FitHint(yaw, fit.region, fit.silhouette_iou, fit.silhouette_yaw_deg,
                               span)
        if fit is None or fit.cost > p.plane_fit_max_cost:
            if req.close_range:
                why = "no fit" if fit is None else f"MBR mismatch {fit.cost:.2f}"
                return (None, None, False, f"plane fit: {why} (> perception.plane_fit_max_cost="
                        f"{p.plane_fit_max_cost:g})", new_hint)
            return est, prov, False, None, new_hint
        pos = np.asarray(fit.position_ned_m)
        d = pos - cam.t
        rng = float(np.linalg.norm(d))
        sin_dep = max(float(d[2]) / max(rng, 1e-9), 1e-3)
        std = fit_std_m(rng, sin_dep, p.plane_fit_angular_std_deg)
        size_ratio = fit.size_ratio
        if req.close_range and size_ratio > 0:
            # range from the apparent size (known target, 1/range) fused with the plane's
            # range (the measured plane, or the vehicle's altitude estimate): same ray. A cut
            # view's size is compared with the model clipped to the image like the detection.
            d = d * size_range_scale(size_ratio, req.plane.std_m, sin_dep, rng,
                                     p.size_std_fraction)
            pos = cam.t + d
        source = (f"{est.source.split(' ')[0]}+fit:{fit.region} yaw {fit.yaw_deg:.0f} "
                  f"cost {fit.cost:.2f} size {size_ratio:.3f}" + (" cut" if cut else ""))
        dc = cam.R.T @ d
        refined = replace(est, position_ned_m=(float(pos[0]), float(pos[1]), float(pos[2])),
                          position_cam_m=(float(dc[0]), float(dc[1]), float(dc[2])),
                          std_m=std, source=source, fit_cost=fit.cost)
        return refined, prov, True, None, new_hint
