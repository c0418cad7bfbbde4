"""The expected outcome of every fault kind, and the range a campaign draws it from.

A *tolerable* fault (a short camera drop, a slow frame, a gust within bounds, one corrupted
frame...) must still end in GRASP_READY and DONE; an *intolerable* one must end in FAILSAFE with
the safe action its configuration prescribes (``safety.link_loss_action`` and so on). The table
is the contract the tests and ``campaign --faults`` check, and docs/faults.md prints it
(:func:`markdown_table`; a test keeps the two equal).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from eaglemission.lab.faults.config import FAULT_KINDS, SIZES

COMPLETE = "complete"


@dataclass(frozen=True)
class Outcome:
    """What one fault kind must end in, where it is injected, and how a campaign draws it."""

    where: str
    """Where it is injected (in life: the camera, the detector, the link, the world)."""
    expected: str
    """``complete`` (GRASP_READY + DONE), or the config path of the safe action (e.g.
    ``safety.link_loss_action``), or a literal action (``release``)."""
    detected_by: tuple[str, ...]
    """Substrings of the mission's log records that show the mission noticed (its
    ``fault_detected`` ``what``, a state's reason)."""
    states: tuple[str, ...]
    """The mission states a campaign injects it in (``at_state``)."""
    delay_s: tuple[float, float]
    duration_s: tuple[float, float]
    size: tuple[float, float] | None = None

    @property
    def tolerable(self) -> bool:
        return self.expected == COMPLETE


_CAM = "camera plugin (lab/faults/faulty_camera.py)"
_DET = "detector (lab/faults/wrappers.py)"
_EST = "estimators (lab/faults/wrappers.py)"
_VEH = "simulated vehicle's link / autopilot (lab/vehicles/simulated/faults.py)"
_LINK = "simulated vehicle's telemetry link (lab/vehicles/simulated/link.py)"
_APPROACH = ("COARSE_APPROACH", "FINE_APPROACH")
_FLYING = ("CRUISE", "COARSE_APPROACH", "FINE_APPROACH")

OUTCOMES: dict[str, Outcome] = {
    "camera_drop": Outcome(_CAM, COMPLETE, ("grab_failed",), _APPROACH, (0.2, 1.0), (0.3, 1.0)),
    "camera_freeze": Outcome(_CAM, COMPLETE, ("frame_repeated",), _APPROACH, (0.2, 1.0),
                             (0.3, 1.0)),
    "corrupted_frame": Outcome(_CAM, COMPLETE, (), _APPROACH, (0.2, 1.0),
                               (0.05, 0.1)),
    "truncated_frame": Outcome(_CAM, COMPLETE, ("frame_rejected",), _APPROACH, (0.2, 1.0),
                               (0.05, 0.1)),
    "exposure_jump": Outcome(_CAM, COMPLETE, (), _APPROACH, (0.2, 1.0), (0.2, 0.5),
                             (2.0, 4.0)),
    "occlusion": Outcome(_CAM, COMPLETE, (), ("FINE_APPROACH",), (0.2, 1.0),
                         (0.5, 1.5)),
    "camera_device_loss": Outcome(_CAM, "mission.params.actions.on_camera_failure",
                                  ("grab_failed", "camera failure"), _FLYING, (0.5, 2.0),
                                  (1.0, 1.0)),
    "camera_clock_jump": Outcome(_CAM, "mission.params.actions.on_camera_failure",
                                 ("frame_stamp", "camera failure"), _FLYING, (0.5, 2.0),
                                 (1.0, 1.0), (5.0, 60.0)),
    "detector_exception": Outcome(_DET, COMPLETE, ("perception_failed",), _APPROACH,
                                  (0.2, 1.0), (0.2, 0.8)),
    "nan_map": Outcome(_DET, COMPLETE, ("nan_map",), _APPROACH, (0.2, 1.0), (0.2, 0.8)),
    "slow_frame": Outcome(_DET, COMPLETE, ("slow_perception",), _APPROACH, (0.2, 1.0),
                          (0.2, 0.6), (0.6, 1.0)),
    "degenerate_corners": Outcome(_EST, COMPLETE, ('"provenance": "fallback"', "fine failed"), ("FINE_APPROACH",),
                                  (0.2, 1.0), (0.2, 0.8)),
    # the top-plane fit recomputes position and heading from the detection: a flipped
    # estimator pose never reaches the filter, so there is nothing for the mission to notice
    "pose_flip": Outcome(_EST, COMPLETE, (), ("FINE_APPROACH",),
                         (0.2, 1.0), (0.1, 0.3)),
    "link_loss": Outcome(_VEH, "safety.link_loss_action", ("link lost",), _FLYING, (0.5, 2.0),
                         (3.0, 6.0)),
    "command_denied": Outcome(_VEH, COMPLETE, ("setpoint refused",), _FLYING, (0.5, 2.0),
                              (1.0, 1.0)),
    "pilot_mode": Outcome(_VEH, "release", ("flight mode changed",), _FLYING, (0.5, 2.0),
                          (1.0, 1.0)),
    "gps_loss": Outcome(_VEH, "safety.gps_loss_action", ("GPS lost",), _FLYING, (0.5, 2.0),
                        (20.0, 40.0)),
    "battery_drain": Outcome(_VEH, "safety.low_battery_action", ("battery low",), _FLYING,
                             (0.5, 2.0), (1.0, 1.0), (0.0, 0.15)),
    # below safety.max_telemetry_age_s a delay is flown through (reported as late telemetry);
    # beyond it the telemetry counts as lost: FAILSAFE with safety.link_loss_action after
    # safety.link_loss_timeout_s (tests/missions/test_link_faults.py, docs/faults.md)
    "link_delay": Outcome(_LINK, COMPLETE, ("telemetry_late",), _FLYING, (0.5, 2.0),
                          (1.0, 3.0), (0.15, 0.4)),
    "link_duplicate": Outcome(_LINK, COMPLETE, ("telemetry_duplicate",), _FLYING, (0.5, 2.0),
                              (1.0, 3.0)),
    "link_reorder": Outcome(_LINK, COMPLETE, ("telemetry_out_of_order",), _FLYING,
                            (0.5, 2.0), (1.0, 3.0)),
    # the mission's times are the host's receipt stamps: a jump of the autopilot's clock is
    # re-anchored, nothing is commanded on the autopilot's time base
    "autopilot_clock_jump": Outcome(_LINK, COMPLETE, ("autopilot_clock_jump",), _FLYING,
                                    (0.5, 2.0), (1.0, 1.0), (5.0, 60.0)),
    "wind_gust": Outcome("world: the simulated vehicle's wind (lab/vehicles/multicopter/dynamics.py)",
                         COMPLETE, (), _APPROACH, (0.2, 1.0), (1.0, 3.0), (0.05, 0.3)),
}


def expected_action(kind: str, cfg: Any) -> str:
    """``complete`` or the safe action ``cfg`` (a MissionFile) prescribes for ``kind``."""
    exp = OUTCOMES[kind].expected
    if exp == COMPLETE or "." not in exp:
        return exp
    section, *rest = exp.split(".")
    obj: Any = getattr(cfg, section)
    for part in rest:
        obj = obj.get(part) if isinstance(obj, dict) else getattr(obj, part, None)
    if obj is None and exp.startswith("mission.params."):
        from eaglemission import registry  # the mission's default for a key the file leaves out

        mcls = registry.get("missions", cfg.mission.type)
        obj = mcls.Config.model_validate(dict(cfg.mission.params))
        for part in rest[1:]:
            obj = getattr(obj, part)
    return str(obj)


def markdown_table() -> str:
    """The table of docs/faults.md."""
    rows = ["| kind | injected in | expected outcome | size (unit) | campaign draws |",
            "|---|---|---|---|---|"]
    for kind in FAULT_KINDS:
        o = OUTCOMES[kind]
        exp = "GRASP_READY + DONE" if o.tolerable else f"FAILSAFE, `{o.expected}`"
        size = SIZES[kind][0] if kind in SIZES else "-"
        draw = (f"in {'/'.join(o.states)} after {o.delay_s[0]:g}-{o.delay_s[1]:g} s, "
                f"for {o.duration_s[0]:g}-{o.duration_s[1]:g} s")
        if o.size is not None:
            draw += f", size {o.size[0]:g}-{o.size[1]:g}"
        rows.append(f"| `{kind}` | {o.where} | {exp} | {size} | {draw} |")
    return "\n".join(rows) + "\n"
