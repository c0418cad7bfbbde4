"""A candidate the mission keeps losing at one place is rejected (``tracking.max_losses``): its
estimates neither confirm nor track, and ``actions.on_target_lost`` applies at once (without it
the mission would loop on a distractor the fine approach's plane fit refuses, until the battery
ran low). A candidate whose outline is not the target's shape is rejected too
(``tracking.shape``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.missions.approach import (
    S,
    Snapshot,
    failsafe,
    lost_resumes_cruise,
)
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.guidance import Guidance, Plan
from mission_helpers import target_tracking, variant

from eaglemission.config import MissionFile, load_config


def test_the_third_loss_near_one_place_rejects_it_and_only_it() -> None:
    t = target_tracking()
    assert t.p.max_losses == 3
    assert t.count_loss() is None and not t.just_rejected  # never tracked: nothing to count
    t.last_target = (8.5, 0.7, -0.2)
    for n in (1, 2):
        place = t.count_loss()
        assert place == (8.5, 0.7) and t.losses_at(place) == n and not t.just_rejected
    t.last_target = (20.0, 0.0, -0.2)  # lost once elsewhere: a place of its own
    assert t.count_loss() == (20.0, 0.0) and t.last_losses == 1 and not t.just_rejected
    t.last_target = (9.9, 2.5, -0.2)  # within reacquire_radius_m + confirm_radius_m: the same place
    assert t.count_loss() == (8.5, 0.7) and t.last_losses == 3 and t.just_rejected
    assert t.rejected == [(8.5, 0.7)]
    assert t.is_rejected((8.5 + 2.9, 0.7, 0.0)) and not t.is_rejected((8.5 + 3.1, 0.7, 0.0))
    assert not t.is_rejected((20.0, 0.0, 0.0))
    t.last_target = (20.0, 0.0, -0.2)  # the next loss elsewhere clears the flag
    assert t.count_loss() == (20.0, 0.0) and not t.just_rejected and t.rejected == [(8.5, 0.7)]


def test_the_bound_is_configurable() -> None:
    t = target_tracking(max_losses=1)
    t.last_target = (1.0, 1.0, 0.0)
    t.count_loss()
    assert t.just_rejected and t.is_rejected((1.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="max_losses"):
        target_tracking(max_losses=0)


def test_a_rejected_candidate_resumes_the_search_or_takes_the_configured_action() -> None:
    cfg = load_config(check_plugins=False)
    snap = Snapshot(candidate_rejected=True, target_losses=3, has_target=True,
                    time_in_state_s=0.1, state_timeout_s=20.0)
    assert lost_resumes_cruise(snap)
    assert failsafe(S.TARGET_LOST, snap, cfg.safety, ApproachConfig.of(cfg).actions) is None
    land = ApproachConfig.of(variant(cfg, mission={
        "params": {**cfg.mission.params, "actions": {"on_target_lost": "land"}}})).actions
    abort = failsafe(S.TARGET_LOST, Snapshot(candidate_rejected=True, target_losses=3,
                                             on_target_lost="land"), cfg.safety, land)
    assert abort is not None and abort.action == "land" and "3 times" in abort.reason
    assert not lost_resumes_cruise(Snapshot(candidate_rejected=True, on_target_lost="land"))
    assert not lost_resumes_cruise(Snapshot())


def campaign_world(world: dict[str, object], **sections: object) -> MissionFile:
    """The embedded mission with both cameras binned 2x2 (``fault_campaign.py --binning 2``),
    a campaign run's world params and other sections (``faults``, ``mission``...) replaced."""
    d = load_config(check_plugins=False).model_dump(mode="json")
    for cam in d["cameras"].values():
        w, h = cam["resolution_px"]
        cam["resolution_px"] = [w // 2, h // 2]
        cam["pixel_size_um"] *= 2
    d["world"]["params"] = world
    d.update(sections)
    return MissionFile.model_validate(d)


@pytest.fixture
def box_of_its_colour_first() -> MissionFile:
    """A campaign world (``fault_campaign.py --seed 3 --binning 2``) with a box of the target's
    colour, square (0.41 m) and taller, on the route at N 8.6 m before the target: it is
    confirmed first, and the fine approach's plane fit refuses it every time."""
    return campaign_world({
        "seed": 1726916654, "target_north_m": 21.656, "target_east_m": -0.770,
        "target_yaw_deg": -178.74, "ground_texture": "snow", "light_gain": 1.28,
        "noise_sigma": 2.0, "wind_ne_mps": [0.061, -0.719], "mount_error_deg": 2.0,
        "focal_error_fraction": 0.03, "camera_time_offset_s": 0.0352, "frame_rate_hz": 30.0,
        "distractors": [
            {"kind": "box", "north_m": 32.351, "east_m": -5.634, "size_m": 0.584,
             "height_m": 0.083, "color_bgr": [152, 77, 201]},
            {"kind": "box", "north_m": 8.621, "east_m": 0.782, "size_m": 0.406,
             "height_m": 0.196, "color_bgr": [30, 40, 210]}]})


def test_a_distractor_lost_three_times_is_rejected_and_the_target_is_grasped(
        box_of_its_colour_first: MissionFile, tmp_path: Path) -> None:
    out = run_simulation(box_of_its_colour_first, log_path=tmp_path / "run.jsonl")
    ev = out.evaluation
    texts = [r["text"] for r in out.log.records if r["kind"] == "event"]
    rejected = [t for t in texts if "candidate rejected" in t]
    assert len(rejected) == 1 and "north 8." in rejected[0], texts
    assert ev.reached_grasp_ready and ev.final_state == "DONE", ev.explanation
    assert ev.horizontal_error_m is not None and ev.horizontal_error_m < 0.05
    assert not ev.violations


def test_a_candidate_whose_outline_is_not_the_targets_shape_is_rejected() -> None:
    t = target_tracking(shape={"min_iou": 0.9, "min_views": 4})
    t.filter.update((37.8, -3.2, -0.2), 0.1, 1)
    t.last_target = (37.8, -3.2, -0.2)
    for iou in (0.81, 0.80, 0.97):  # 3 views: not judged yet
        t.check_shape(0.0, (37.8, -3.2, -0.2), "narrow", iou)
    assert not t.misshapen
    t.check_shape(0.0, (37.8, -3.2, -0.2), "narrow", 0.79)  # median 0.805 < 0.9
    assert list(t.misshapen) == [(37.8, -3.2)]
    assert "silhouette IoU 0.81 over 4 views" in t.misshapen[(37.8, -3.2)]
    assert t.filter.state(1) is None and t.is_rejected((38.0, -3.0, 0.0))
    assert t.count_loss() == (37.8, -3.2) and t.just_rejected


def test_the_target_keeps_its_track_through_a_few_poor_outlines() -> None:
    t = target_tracking(shape={"min_iou": 0.9, "min_views": 4})
    t.filter.update((22.0, 1.5, -0.2), 0.1, 1)
    for iou in (0.97, 0.6, 0.98, 0.96, 0.55, 0.99, 0.97):  # a merged blob now and then
        t.check_shape(20.0, (22.0, 1.5, -0.2), "wide", iou)
    t.check_shape(20.0, (22.0, 1.5, -0.2), "wide", None)  # a view without an outline
    assert not t.misshapen and t.filter.state(1) is not None
    assert len(t.silhouettes) == 7 and len(t.headings_deg) == 8


def test_the_silhouette_check_is_on_by_default_and_can_be_turned_off() -> None:
    t = target_tracking()
    assert t.p.shape.min_iou == 0.86 and t.p.shape.min_views == 8
    off = target_tracking(shape={"min_iou": None, "min_views": 1})
    for _ in range(10):
        off.check_shape(0.0, (1.0, 1.0, 0.0), "narrow", 0.5)
    assert not off.misshapen


def test_a_granted_pass_flies_back_to_the_route_start_before_the_route_ends() -> None:
    cfg = load_config(check_plugins=False)
    p = ApproachConfig.of(cfg)
    g = Guidance(Plan.of(cfg, p.grasp.distance_m), p.guidance)
    assert p.guidance.max_route_passes == 2
    route = g.plan.route_ne_m
    end = (route[-1][0], route[-1][1], -cfg.mission.cruise_altitude_m)
    g.route_s_m = g.route_len_m
    assert g.route_finished(end)
    assert g.search_route_again() is not None and g.search_route_again() is None
    assert not g.route_finished(end)
    goal = g.goal("ROUTE", end, 0.0, (1.0, 0.0, 0.0, 0.0), None, 0, 0.1)
    assert goal is not None and goal[0][:2] == pytest.approx(route[0])
    assert not g.route_finished(end) and g.passes_left == 0
    start = (route[0][0], route[0][1], end[2])
    goal = g.goal("ROUTE", start, 0.0, (1.0, 0.0, 0.0, 0.0), None, 0, 0.1)
    assert goal is not None and 0.0 < g.route_s_m < 1.0  # the second pass has begun
    assert not g.route_finished(start)


@pytest.fixture
def square_box_past_the_target() -> MissionFile:
    """A campaign world (``fault_campaign.py --binning 2``, ``command_denied`` in the coarse
    approach): the target at N 28.0 m is seen once in cruise, unconfirmed; a red box 0.32 m
    square (the target's colour and top area, 0.40 x 0.25 m) at N 37.8 m is confirmed, and
    every plane fit explains it, each at another heading."""
    return campaign_world({
        "seed": 1505987167, "target_north_m": 28.017, "target_east_m": 2.349,
        "target_yaw_deg": -74.82, "ground_texture": "soil", "light_gain": 0.722,
        "noise_sigma": 2.0, "wind_ne_mps": [0.858, -0.451], "mount_error_deg": 2.0,
        "focal_error_fraction": 0.03, "camera_time_offset_s": 0.00954, "frame_rate_hz": 30.0,
        "distractors": [
            {"kind": "box", "north_m": 37.806, "east_m": -3.163, "size_m": 0.324,
             "height_m": 0.1996, "color_bgr": [29, 25, 177]},
            {"kind": "disc", "north_m": 23.219, "east_m": -2.767, "size_m": 0.588,
             "height_m": 0.111, "color_bgr": [226, 195, 66]}]},
        faults={"inject": [{"kind": "command_denied", "at_state": "COARSE_APPROACH",
                            "delay_s": 1.389, "duration_s": 1.0, "command": "set_setpoint"}]})


#: DTDMI's `field` preset, which confirms the square box before the target in that world
FIELD_DETECTOR = {"type": "dtdmi", "params": {"preset": "field", "use_dynamic": False,
                                              "downscale": 2}}


def test_a_square_box_of_the_targets_colour_is_rejected_and_the_route_searched_again(
        square_box_past_the_target: MissionFile, tmp_path: Path) -> None:
    """With the default shape check: the box's outlines fit the target's shape at IoU 0.7-0.8
    (the target's own at 0.9-1), so it is rejected after 8 views; the route is flown again and
    the target grasped (without the check, GRASP_READY on the box, 11.2 m from the target).
    Flown with the `field` detector, which confirms the box first (the shipped `aerial` +
    image confirms the target first: the next test)."""
    field = variant(square_box_past_the_target, detector=FIELD_DETECTOR,
                    target={"appearance_image": None})
    out = run_simulation(field, log_path=tmp_path / "run.jsonl")
    ev = out.evaluation
    texts = [r["text"] for r in out.log.records if r["kind"] == "event"]
    rejected = [t for t in texts if "does not fit the target's shape" in t]
    assert rejected, texts
    north_m = float(re.search(r"near north ([-\d.]+) m", rejected[0]).group(1))  # type: ignore[union-attr]
    assert north_m == pytest.approx(37.8, abs=0.5)  # the box, not the target at N 28 m
    assert any("searched again from its start" in t for t in texts), texts
    ious = [h["silhouette_iou"] for h in out.log.of_kind("heading")
            if h["silhouette_iou"] is not None]
    assert ious and min(ious) > 0.5
    assert ev.reached_grasp_ready and ev.final_state == "DONE", ev.explanation
    assert ev.horizontal_error_m is not None and ev.horizontal_error_m < 0.05
    assert not ev.violations


def test_the_shipped_detector_confirms_the_target_not_the_square_box(
        square_box_past_the_target: MissionFile, tmp_path: Path) -> None:
    """The embedded mission's detector (`aerial` + the target's example image) takes the target
    at N 28 m on its first sighting: no candidate to reject, grasped within 5 cm."""
    out = run_simulation(square_box_past_the_target, log_path=tmp_path / "run.jsonl")
    ev = out.evaluation
    texts = [r["text"] for r in out.log.records if r["kind"] == "event"]
    assert not any("does not fit the target's shape" in t or "candidate rejected" in t
                   for t in texts), texts
    assert ev.reached_grasp_ready and ev.final_state == "DONE", ev.explanation
    assert ev.horizontal_error_m is not None and ev.horizontal_error_m < 0.05
    assert not ev.violations
