"""The mavsdk vehicle's UDP fault relay on loopback sockets: what passes, when and how, for each
injected link fault (real sockets, real MAVLink bytes; no MAVSDK needed)."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest
from eaglemission.drivers.vehicles.mavsdk.vehicle import MavsdkVehicle, MavsdkVehicleConfig
from eaglemission.lab.faults.config import FaultsConfig
from eaglemission.lab.faults.injection import FaultInjection, injector_of
from eaglemission.lab.faults.link_relay import LinkFaultRelay, first_msgid, parse_udpin
from eaglemission.lab.vehicles.emulator.dialect import mavlink

from eaglemission.config import load_config
from eaglemission.config.models import PluginSection
from eaglemission.errors import ConfigError

pytestmark = pytest.mark.machine  # UDP sockets in real time (tests/conftest.py)


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Ends:
    """The autopilot's socket (sends to the relay) and the client's (bound where MAVSDK would)."""

    def __init__(self, relay: LinkFaultRelay) -> None:
        self.autopilot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.autopilot.bind(("127.0.0.1", 0))
        self.client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.client.bind(("127.0.0.1", relay.client_port))
        self.relay_addr = relay.listen
        for s in (self.autopilot, self.client):
            s.settimeout(0.02)
        self.client_peer: tuple[str, int] | None = None

    def down(self, data: bytes) -> None:
        self.autopilot.sendto(data, self.relay_addr)

    def up(self, data: bytes) -> None:
        assert self.client_peer is not None, "the client answers whoever sent to it"
        self.client.sendto(data, self.client_peer)

    def received(self, sock: socket.socket, wait_s: float) -> list[tuple[float, bytes]]:
        out, deadline = [], time.monotonic() + wait_s
        while time.monotonic() < deadline:
            try:
                data, addr = sock.recvfrom(65535)
            except OSError:
                continue
            if sock is self.client:
                self.client_peer = addr
            out.append((time.monotonic(), data))
        return out


@pytest.fixture
def ends() -> Iterator[tuple[LinkFaultRelay, Ends]]:
    relay = LinkFaultRelay(f"udpin://127.0.0.1:{_port()}", seed=3)
    relay.start()
    e = Ends(relay)
    try:
        yield relay, e
    finally:
        relay.stop()
        e.autopilot.close()
        e.client.close()


def _attitude(boot_ms: int, seq: int = 0) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.seq = seq
    return bytes(mavlink.MAVLink_attitude_quaternion_message(boot_ms, 1.0, 0.0, 0.0, 0.0, 0.1,
                                                             0.2, 0.3).pack(mav))


def test_both_directions_pass_unchanged(ends: tuple[LinkFaultRelay, Ends]) -> None:
    _, e = ends
    e.down(b"telemetry")
    assert [d for _, d in e.received(e.client, 0.3)] == [b"telemetry"]
    e.up(b"command")
    assert [d for _, d in e.received(e.autopilot, 0.3)] == [b"command"]


def test_a_link_loss_drops_both_ways_for_its_window(ends: tuple[LinkFaultRelay, Ends]) -> None:
    relay, e = ends
    e.down(b"hello")
    e.received(e.client, 0.2)
    relay.inject_link_loss(0.4)
    e.down(b"lost")
    e.up(b"lost too")
    assert e.received(e.client, 0.15) == [] and e.received(e.autopilot, 0.1) == []
    time.sleep(0.25)
    e.down(b"back")
    assert [d for _, d in e.received(e.client, 0.3)] == [b"back"]
    assert relay.counts["dropped"] == 2


def test_a_delay_holds_each_datagram_in_order(ends: tuple[LinkFaultRelay, Ends]) -> None:
    relay, e = ends
    relay.inject_link_delay(0.25, 5.0)
    sent = []
    for i in range(5):
        sent.append(time.monotonic())
        e.down(b"%d" % i)
        time.sleep(0.01)
    got = e.received(e.client, 0.6)
    assert [d for _, d in got] == [b"0", b"1", b"2", b"3", b"4"]
    assert all(t - s >= 0.24 for (t, _), s in zip(got, sent, strict=True))


def test_duplicates_arrive_twice(ends: tuple[LinkFaultRelay, Ends]) -> None:
    relay, e = ends
    relay.inject_link_duplicate(2.0)
    e.down(b"a")
    e.down(b"b")
    assert [d for _, d in e.received(e.client, 0.3)] == [b"a", b"a", b"b", b"b"]


def test_reordering_swaps_datagrams_and_loses_none(ends: tuple[LinkFaultRelay, Ends]) -> None:
    relay, e = ends
    relay.inject_link_reorder(5.0)
    sent = [b"%02d" % i for i in range(40)]
    for d in sent:
        e.down(d)
        time.sleep(0.005)
    got = [d for _, d in e.received(e.client, 0.5)]
    assert sorted(got) == sent
    assert got != sent, "some datagram must arrive after one sent after it"


def test_a_clock_jump_restamps_the_autopilots_messages(ends: tuple[LinkFaultRelay, Ends]) -> None:
    relay, e = ends
    relay.inject_autopilot_clock_jump(-5.0)
    e.down(_attitude(20_000, seq=7))
    (_, data), = e.received(e.client, 0.3)
    msg, = mavlink.MAVLink(None).parse_buffer(data)  # CRC checked by the parser
    assert msg.get_type() == "ATTITUDE_QUATERNION"
    assert msg.time_boot_ms == 15_000 and msg.get_seq() == 7 and msg.get_srcSystem() == 1
    assert (msg.q1, msg.rollspeed) == (1.0, pytest.approx(0.1))


def test_a_jump_back_past_zero_wraps_each_stamp_at_its_own_width(
        ends: tuple[LinkFaultRelay, Ends]) -> None:
    """PX4 sends SERVO_OUTPUT_RAW, whose ``time_usec`` is a uint32 (a uint64 elsewhere). A
    -30 s jump 20 s after PX4's boot wrapped it as a uint64: the re-encoding raised, the relay
    thread died and the link stayed cut for the rest of the flight (a local PX4 SITL, issue
    13/16); the emulator sends no SERVO_OUTPUT_RAW, so its campaigns never met it."""
    relay, e = ends
    relay.inject_autopilot_clock_jump(-30.0)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    e.down(bytes(mavlink.MAVLink_servo_output_raw_message(20_000_000, 0, *[1500] * 8).pack(mav)))
    e.down(bytes(mavlink.MAVLink_hil_actuator_controls_message(20_000_000, [0.0] * 16, 0,
                                                                 0).pack(mav)))
    e.down(_attitude(20_000, seq=9))
    got = [m for _, d in e.received(e.client, 0.5) for m in mavlink.MAVLink(None).parse_buffer(d)]
    by_type = {m.get_type(): m for m in got}
    assert by_type["SERVO_OUTPUT_RAW"].time_usec == (20_000_000 - 30_000_000) % 2**32
    assert by_type["HIL_ACTUATOR_CONTROLS"].time_usec == (20_000_000 - 30_000_000) % 2**64
    assert by_type["ATTITUDE_QUATERNION"].time_boot_ms == (20_000 - 30_000) % 2**32
    e.down(_attitude(21_000, seq=10))  # and the relay is still relaying
    assert e.received(e.client, 0.3)


def test_the_simulators_truth_is_not_on_the_faulty_link(ends: tuple[LinkFaultRelay, Ends]) -> None:
    relay, e = ends
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    truth = bytes(mavlink.MAVLink_hil_state_quaternion_message(
        0, [1.0, 0, 0, 0], 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav))
    assert first_msgid(truth) == 115
    relay.inject_link_loss(2.0)
    e.down(truth)
    e.down(_attitude(1000))
    assert [d for _, d in e.received(e.client, 0.3)] == [truth]


def test_bad_arguments_and_urls_are_refused() -> None:
    with pytest.raises(ConfigError, match="udpin://HOST:PORT"):
        parse_udpin("udpout://127.0.0.1:14540")
    relay = LinkFaultRelay("udpin://127.0.0.1:1")
    with pytest.raises(RuntimeError, match="not running"):
        relay.inject_link_loss(1.0)
    cfg = load_config(check_plugins=False)
    serial = cfg.model_copy(update={"vehicle": PluginSection(
        type="mavsdk", params={"url": "serial:///dev/ttyACM0:921600"})})
    section = FaultInjection(FaultsConfig.model_validate(
        {"inject": [{"kind": "link_loss", "at_s": 1.0}]}))
    with pytest.raises(ConfigError, match="needs vehicle.params.url = udpin://HOST:PORT"):
        section.prepare(serial)


def test_the_faults_section_puts_a_relay_only_before_a_mavsdk_vehicle_with_link_kinds() -> None:
    cfg = load_config(check_plugins=False)
    mavsdk = cfg.model_copy(update={"vehicle": PluginSection(
        type="mavsdk", params={"url": "udpin://127.0.0.1:0"})})
    link = FaultInjection(FaultsConfig.model_validate(
        {"inject": [{"kind": "link_delay", "at_s": 1.0, "size": 0.2}]}))
    gps = FaultInjection(FaultsConfig.model_validate({"inject": [{"kind": "gps_loss", "at_s": 1}]}))
    try:
        assert gps.prepare(mavsdk) is mavsdk and gps.relay is None
        assert link.prepare(cfg) is cfg and link.relay is None  # the simulated vehicle's own
        flown = link.prepare(mavsdk)
        assert link.relay is not None
        assert flown.vehicle.params["url"] == link.relay.client_url != "udpin://127.0.0.1:0"
        plain = MavsdkVehicle(MavsdkVehicleConfig())
        assert injector_of(plain, "link_delay") is None
        assert injector_of(plain, "link_delay", link.relay) == link.relay.inject_link_delay
        assert injector_of(plain, "gps_loss", link.relay) is None  # the autopilot's world
    finally:
        link.close()
