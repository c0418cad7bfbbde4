"""Recorded PX4 v1.16 fact: a second ground station switches the mode (scenarios h1-h3 of
``../shared/data/px4_sitl_tlogs``; skipped when absent), reproduced on the emulator.

Fact 31 (README of the recordings): DO_SET_MODE from a second GCS (sysid 255) while MAVSDK
holds in OFFBOARD at 3 m. Position without MANUAL_CONTROL (h1): ACCEPTED, then
TEMPORARILY_REJECTED, STATUSTEXT CRITICAL "Switching to Position is currently not available";
PX4 stays in OFFBOARD. Hold (h2): ACCEPTED x2, Hold holds. Position with centred MANUAL_CONTROL
at 20 Hz (h3): ACCEPTED x2, Position holds (truth height 3.48 -> 3.47 m over 12 s), where
Position without sticks (a failsafe, recorded b / i) sinks at ~0.65 m/s.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from eaglemission.drivers.vehicles import px4
from emulator_support import read_tlog, scenario
from test_px4_recorded_facts import Gcs, M, make_emulator

from eaglemission.types import FlightMode

RUNS = {"h1": (3, 0, False), "h2": (4, 3, False), "h3": (3, 0, True)}
"""run -> DO_SET_MODE (main, sub), centred MANUAL_CONTROL streamed."""
WINDOW_S = 12.0  # recorded: MAVSDK kept its setpoints 12 s after the command, then landed


def recorded_takeover(tlogs: Path, run: str) -> dict[str, Any]:
    """The second client's command: its ACK results, the STATUSTEXTs, the mode PX4 then showed
    and the truth height change over the 12 s after it."""
    px4_msgs, _, t0 = scenario(tlogs, run)
    gcs_in = [(t - t0, m) for t, m in read_tlog(str(tlogs / f"scenario_{run}_gcs_to_px4.tlog"))]
    gcs_out = [(t - t0, m) for t, m in read_tlog(str(tlogs / f"scenario_{run}_px4_to_gcs.tlog"))]
    t_cmd = next(t for t, m in gcs_in if m.get_type() == "COMMAND_LONG"
                 and m.command == M.MAV_CMD_DO_SET_MODE)
    acks = [int(m.result) for t, m in gcs_out if m.get_type() == "COMMAND_ACK"
            and m.command == M.MAV_CMD_DO_SET_MODE and t >= t_cmd]
    texts = [str(m.text).strip() for t, m in gcs_out if m.get_type() == "STATUSTEXT"
             and t_cmd <= t < t_cmd + 1.0]
    modes = [px4.decode_custom_mode(m.custom_mode) for t, m in px4_msgs
             if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1 and t_cmd + 1.1 < t < t_cmd + WINDOW_S]
    truth = [(t, m.alt / 1000.0) for t, m in px4_msgs if m.get_type() == "HIL_STATE_QUATERNION"]
    h = [a for t, a in truth if t_cmd <= t <= t_cmd + WINDOW_S]
    return {"acks": acks, "texts": texts, "modes": set(modes), "dh": h[-1] - h[0],
            "min_dh": min(h) - h[0]}


class SecondGcs:
    """A pymavlink ground station as sysid 255 / compid 190 on the emulator (recorded h1-h3),
    optionally streaming centred MANUAL_CONTROL at 20 Hz (x = y = r = 0, z = 500)."""

    def __init__(self, gcs: Gcs, manual: bool) -> None:
        self.gcs, self.manual = gcs, manual
        self.mav = M.MAVLink(None, srcSystem=255, srcComponent=190)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def send(self, msg: Any) -> None:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.gcs.emu.feed(data)

    def _run(self) -> None:
        while not self._stop.wait(0.05 / self.gcs.emu.config.speedup):
            if self.manual:
                self.send(M.MAVLink_manual_control_message(1, 0, 0, 500, 0, 0))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def acks(self) -> list[int]:
        return [int(m.result) for _, _, m in self.gcs.out("COMMAND_ACK")
                if m.command == M.MAV_CMD_DO_SET_MODE and m.target_system == 255]


def emulator_takeover(main: int, sub: int, manual: bool) -> dict[str, Any]:
    """The scenario on the emulator: takeoff to 3 m, offboard hold, the second GCS's command;
    what it was answered, the modes shown and the truth height change over 12 s."""
    speedup = 5.0
    with Gcs(make_emulator(speedup=speedup, MIS_TAKEOFF_ALT=3.0)) as gcs:
        emu = gcs.emu
        gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        gcs.command(M.MAV_CMD_NAV_TAKEOFF)
        gcs.wait(lambda: emu.snapshot().mode == FlightMode.HOLD
                 and -emu.snapshot().true_position_ned_m[2] > 2.7, 30.0, "takeoff to 3 m")
        gcs.start_offboard_here()
        gcs.wait(lambda: emu.snapshot().mode == FlightMode.OFFBOARD, 5.0, "OFFBOARD")
        gcs.wait_sim(emu.snapshot().sim_time_s + 5.0)
        other = SecondGcs(gcs, manual)
        try:
            gcs.wait_sim(emu.snapshot().sim_time_s + 1.0)  # MANUAL_CONTROL flowing
            t_cmd = emu.snapshot().sim_time_s
            h0 = -emu.snapshot().true_position_ned_m[2]
            other.send(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 129, main, sub,
                                                      0, 0, 0, 0))
            heights = []
            while (s := emu.snapshot()).sim_time_s < t_cmd + WINDOW_S:
                heights.append(-s.true_position_ned_m[2])
                time.sleep(0.01)
            texts = [str(m.text).strip() for _, t, m in gcs.out("STATUSTEXT") if t >= t_cmd]
            modes = {px4.decode_custom_mode(m.custom_mode) for _, t, m in gcs.out("HEARTBEAT")
                     if t_cmd + 1.1 < t}
            return {"acks": other.acks(), "texts": texts, "modes": modes,
                    "dh": heights[-1] - h0, "min_dh": min(heights) - h0}
        finally:
            other.close()


A, TR = int(M.MAV_RESULT_ACCEPTED), int(M.MAV_RESULT_TEMPORARILY_REJECTED)


@pytest.mark.parametrize("run", ["h1", "h2", "h3"])
def test_fact_second_gcs_mode_change_answered_and_flown_as_px4(px4_tlogs: Path, run: str) -> None:
    rec = recorded_takeover(px4_tlogs, run)
    want_mode = {"h1": FlightMode.OFFBOARD, "h2": FlightMode.HOLD, "h3": FlightMode.POSCTL}[run]
    assert rec["acks"] == ([A, TR] if run == "h1" else [A, A]), rec
    assert rec["modes"] == {want_mode}, rec
    refused = "Switching to Position is currently not available"
    assert (refused in rec["texts"]) == (run == "h1"), rec["texts"]
    assert abs(rec["dh"]) < 0.2 and rec["min_dh"] > -0.5, rec  # recorded: no sinking

    ours = emulator_takeover(*RUNS[run])
    assert ours["acks"] == rec["acks"], ours
    assert ours["modes"] == rec["modes"], ours
    assert (refused in ours["texts"]) == (run == "h1"), ours["texts"]
    # the vehicle holds its height as PX4 did (recorded |dh| <= 0.12 m, lowest -0.43 m in h1;
    # sinking at 0.65 m/s would lose ~7 m)
    assert abs(ours["dh"]) < 0.4 and ours["min_dh"] > -0.55, ours
