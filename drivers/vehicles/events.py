"""``VehicleEvent.kind`` values used by the vehicles (docs/vehicles.md has the table)."""

from __future__ import annotations

EVENT_MODE = "mode"  # flight mode changed; data: from, to, source (command/autopilot/failsafe/pilot)
EVENT_STATUS = "status"  # autopilot status text (PX4 STATUSTEXT); data: severity
EVENT_FAILSAFE = "failsafe"  # a failsafe fired; data: reason, action
EVENT_REFUSED = "refused"  # a command was refused; data: command, result
EVENT_MISSION = "mission"  # a mission item was reached; data: index, total
EVENT_GRIPPER = "gripper"  # grab / release; data: action
EVENT_LINK = "link"  # link lost / regained; data: ok
EVENT_FAILOVER = "failover"  # offboard setpoints lost longer than the autopilot allows; data: gap_s, offboard_loss_timeout_s
EVENT_FAULT = "fault"  # a fault was injected (sim only); data: fault, duration_s
EVENT_TIME_BASE = "time_base"  # a telemetry stamp refused (copy, older) or re-anchored (clock jump); data: problem, stream
EVENT_WATCHDOG = "watchdog"  # the offboard watchdog commanded HOLD; data: age_s
EVENT_TRUTH = "truth"  # the ground truth looks wrong (simulators only); data: problem
