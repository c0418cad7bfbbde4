"""The state machine: one table, pure guards, failsafes, timeouts, the Mermaid doc."""

from __future__ import annotations

import copy
import dataclasses
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from eaglemission.missions import approach as ap
from eaglemission.missions.approach import (
    ACTIVE_STATES,
    TRANSITIONS,
    Abort,
    ApproachMachine,
    MissionState,
    Snapshot,
    failsafe,
    mermaid_diagram,
)
from eaglemission.missions.approach_config import ActionsConfig
from transitions import MachineError

from eaglemission.config import load_config

S = MissionState
DOC = Path(__file__).resolve().parents[2] / "docs" / "mission.md"

READY = Snapshot(armable=True, position_valid=True, cameras_streaming=True, detector_warm=True,
                 telemetry_hz=50.0)


def machine_in(state: MissionState) -> ApproachMachine:
    m = ApproachMachine()
    m.machine.set_state(state)  # test setup only: the model has no to_<state>() shortcuts
    return m


def test_table_uses_enum_states_and_no_auto_transitions() -> None:
    m = ApproachMachine()
    for t in TRANSITIONS:
        srcs = t["source"] if isinstance(t["source"], list) else [t["source"]]
        assert all(isinstance(s, MissionState) for s in srcs)
        assert isinstance(t["dest"], MissionState)
    assert not hasattr(m, "to_CRUISE") and not hasattr(m, "to_GRASP_READY")
    with pytest.raises(MachineError):
        m.trigger("tool_point_at_grasp", READY)  # not allowed from PREFLIGHT


def test_nominal_sequence_needs_every_guard() -> None:
    changes: list[tuple[str, str]] = []
    m = ApproachMachine(on_change=lambda a, b, r, act: changes.append((a.value, b.value)))
    assert m.step(Snapshot()) is None and m.state is S.PREFLIGHT  # nothing ready yet
    assert m.step(READY) == "preflight_passed"
    assert m.step(Snapshot(in_air=True, altitude_m=2.0, takeoff_altitude_m=5.0)) is None
    assert m.step(Snapshot(in_air=True, altitude_m=4.9, takeoff_altitude_m=5.0)) == "reached_altitude"
    assert m.step(Snapshot(confirmed_frames=2, confirm_frames=3)) is None
    assert m.step(Snapshot(confirmed_frames=3, confirm_frames=3)) == "target_detected"
    near = Snapshot(has_target=True, target_age_s=0.1, target_in_narrow_view=True)
    assert m.step(near) is None  # narrow detector not warm yet
    assert m.step(dataclasses.replace(near, narrow_warm=True)) == "in_narrow_view"
    fine = Snapshot(has_target=True, target_age_s=0.1, grasp_required_frames=5,
                    fine_min_estimates=5, standoff_max_wait_s=3.0)
    # the standoff: there, but too few fine estimates and not waited long enough
    assert m.step(dataclasses.replace(fine, at_standoff=True, fine_estimates=4)) is None
    assert m.step(dataclasses.replace(fine, fine_estimates=9)) is None  # not there yet
    assert m.step(dataclasses.replace(fine, at_standoff=True, fine_estimates=5)) == "at_standoff"
    assert m.state is S.FINE_DESCENT
    assert m.step(dataclasses.replace(fine, grasp_stable_frames=4)) is None
    assert m.step(dataclasses.replace(fine, grasp_stable_frames=5)) == "tool_point_at_grasp"
    assert m.step(dataclasses.replace(fine, grasp_done=True)) == "grasp_complete"
    assert m.final and m.state is S.DONE
    assert [b for _, b in changes] == ["TAKEOFF", "CRUISE", "COARSE_APPROACH", "FINE_APPROACH",
                                       "FINE_DESCENT", "GRASP_READY", "DONE"]


def test_descent_also_starts_after_waiting_at_the_standoff() -> None:
    m = machine_in(S.FINE_APPROACH)
    s = Snapshot(has_target=True, target_age_s=0.1, at_standoff=True, fine_estimates=1,
                 fine_min_estimates=5, standoff_max_wait_s=3.0, standoff_dwell_s=2.9)
    assert m.step(s) is None
    assert m.step(dataclasses.replace(s, standoff_dwell_s=3.1)) == "at_standoff"


def test_the_fine_approach_is_one_time_budget() -> None:
    """The descent's timeout runs from the fine approach's start (standoff + descent)."""
    pol = ap.POLICIES
    assert pol[S.FINE_DESCENT].timeout_from is S.FINE_APPROACH
    assert pol[S.FINE_DESCENT].timeout_field == pol[S.FINE_APPROACH].timeout_field


def test_every_state_has_a_policy_and_every_entry_action_exists() -> None:
    from eaglemission.missions.runner import MissionRunner

    assert set(ap.POLICIES) == set(MissionState)
    for state, pol in ap.POLICIES.items():
        for action in pol.on_enter:
            assert hasattr(MissionRunner, f"_enter_{action}"), (state, action)
    # the machine's own states are exactly the table's
    states_in_table = set()
    for t in TRANSITIONS:
        src = t["source"] if isinstance(t["source"], list) else [t["source"]]
        states_in_table |= set(src) | {t["dest"]}
    assert states_in_table == set(MissionState)


def test_no_mission_state_branches_outside_the_table() -> None:
    """What a state does is data (POLICIES): the other mission modules never compare the
    machine's state with a state."""
    import re

    root = Path(__file__).resolve().parents[2] / "missions"
    pattern = re.compile(r"\b(?:S|MissionState)\.(?:" + "|".join(s.name for s in MissionState)
                         + r")\b")
    offenders = []
    for path in sorted(root.glob("*.py")):
        if path.name in ("approach.py",):
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line):
                offenders.append(f"{path.name}:{i}: {line.strip()}")
    assert offenders == []


def test_target_lost_and_reacquired() -> None:
    m = machine_in(S.FINE_APPROACH)
    fresh = Snapshot(has_target=True, target_age_s=0.5, target_lost_after_s=2.5)
    assert m.step(fresh) is None
    # stale but not expected in view (too close for the camera): keep going on the filter
    assert m.step(dataclasses.replace(fresh, target_age_s=3.0, target_expected_visible=False)) is None
    assert m.step(dataclasses.replace(fresh, target_age_s=3.0)) == "lost"
    assert m.state is S.TARGET_LOST
    assert m.step(Snapshot(has_target=True, confirmed_frames=3, confirm_frames=3)) == "reacquired"
    assert m.state is S.COARSE_APPROACH


@pytest.mark.parametrize("state", ACTIVE_STATES)
def test_abort_from_every_active_state(state: MissionState) -> None:
    m = machine_in(state)
    assert m.step(Snapshot(), Abort("test", "land")) == "abort"
    assert m.state is S.FAILSAFE and m.action == "land" and m.reason == "test"
    assert m.step(READY, Abort("again", "hold")) is None  # final: nothing fires any more


def _fs(state: MissionState, snap: Snapshot, **actions: object) -> Abort | None:
    cfg = load_config(check_plugins=False)
    return failsafe(state, snap, cfg.safety, ActionsConfig.model_validate(actions))


def test_failsafes_map_to_configured_actions() -> None:
    cfg = load_config(check_plugins=False)
    s = cfg.safety
    assert _fs(S.CRUISE, Snapshot(link_lost_s=2.0)).action == s.link_loss_action
    assert _fs(S.CRUISE, Snapshot(link_lost_s=1.0)) is None  # below link_loss_timeout_s
    assert _fs(S.CRUISE, Snapshot(gps_ok=False)).action == s.gps_loss_action
    assert _fs(S.FINE_APPROACH, Snapshot(battery_remaining=0.1)).action == s.low_battery_action
    assert _fs(S.CRUISE, Snapshot(pilot_override=True)).action == "release"
    assert _fs(S.CRUISE, Snapshot(camera_failed=True),
               on_camera_failure="land").action == "land"
    assert _fs(S.COARSE_APPROACH, Snapshot(goal_inside_geofence=False),
               on_geofence="hold").action == "hold"
    # on the ground nothing is flown: failures end with action none
    assert _fs(S.PREFLIGHT, Snapshot(battery_remaining=0.1)).action == "none"
    # priority: link loss is reported before the mode change it causes
    both = _fs(S.CRUISE, Snapshot(link_lost_s=2.0, pilot_override=True))
    assert both.reason.startswith("link lost")
    # a short link loss PX4 failed over in (and came back from, unreported): not carried on
    fo = _fs(S.FINE_DESCENT, Snapshot(link_lost_s=1.0, autopilot_failover="no telemetry for 1.2 s"))
    assert fo is not None and fo.action == s.link_loss_action and "failover" in fo.reason
    assert _fs(S.PREFLIGHT, Snapshot(autopilot_failover="x")) is None  # on the ground: nothing flown


def test_state_timeouts() -> None:
    assert _fs(S.CRUISE, Snapshot(time_in_state_s=10, state_timeout_s=120)) is None
    ab = _fs(S.CRUISE, Snapshot(time_in_state_s=121, state_timeout_s=120), on_timeout="land")
    assert ab is not None and "timed out" in ab.reason and ab.action == "land"
    # TARGET_LOST with on_target_lost=resume_cruise: no abort, the resume transition fires
    lost = Snapshot(time_in_state_s=16, state_timeout_s=15, search_exhausted=True)
    assert _fs(S.TARGET_LOST, lost) is None
    m = machine_in(S.TARGET_LOST)
    assert m.step(lost) == "resume_cruise" and m.state is S.CRUISE


def test_route_end_without_target_is_a_failsafe() -> None:
    ab = _fs(S.CRUISE, Snapshot(route_finished=True), on_route_end="return")
    assert ab is not None and ab.action == "return"


# -- purity of the guards and the failsafe ----------------------------------------------------
GUARDS: tuple[Callable[[Snapshot], object], ...] = tuple(dict.fromkeys(
    [c for t in TRANSITIONS for c in t.get("conditions", [])]
    + [ap.state_timed_out, ap.route_finished]))
"""Every guard of the table, and the predicates :func:`failsafe` applies."""

FLOATS = (0.0, 0.1, 1.0, 2.5, 3.0, 5.0, 10.0, 60.0, 121.0, float("inf"))
ACTION_NAMES = (*ap.FINAL_ACTIONS, "resume_cruise")


def _draw(rng: random.Random) -> dict[str, Any]:
    """Field values for one snapshot, near the thresholds the guards compare them with."""
    values: dict[str, Any] = {}
    for f in dataclasses.fields(Snapshot):
        default = f.default_factory() if f.default is dataclasses.MISSING else f.default
        if isinstance(default, bool):
            values[f.name] = rng.random() < 0.7
        elif isinstance(default, int):
            values[f.name] = rng.randint(0, 7)
        elif isinstance(default, float):
            values[f.name] = rng.choice(FLOATS)
        elif f.name in ("on_target_lost", "interrupt_action"):
            values[f.name] = rng.choice(ACTION_NAMES)
        elif isinstance(default, str):
            values[f.name] = rng.choice(("", "", "", "a reason"))
        else:
            values[f.name] = {"note": [rng.random()]}
    return values


def impurities(guard: Callable[[Snapshot], object], seed: int, n: int = 300) -> list[str]:
    """How ``guard`` is not a pure function of its snapshot's values: a different answer for
    equal snapshots built apart, a changed snapshot, a different answer for a snapshot seen
    again after others (hidden state); and whether the draws exercised it at all."""
    rng = random.Random(seed)
    drawn = [_draw(rng) for _ in range(n)]
    problems: list[str] = []
    first = []
    for i, values in enumerate(drawn):
        a, b = Snapshot(**copy.deepcopy(values)), Snapshot(**copy.deepcopy(values))
        ra, rb = guard(a), guard(b)
        if ra != rb:
            problems.append(f"draw {i}: equal snapshots built apart gave {ra!r} and {rb!r}")
        if dataclasses.asdict(a) != values:
            problems.append(f"draw {i}: the guard changed its snapshot")
        first.append(ra)
    for i in reversed(range(n)):  # the same values again, after all the others
        again = guard(Snapshot(**copy.deepcopy(drawn[i])))
        if again != first[i]:
            problems.append(f"draw {i}: {first[i]!r} first, {again!r} after other snapshots")
    if len({repr(r) for r in first}) < 2:
        problems.append(f"the {n} draws gave one answer only: they do not exercise the guard")
    return problems


def _failsafe_in(state: MissionState) -> Callable[[Snapshot], object]:
    cfg = load_config(check_plugins=False)
    params = ActionsConfig(on_target_lost="land")

    def check(s: Snapshot) -> object:
        return failsafe(state, s, cfg.safety, params)

    check.__name__ = f"failsafe_{state.name}"
    return check


@pytest.mark.parametrize("guard", [*GUARDS, *(_failsafe_in(s) for s in ACTIVE_STATES)],
                         ids=lambda g: g.__name__)
def test_guards_are_pure(guard: Callable[[Snapshot], object]) -> None:
    assert impurities(guard, seed=1729) == []


def test_the_purity_check_catches_impure_guards() -> None:
    """:func:`impurities` fails a guard with hidden state, one that changes its snapshot and
    one that looks at the object rather than its values."""
    calls = [0]

    def counts_calls(s: Snapshot) -> bool:
        calls[0] += 1
        return s.has_target and calls[0] % 3 != 0

    last: list[bool] = [False]

    def remembers_the_previous_answer(s: Snapshot) -> bool:
        previous, last[0] = last[0], s.has_target
        return previous or s.in_air

    def marks_its_snapshot(s: Snapshot) -> bool:
        s.extra["seen"] = True
        return s.has_target

    def looks_at_the_object(s: Snapshot) -> bool:
        return s.has_target and id(s) // 16 % 7 < 3

    for impure in (counts_calls, remembers_the_previous_answer, marks_its_snapshot,
                   looks_at_the_object):
        assert impurities(impure, seed=1729) != [], impure.__name__
    assert any("one answer" in p for p in impurities(lambda s: True, seed=1729))


def test_mermaid_doc_is_up_to_date() -> None:
    text = DOC.read_text(encoding="utf-8")
    assert mermaid_diagram() in text, (
        "docs/mission.md is stale: regenerate with "
        "`python -m eaglemission.missions.approach --mermaid`")


def test_px4_failsafe_parameters_are_reported() -> None:
    from eaglemission.missions.actuator import failsafe_param_warnings

    cfg = load_config(check_plugins=False)
    w = failsafe_param_warnings({"RTL_RETURN_ALT": 60.0, "MPC_Z_VEL_MAX_UP": 3.0,
                                 "COM_OBL_RC_ACT": 0.0, "COM_OF_LOSS_T": 1.0}, cfg.safety)
    assert any(x.startswith("RTL_RETURN_ALT") for x in w)
    assert any(x.startswith("MPC_Z_VEL_MAX_UP") for x in w)
    assert any("Position mode" in x and "descends and lands" in x for x in w)
    assert failsafe_param_warnings({"RTL_RETURN_ALT": 10.0}, cfg.safety) == []
