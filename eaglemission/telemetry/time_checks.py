"""Checks of the telemetry's time base: late, stale, duplicated, out-of-order samples and jumps
of the autopilot's clock.

A sample carries two times: ``timestamp_ns``, stamped by the host on receipt, and
``autopilot_time_ns``, the autopilot's own stamp (MAVLink ``time_boot_ms`` / ``time_usec``;
None when the vehicle does not report it: then nothing is checked). The offset
``receipt - autopilot`` is the link's latency plus the clocks' difference; its smallest value
since the last anchoring is the anchor, so the *age* of the newest accepted sample is
``now - autopilot_time - anchor`` (latency beyond the best seen, plus the time since receipt).
The clocks drift apart: PX4 SITL's runs 0.65-1.6 % slow (recorded), 2 % on a loaded machine, so
the offset grows by up to 20 ms a second and a fixed anchor would read a 60 s flight's drift as
a stale link. The anchor may therefore rise by ``max_drift`` (5 %) of the receipt time that
passed: ``anchor = min(anchor + max_drift * dt, offset)``. A drift below it never adds up; a
delay that persists is absorbed at 50 ms a second (a 2 s delay reads stale for 30 s): by its
stamps alone a lasting delay cannot be told from a clock offset.

* a new message (new receipt stamp) with the autopilot time of the last one: a duplicate,
  refused;
* an autopilot time before the last one by at most ``jump_s``: out of order, refused (the
  mission never acts on an older sample than the one it has);
* an autopilot time before the last one by more than ``jump_s``, or an offset below the anchor
  by more than ``jump_s`` (the autopilot's clock ran ahead of the host's): a clock jump; the
  anchor is reset on the new sample and it is accepted (the mission's own times are the host's
  receipt stamps, so the re-anchored base is never used to command);
* an age beyond ``late_s``: late (reported, tolerated); beyond ``stale_s``: stale (the caller
  treats it as a link loss).
"""

from __future__ import annotations

from dataclasses import dataclass

from eaglemission.types import VehicleState

DUPLICATE = "telemetry_duplicate"
OUT_OF_ORDER = "telemetry_out_of_order"
CLOCK_JUMP = "autopilot_clock_jump"


@dataclass(frozen=True)
class Verdict:
    """What :meth:`TelemetryTimeCheck.check` made of one sample."""

    accepted: bool
    problem: str = ""
    """'' (fine), or DUPLICATE / OUT_OF_ORDER / CLOCK_JUMP."""
    text: str = ""


class TelemetryTimeCheck:
    """The time-base checks of one telemetry stream (see the module docstring)."""

    def __init__(self, *, jump_s: float = 1.0, max_drift: float = 0.05) -> None:
        if not jump_s > 0:
            raise ValueError(f"jump_s: must be > 0, got {jump_s}")
        if not 0 <= max_drift < 1:
            raise ValueError(f"max_drift: must be in [0, 1), got {max_drift}")
        self.jump_ns = int(jump_s * 1e9)
        self.max_drift = max_drift
        self.last: VehicleState | None = None
        self._last_stamps: tuple[int, int | None] | None = None  # (receipt, autopilot)
        self._anchor_ns: int | None = None

    def check(self, vs: VehicleState) -> Verdict:
        """Judge ``vs``; an accepted sample becomes :attr:`last`. The same message read again
        (same receipt and autopilot stamps) is accepted silently."""
        verdict = self.check_stamps(vs.timestamp_ns, vs.autopilot_time_ns)
        if verdict.accepted:
            self.last = vs
        return verdict

    def check_stamps(self, receipt_ns: int, autopilot_ns: int | None) -> Verdict:
        """:meth:`check` on one message's two stamps (a driver judging a raw stream)."""
        ap = autopilot_ns
        last = self._last_stamps
        if ap is None or last is None or last[1] is None:
            return self._accept(receipt_ns, ap)
        last_receipt, last_ap = last[0], last[1]
        if receipt_ns == last_receipt and ap == last_ap:
            return Verdict(True)
        if ap == last_ap:
            return Verdict(False, DUPLICATE, "a second message with the autopilot time of the "
                                             "last one: ignored")
        if ap < last_ap:
            back_s = (last_ap - ap) * 1e-9
            if last_ap - ap <= self.jump_ns:
                return Verdict(False, OUT_OF_ORDER, f"a sample {back_s * 1e3:.0f} ms older than "
                                                    "the last one: ignored")
            self._anchor_ns = None
            self._accept(receipt_ns, ap)
            return Verdict(True, CLOCK_JUMP, f"the autopilot's time went back {back_s:.2f} s: "
                                             "time base re-anchored")
        offset = receipt_ns - ap
        assert self._anchor_ns is not None
        if self._anchor_ns - offset > self.jump_ns:
            ahead_s = (self._anchor_ns - offset) * 1e-9
            self._anchor_ns = None
            self._accept(receipt_ns, ap)
            return Verdict(True, CLOCK_JUMP, f"the autopilot's time jumped {ahead_s:.2f} s "
                                             "ahead of the host's: time base re-anchored")
        return self._accept(receipt_ns, ap)

    def _accept(self, receipt_ns: int, autopilot_ns: int | None) -> Verdict:
        last = self._last_stamps
        self._last_stamps = (receipt_ns, autopilot_ns)
        if autopilot_ns is not None:
            offset = receipt_ns - autopilot_ns
            if self._anchor_ns is None:
                self._anchor_ns = offset
            else:  # the clocks may drift apart by max_drift (module docstring)
                dt_ns = max(0, receipt_ns - last[0]) if last is not None else 0
                self._anchor_ns = min(self._anchor_ns + int(self.max_drift * dt_ns), offset)
        return Verdict(True)

    def age_s(self, now_ns: int) -> float:
        """Age of the newest accepted sample at host time ``now_ns`` (0 without autopilot
        stamps: the vehicle's own ``link_ok`` is the only judge then)."""
        last = self._last_stamps
        if last is None or last[1] is None or self._anchor_ns is None:
            return 0.0
        return max(0.0, (now_ns - last[1] - self._anchor_ns) * 1e-9)
