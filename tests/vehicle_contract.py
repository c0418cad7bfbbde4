"""The Vehicle contract suite: one set of behaviours every Vehicle backend must show.

A backend test module defines an async fixture ``vehicle_backend`` that yields a *connected*
backend object (see :class:`VehicleBackend`) and a test class that inherits
:class:`VehicleContract`::

    from vehicle_contract import BackendBase, VehicleContract   # tests/, on sys.path

    @pytest.fixture(params=["calm", "windy"])
    async def vehicle_backend(request):
        backend = MyBackend(...)
        await backend.vehicle.connect()
        yield backend
        await backend.vehicle.close()

    class TestMyBackendContract(VehicleContract):
        pass

Backends: the simulated vehicle (tests/lab/vehicles/simulated/test_contract_simulated.py,
ManualClock: the whole suite runs in well under a second of wall time per test), the MAVSDK
driver talking to the MAVLink emulator (tests/drivers/vehicles/test_contract_mavsdk.py), and a real PX4 SITL when ``EAGLEMISSION_PX4_URL``
is set (skipped otherwise).

Every wait is bounded (``backend.wait``); timeouts are in the backend's clock seconds and sized
for a real PX4 v1.16 SITL (takeoff to 5 m takes ~9 s there, heartbeats are 1 Hz so a mode
change may show up to ``report_lag_s`` late). Hooks a backend cannot provide are left out of
``hooks`` and the tests that need them are skipped, never faked.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

import pytest

from eaglemission.clock import Clock
from eaglemission.errors import DriverError, ModeChangedExternally, VehicleError
from eaglemission.geometry import geodetic_to_ned, ned_to_geodetic, wrap_deg
from eaglemission.interfaces import Vehicle
from eaglemission.types import FlightMode, Setpoint, VehicleState, Waypoint

TAKEOFF_ALTITUDE_M = 5.0
TAKEOFF_TIMEOUT_S = 40.0
MOVE_TIMEOUT_S = 40.0
LAND_TIMEOUT_S = 60.0
RTL_TIMEOUT_S = 180.0  # PX4's default RTL_RETURN_ALT is 60 m: climb, return, descend at ~1 m/s
SETPOINT_PERIOD_S = 0.05  # 20 Hz, like MAVSDK's own re-sending
HOOKS = frozenset({"link_loss", "pilot_mode_change", "block_event_loop"})


class VehicleBackend(Protocol):
    """What a backend fixture yields: the Vehicle, its clock and fault-injection hooks."""

    name: str
    vehicle: Vehicle
    clock: Clock
    watchdog_timeout_s: float  # fresh setpoints missing this long -> the vehicle leaves OFFBOARD
    report_lag_s: float  # how late ``state()`` may show a change (PX4 heartbeat: 1 Hz)
    hooks: frozenset[str]  # subset of HOOKS this backend provides

    async def sleep(self, seconds: float) -> None: ...

    async def wait(self, predicate: Callable[[VehicleState], object], timeout_s: float,
                   what: str) -> VehicleState: ...

    async def link_loss(self, duration_s: float) -> None:
        """Start a link loss of ``duration_s`` and return at once."""

    async def pilot_mode_change(self, mode: FlightMode) -> None:
        """Someone else (pilot, ground station) switches the flight mode."""

    async def block_event_loop(self, seconds: float) -> None:
        """Block the event loop running the mission for ``seconds`` (a hung mission loop),
        then return."""


class BackendBase:
    """Default ``sleep`` and ``wait`` on the backend's clock; hooks raise until provided."""

    name = "base"
    watchdog_timeout_s = 0.5
    report_lag_s = 0.0
    hooks: frozenset[str] = frozenset()

    def __init__(self, vehicle: Vehicle, clock: Clock) -> None:
        self.vehicle = vehicle
        self.clock = clock

    async def sleep(self, seconds: float) -> None:
        await self.clock.sleep(seconds)

    async def wait(self, predicate: Callable[[VehicleState], object], timeout_s: float,
                   what: str, *, poll_s: float = 0.05) -> VehicleState:
        deadline = self.clock.now_ns() + int(timeout_s * 1e9)
        while True:
            state = self.vehicle.state()
            if predicate(state):
                return state
            if self.clock.now_ns() >= deadline:
                events = "\n".join(f"  {e.timestamp_ns / 1e9:9.3f} {e.kind}: {e.text}"
                                   for e in list(self.vehicle.events())[-12:])
                pytest.fail(f"[{self.name}] {what}: not reached within {timeout_s:g} s; last state: "
                            f"mode={state.flight_mode.value} armed={state.armed} "
                            f"in_air={state.in_air} ned={_fmt(state.position_ned_m)} "
                            f"alt={state.relative_altitude_m:.2f} link_ok={state.link_ok}\n"
                            f"recent events:\n{events}")
            await self.sleep(poll_s)

    async def link_loss(self, duration_s: float) -> None:
        raise NotImplementedError("link_loss")

    async def pilot_mode_change(self, mode: FlightMode) -> None:
        raise NotImplementedError("pilot_mode_change")

    async def block_event_loop(self, seconds: float) -> None:
        raise NotImplementedError("block_event_loop")


# ---------------------------------------------------------------------------------------------
# Helpers (composable steps, used by the tests and reusable by backend-specific tests)
# ---------------------------------------------------------------------------------------------
def _fmt(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"


def _dist(a: Sequence[float], b: Sequence[float]) -> float:
    return math.dist(a, b)


def _settled_near(goal_ned_m: Sequence[float], radius_m: float = 0.5, speed_mps: float = 0.3,
                  window_s: float = 1.0) -> Callable[[VehicleState], bool]:
    """A ``stream_until`` predicate: within ``radius_m`` of the goal, below ``speed_mps`` by
    the velocity estimate, and moved less than ``speed_mps * window_s`` over the last
    ``window_s`` of samples (judged on the position the test then asserts on)."""
    recent: list[tuple[int, Sequence[float]]] = []
    window_ns = int(window_s * 1e9)

    def settled(st: VehicleState) -> bool:
        if not recent or st.timestamp_ns > recent[-1][0]:
            recent.append((st.timestamp_ns, st.position_ned_m))
        while recent[0][0] < st.timestamp_ns - window_ns:
            recent.pop(0)
        span_ns = st.timestamp_ns - recent[0][0]
        return (_dist(st.position_ned_m, goal_ned_m) < radius_m
                and _dist(st.velocity_ned_mps, (0.0, 0.0, 0.0)) < speed_mps
                and span_ns >= 0.9 * window_ns
                and _dist(recent[0][1], st.position_ned_m) < speed_mps * window_s)

    return settled


def _require_hook(b: VehicleBackend, hook: str) -> None:
    if hook not in b.hooks:
        pytest.skip(f"backend {b.name!r} has no {hook!r} hook")


async def arm(b: VehicleBackend) -> None:
    await b.wait(lambda s: s.armable and s.position_valid, 30.0, "armable with a valid position")
    await b.vehicle.arm()
    await b.wait(lambda s: s.armed, 2.0 + b.report_lag_s, "armed")


async def take_off(b: VehicleBackend, altitude_m: float = TAKEOFF_ALTITUDE_M) -> VehicleState:
    """Arm, take off, wait for the altitude and for the autopilot's switch to HOLD."""
    await arm(b)
    await b.vehicle.takeoff(altitude_m)
    await b.wait(lambda s: s.relative_altitude_m >= altitude_m - 0.5, TAKEOFF_TIMEOUT_S,
                 f"climb to {altitude_m - 0.5:g} m")
    return await b.wait(lambda s: s.flight_mode == FlightMode.HOLD and s.in_air,
                        5.0 + b.report_lag_s, "TAKEOFF -> HOLD at altitude")


def current_setpoint(s: VehicleState) -> Setpoint:
    """The first offboard setpoint: the current position and yaw (never 0, 0, 0)."""
    n, e, d = s.position_ned_m
    return Setpoint(n, e, d, s.yaw_deg)


async def start_offboard_here(b: VehicleBackend) -> Setpoint:
    s = b.vehicle.state()
    sp = current_setpoint(s)
    await b.vehicle.start_offboard(sp)  # the driver sends it before switching (PX4 needs one)
    await b.wait(lambda st: st.flight_mode == FlightMode.OFFBOARD, 2.0 + b.report_lag_s, "OFFBOARD")
    return sp


async def stream(b: VehicleBackend, setpoint: Setpoint, duration_s: float) -> None:
    """Send ``setpoint`` at 20 Hz for ``duration_s`` (the mission's setpoint timer)."""
    t_end = b.clock.now_ns() + int(duration_s * 1e9)
    while b.clock.now_ns() < t_end:
        await b.vehicle.set_setpoint(setpoint)
        await b.sleep(SETPOINT_PERIOD_S)


async def stream_until(b: VehicleBackend, setpoint: Setpoint, done: Callable[[VehicleState], bool],
                       timeout_s: float, what: str) -> VehicleState:
    t_end = b.clock.now_ns() + int(timeout_s * 1e9)
    while True:
        await b.vehicle.set_setpoint(setpoint)
        s = b.vehicle.state()
        if done(s):
            return s
        if b.clock.now_ns() >= t_end:
            pytest.fail(f"[{b.name}] {what}: not reached within {timeout_s:g} s while streaming "
                        f"{setpoint}; at {_fmt(s.position_ned_m)} mode={s.flight_mode.value}")
        await b.sleep(SETPOINT_PERIOD_S)


def _mode_events(b: VehicleBackend, since_ns: int) -> list[str]:
    return [e.text for e in b.vehicle.events() if e.kind == "mode" and e.timestamp_ns >= since_ns]


# ---------------------------------------------------------------------------------------------
# The suite
# ---------------------------------------------------------------------------------------------
class VehicleContract:
    """Inherit in a ``Test...`` class next to a ``vehicle_backend`` fixture."""

    async def test_connect_gives_telemetry_and_history(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        assert isinstance(b.vehicle, Vehicle)
        s = await b.wait(lambda st: st.home is not None and st.position_valid, 30.0,
                         "home and a valid position")
        assert not s.armed and not s.in_air
        assert s.link_ok
        assert abs(s.relative_altitude_m) < 1.5  # PX4 on the ground reads -1.2 .. +0.1 m
        assert math.dist(s.position_ned_m[:2], (0.0, 0.0)) < 1.0  # home vs EKF origin: dm
        assert abs(b.clock.now_ns() - s.timestamp_ns) < 1e9  # stamped with the host clock
        await b.sleep(0.5)
        s2 = b.vehicle.state()
        assert s2.timestamp_ns > s.timestamp_ns  # telemetry keeps flowing
        mid = (s.timestamp_ns + s2.timestamp_ns) // 2
        at = b.vehicle.state_at(mid)
        assert at is not None and at.timestamp_ns == mid
        assert b.vehicle.state_at(s2.timestamp_ns - 60_000_000_000) is None  # outside history

    async def test_refuses_takeoff_while_disarmed(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        await b.wait(lambda st: st.home is not None, 30.0, "home")
        with pytest.raises(VehicleError) as info:
            await b.vehicle.takeoff(TAKEOFF_ALTITUDE_M)
        assert "takeoff" in info.value.origin
        assert info.value.result  # a result code, e.g. COMMAND_DENIED
        await b.sleep(2.0)
        s = b.vehicle.state()
        assert not s.armed and not s.in_air and s.relative_altitude_m < 0.5

    async def test_arm_and_takeoff_to_altitude(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        await arm(b)
        t0 = b.clock.now_ns()
        await b.vehicle.takeoff(TAKEOFF_ALTITUDE_M)
        returned_ns = b.clock.now_ns()
        # returns when accepted, not at altitude: the climb goes on for seconds after it (a
        # fixed height bound at the return would time the host's load, not the backend)
        assert (returned_ns - t0) / 1e9 < 3.0
        assert b.vehicle.state().relative_altitude_m < TAKEOFF_ALTITUDE_M - 1.0
        s = await b.wait(lambda st: st.relative_altitude_m >= TAKEOFF_ALTITUDE_M - 0.5,
                         TAKEOFF_TIMEOUT_S, "climb")
        assert (s.timestamp_ns - returned_ns) / 1e9 > 1.0
        assert s.armed
        assert (s.timestamp_ns - t0) / 1e9 > 1.0  # takeoff takes seconds
        s = await b.wait(lambda st: st.flight_mode == FlightMode.HOLD, 5.0 + b.report_lag_s,
                         "TAKEOFF -> HOLD")
        assert s.in_air
        assert abs(s.relative_altitude_m - TAKEOFF_ALTITUDE_M) < 0.7
        await b.sleep(2.0)
        s = b.vehicle.state()
        assert abs(s.relative_altitude_m - TAKEOFF_ALTITUDE_M) < 0.7  # holds the altitude
        assert math.dist(s.velocity_ned_mps, (0.0, 0.0, 0.0)) < 0.5
        past = b.vehicle.state_at(s.timestamp_ns - 500_000_000)
        assert past is not None and past.in_air

    async def test_goto(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        s = await take_off(b)
        assert s.home is not None
        n, e, _ = s.position_ned_m
        goal = (n + 10.0, e + 5.0, -TAKEOFF_ALTITUDE_M)
        target = ned_to_geodetic(s.home, *goal)  # AMSL = home AMSL + relative altitude
        await b.vehicle.goto(target, 90.0)
        s = await b.wait(lambda st: _dist(st.position_ned_m, goal) < 1.0, MOVE_TIMEOUT_S,
                         f"goto {_fmt(goal)}")
        s = await b.wait(lambda st: abs(wrap_deg(st.yaw_deg - 90.0)) < 10.0, 10.0, "yaw 90")
        assert s.flight_mode == FlightMode.HOLD  # PX4: DO_REPOSITION flies in Hold (LOITER)

    async def test_mission_with_progress(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        wps = [Waypoint(10.0, 0.0, 6.0, speed_mps=4.0), Waypoint(10.0, 10.0, 6.0, speed_mps=3.0),
               Waypoint(0.0, 10.0, 6.0)]
        await b.vehicle.upload_mission(wps)
        assert b.vehicle.mission_progress().current == 0
        await arm(b)
        await b.vehicle.start_mission()  # from the ground: PX4 climbs first
        await b.wait(lambda st: st.flight_mode == FlightMode.MISSION, 2.0 + b.report_lag_s, "MISSION")
        seen: list[int] = []
        visited: list[tuple[float, float, float]] = []

        def progressing(st: VehicleState) -> bool:
            p = b.vehicle.mission_progress()
            if not seen or seen[-1] != p.current:
                seen.append(p.current)
                visited.append(st.position_ned_m)
            assert p.total == len(wps)
            return p.finished

        await b.wait(progressing, 120.0, "mission finished")
        assert seen == sorted(seen), f"progress went backwards: {seen}"
        assert seen[-1] == len(wps) and {1, 2, 3} <= set(seen), seen
        for k, w in enumerate(wps, start=1):  # when item k is reached we are near it
            i = seen.index(k)
            assert math.dist(visited[i][:2], (w.north_m, w.east_m)) < 2.5, (k, visited[i])
        s = b.vehicle.state()
        assert abs(s.relative_altitude_m - 6.0) < 1.0

    async def test_offboard_to_ned_point(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        await take_off(b)
        first = await start_offboard_here(b)
        goal = Setpoint(first.north_m + 8.0, first.east_m - 3.0, first.down_m - 1.0,
                        wrap_deg(first.yaw_deg + 45.0))
        # reached and settled: PX4 SITL overshot an 8.5 m move by 0.8-1.0 m and took ~6 s back
        # (its recorded 2 m steps overshoot by up to 22 %), so "arrived" is near and slow.
        # Slow by the velocity estimate and by the position itself over the last second: PX4
        # SIH's velocity estimate is off its own position's motion by ~0.3 m/s, and a pass
        # through the 0.5 m ball on an overshoot's way out read as "slow" by the first alone.
        s = await stream_until(b, goal, _settled_near(goal.position_ned_m), MOVE_TIMEOUT_S,
                               "offboard point, settled")
        assert s.flight_mode == FlightMode.OFFBOARD
        worst = 0.0
        for _ in range(20):  # ...and held for 1 s
            await stream(b, goal, SETPOINT_PERIOD_S)
            s = b.vehicle.state()
            worst = max(worst, _dist(s.position_ned_m, goal.position_ned_m))
        assert worst < 0.5, f"[{b.name}] left the point by {worst:.2f} m while holding it"
        assert abs(wrap_deg(s.yaw_deg - goal.yaw_deg)) < 5.0
        await b.vehicle.stop_offboard()
        await b.wait(lambda st: st.flight_mode != FlightMode.OFFBOARD, 2.0 + b.report_lag_s,
                     "leave OFFBOARD")

    async def _assert_holds_after_setpoints_stop(self, b: VehicleBackend, stop_pos: Sequence[float],
                                                 t_stop_ns: int) -> None:
        s = await b.wait(lambda st: st.flight_mode == FlightMode.HOLD,
                         b.watchdog_timeout_s + b.report_lag_s + 1.0, "HOLD after setpoints stop")
        assert (s.timestamp_ns - t_stop_ns) / 1e9 >= b.watchdog_timeout_s * 0.5
        with pytest.raises(ModeChangedExternally):  # our commanding has ended and we are told
            for _ in range(int((b.report_lag_s + 1.0) / SETPOINT_PERIOD_S) + 1):
                await b.vehicle.set_setpoint(current_setpoint(b.vehicle.state()))
                await b.sleep(SETPOINT_PERIOD_S)
        await b.sleep(3.0)
        s = b.vehicle.state()
        assert s.flight_mode == FlightMode.HOLD and s.in_air
        assert math.dist(s.position_ned_m[:2], stop_pos[:2]) < 2.0  # holds, does not wander
        assert abs(s.position_ned_m[2] - stop_pos[2]) < 1.0  # and does not descend

    async def test_watchdog_hold_when_setpoints_stop(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        await take_off(b)
        first = await start_offboard_here(b)
        goal = Setpoint(first.north_m + 3.0, first.east_m, first.down_m, first.yaw_deg)
        await stream(b, goal, 4.0)
        t_stop = b.clock.now_ns()
        stop_pos = b.vehicle.state().position_ned_m
        # the mission loop stops sending (task cancelled / crashed); the loop itself runs
        await self._assert_holds_after_setpoints_stop(b, stop_pos, t_stop)

    async def test_watchdog_hold_when_event_loop_blocked(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        _require_hook(b, "block_event_loop")
        await take_off(b)
        first = await start_offboard_here(b)
        goal = Setpoint(first.north_m + 3.0, first.east_m, first.down_m, first.yaw_deg)
        await stream(b, goal, 4.0)
        t_stop = b.clock.now_ns()
        stop_pos = b.vehicle.state().position_ned_m
        # a hung mission loop: nothing on the loop runs (MAVSDK would keep re-sending the last
        # setpoint by itself, so only a watchdog outside the loop can notice)
        await b.block_event_loop(b.watchdog_timeout_s + 1.5)
        await self._assert_holds_after_setpoints_stop(b, stop_pos, t_stop)

    async def test_external_mode_change_stops_our_commanding(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        _require_hook(b, "pilot_mode_change")
        await take_off(b)
        first = await start_offboard_here(b)
        await stream(b, first, 1.0)
        t0 = b.clock.now_ns()
        await b.pilot_mode_change(FlightMode.HOLD)  # a ground station switches to Hold
        with pytest.raises(ModeChangedExternally):
            await stream(b, first, 2.0 + b.report_lag_s)
        s = await b.wait(lambda st: st.flight_mode == FlightMode.HOLD, 1.0 + b.report_lag_s, "HOLD")
        assert s.in_air
        assert any("HOLD" in text for text in _mode_events(b, t0)), "mode change not reported"
        await b.sleep(1.0)
        assert b.vehicle.state().flight_mode == FlightMode.HOLD  # we did not take it back
        # taking control back is explicit
        await start_offboard_here(b)
        await stream(b, current_setpoint(b.vehicle.state()), 0.5)

    async def test_link_loss_and_recovery(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        _require_hook(b, "link_loss")
        s0 = await take_off(b)
        loss_s = 6.0
        t0 = b.clock.now_ns()
        await b.link_loss(loss_s)
        await b.wait(lambda st: not st.link_ok, 5.0, "link_ok False during the loss")
        with pytest.raises(DriverError):  # no answer: a typed error, bounded by the timeout
            await b.vehicle.hold()
        assert (b.clock.now_ns() - t0) / 1e9 < loss_s + 5.0
        s = await b.wait(lambda st: st.link_ok, loss_s + 10.0, "link regained")
        await b.sleep(0.5)
        s = b.vehicle.state()
        assert abs(b.clock.now_ns() - s.timestamp_ns) < 1e9  # fresh telemetry again
        await b.vehicle.hold()  # commands work again
        assert s.in_air and s.armed
        assert math.dist(s.position_ned_m, s0.position_ned_m) < 2.0  # PX4 default: no action

    async def test_land_and_disarm(self, vehicle_backend: VehicleBackend) -> None:
        b = vehicle_backend
        await take_off(b)
        with pytest.raises(VehicleError):
            await b.vehicle.disarm()  # refused in the air
        await b.sleep(1.0)
        assert b.vehicle.state().armed and b.vehicle.state().in_air
        await b.vehicle.land()
        await b.wait(lambda st: st.flight_mode == FlightMode.LAND, 1.0 + b.report_lag_s, "LAND")
        s = await b.wait(lambda st: not st.in_air, LAND_TIMEOUT_S, "landed")
        assert s.relative_altitude_m < 1.0
        await b.vehicle.disarm()  # accepted on the ground (or already auto-disarmed)
        await b.wait(lambda st: not st.armed, 3.0 + b.report_lag_s, "disarmed")

    async def test_return_to_launch_right_after_offboard_lands_at_home(
            self, vehicle_backend: VehicleBackend) -> None:
        """What a mission's final action does: leave offboard, then return at once. The vehicle
        must start moving, come home, land and disarm by itself (PX4: "Disarmed by landing")."""
        b = vehicle_backend
        await take_off(b)
        first = await start_offboard_here(b)
        goal = Setpoint(first.north_m + 6.0, first.east_m + 3.0, first.down_m, first.yaw_deg)
        await stream_until(b, goal, lambda st: _dist(st.position_ned_m, goal.position_ned_m) < 1.0,
                           MOVE_TIMEOUT_S, "offboard point")
        await b.vehicle.set_setpoint(goal)
        await b.vehicle.stop_offboard()
        await b.vehicle.return_to_launch()  # no pause: nothing still in flight may undo it
        t0 = b.clock.now_ns()
        s0 = await b.wait(lambda st: st.flight_mode == FlightMode.RETURN_TO_LAUNCH,
                          1.0 + b.report_lag_s, "RETURN_TO_LAUNCH")

        def home_distance_m(st: VehicleState) -> float:
            assert st.home is not None
            n, e, _ = geodetic_to_ned(st.home, st.geodetic)
            return math.hypot(n, e)

        d0 = home_distance_m(s0)
        assert d0 > 5.0
        # on its way within seconds: climbing to the return altitude or flying home
        await b.wait(lambda st: st.relative_altitude_m > s0.relative_altitude_m + 1.0
                     or home_distance_m(st) < d0 - 1.0, 10.0 + b.report_lag_s, "RTL under way")
        s = await b.wait(lambda st: not st.armed and not st.in_air, RTL_TIMEOUT_S,
                         "RTL landed and disarmed")
        assert home_distance_m(s) < 2.0, s.position_ned_m  # home vs EKF origin: decimetres
        assert s.relative_altitude_m < 1.5  # PX4 on the ground reads -1.2 .. +0.1 m
        assert (b.clock.now_ns() - t0) / 1e9 < RTL_TIMEOUT_S
