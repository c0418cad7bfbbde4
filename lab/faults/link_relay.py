"""A loopback UDP relay between an autopilot and MAVSDK that carries injected link faults in
real time: the ``faults:`` section's link kinds on a real MAVLink path.

The relay takes the address the autopilot sends to (the ``udpin://HOST:PORT`` MAVSDK would have
bound: PX4 SITL's 14540, the emulator's port) and passes every datagram to MAVSDK on a free
loopback port (:attr:`LinkFaultRelay.client_url`), and MAVSDK's answers back to the autopilot.
While a fault is injected it does what a bad radio link does:

* ``link_loss``: nothing passes, either way;
* ``link_delay``: every datagram passes ``delay_s`` late, in order (the link is a queue);
* ``link_duplicate``: every datagram passes twice;
* ``link_reorder``: half the datagrams, drawn at random, arrive :data:`REORDER_LATE_S` late,
  after ones sent after them (a 50 Hz stream's samples swap; none is lost);
* ``autopilot_clock_jump``: the autopilot's stamps (``time_boot_ms``, ``time_usec``) in what it
  sends are shifted by ``jump_s`` from then on (re-encoded with pymavlink, CRC and sequence
  kept).

The simulator's ground truth (HIL_STATE_QUATERNION, on the same UDP link only because SITL
puts it there) passes untouched: it stands for the world, which no radio fault delays.

Testing only: a relay on the flight link adds a hop and a thread; the ``faults`` section starts
one only when it injects a link fault into a ``mavsdk`` vehicle.
"""

from __future__ import annotations

import heapq
import logging
import math
import random
import selectors
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from eaglemission.errors import ConfigError

log = logging.getLogger(__name__)

REORDER_LATE_S = 0.05
"""How late a reordered datagram arrives: longer than a 50 Hz stream's period."""
DOWN, UP = 0, 1  # autopilot -> client, client -> autopilot
TRUTH_MSGIDS = frozenset({115})  # HIL_STATE_QUATERNION: the simulator's ground truth


def first_msgid(data: bytes) -> int | None:
    """The message id of the first MAVLink frame in ``data`` (v2 or v1), None if none."""
    if len(data) >= 10 and data[0] == 0xFD:
        return int.from_bytes(data[7:10], "little")
    if len(data) >= 6 and data[0] == 0xFE:
        return data[5]
    return None


def parse_udpin(url: str) -> tuple[str, int]:
    """``udpin://HOST:PORT`` -> (host, port); ConfigError otherwise."""
    scheme, sep, rest = url.partition("://")
    host, _, port = rest.rpartition(":")
    if scheme != "udpin" or not sep or not host or not port.isdigit():
        raise ConfigError(f"vehicle.params.url: the fault relay needs udpin://HOST:PORT (the "
                          f"address the autopilot sends to), got {url!r}")
    return host, int(port)


def _window_s(duration_s: float, origin: str) -> float:
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"{origin}: duration_s must be > 0, got {duration_s}")
    return float(duration_s)


def _wrap(m: Any, name: str, value: int) -> int:
    """``value`` wrapped to field ``name``'s unsigned width (``time_usec`` is a uint32 in
    SERVO_OUTPUT_RAW, a uint64 elsewhere: PX4 sends both)."""
    bits = {"uint8_t": 8, "uint16_t": 16, "uint32_t": 32}.get(
        m.fieldtypes[m.fieldnames.index(name)], 64)
    return int(value % 2**bits)


def shift_stamps(data: bytes, jump_us: int, parser: Any, packer: Any) -> bytes:
    """``data`` (one datagram of MAVLink) with each message's ``time_boot_ms`` / ``time_usec``
    shifted by ``jump_us``; messages pymavlink cannot parse or pack again pass unchanged."""
    try:
        msgs = parser.parse_buffer(data) or []
    except Exception:  # not MAVLink we know: pass it on as it came
        return data
    if not msgs:
        return data
    out = bytearray()
    for m in msgs:
        fields = m.get_fieldnames()
        if "time_boot_ms" not in fields and "time_usec" not in fields:
            out += m.get_msgbuf()
            continue
        original = bytes(m.get_msgbuf())
        # unsigned counters: a jump back past zero wraps, as the autopilot's own counter would
        if "time_boot_ms" in fields:
            m.time_boot_ms = _wrap(m, "time_boot_ms", int(m.time_boot_ms) + jump_us // 1000)
        if "time_usec" in fields:
            m.time_usec = _wrap(m, "time_usec", int(m.time_usec) + jump_us)
        packer.seq, packer.srcSystem = m.get_seq(), m.get_srcSystem()
        packer.srcComponent = m.get_srcComponent()
        try:
            out += m.pack(packer)
        except Exception as exc:  # noqa: BLE001 - a message we cannot re-encode goes as it came
            log.warning("fault relay: %s not re-stamped (%s)", m.get_type(), exc)
            out += original
    return bytes(out)


class LinkFaultRelay:
    """Relays the autopilot's UDP link to MAVSDK and injects link faults (module docstring)."""

    def __init__(self, url: str, *, clock: Callable[[], float] = time.monotonic,
                 seed: int = 0) -> None:
        self.listen = parse_udpin(url)
        self._clock = clock
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._loss_until = -math.inf
        self._delay_s, self._delay_until = 0.0, -math.inf
        self._duplicate_until = -math.inf
        self._reorder_until = -math.inf
        self._jump_us = 0
        self._queue: list[tuple[float, int, int, bytes]] = []  # (due, order, direction, data)
        self._order = 0
        self._last_due = [-math.inf, -math.inf]
        self._autopilot: tuple[str, int] | None = None
        self._sock_ap: socket.socket | None = None
        self._sock_client: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.client_port = 0
        self.counts = {"down": 0, "up": 0, "dropped": 0, "duplicated": 0, "reordered": 0,
                       "delayed": 0, "restamped": 0}

    @property
    def client_url(self) -> str:
        """Where MAVSDK listens instead (after :meth:`start`)."""
        return f"udpin://127.0.0.1:{self.client_port}"

    # -- lifetime ------------------------------------------------------------------------------
    def start(self) -> str:
        """Bind, start the relay thread; returns :attr:`client_url`."""
        if self._thread is not None:
            return self.client_url
        ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        ap.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            ap.bind(self.listen)
        except OSError as exc:
            ap.close()
            raise ConfigError(f"vehicle.params.url: the fault relay cannot bind "
                              f"{self.listen[0]}:{self.listen[1]}: {exc}") from exc
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:  # MAVSDK's free port
            probe.bind(("127.0.0.1", 0))
            self.client_port = int(probe.getsockname()[1])
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client.bind(("127.0.0.1", 0))
        self._sock_ap, self._sock_client = ap, client
        self._thread = threading.Thread(target=self._run, name="link-fault-relay", daemon=True)
        self._thread.start()
        log.info("fault relay: %s:%d <-> %s", *self.listen, self.client_url)
        return self.client_url

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the thread and close the sockets. Idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
        for s in (self._sock_ap, self._sock_client):
            if s is not None:
                s.close()
        self._thread = None

    # -- injection (any thread) ----------------------------------------------------------------
    def _require_started(self, origin: str) -> None:
        if self._thread is None:
            raise RuntimeError(f"{origin}: the fault relay is not running (connect first)")

    def inject_link_loss(self, duration_s: float) -> None:
        self._require_started("inject_link_loss")
        with self._lock:
            self._loss_until = self._clock() + _window_s(duration_s, "inject_link_loss")

    def inject_link_delay(self, delay_s: float, duration_s: float) -> None:
        self._require_started("inject_link_delay")
        if not (math.isfinite(delay_s) and 0 < delay_s <= 10):
            raise ValueError(f"inject_link_delay: delay_s must be in (0, 10], got {delay_s}")
        with self._lock:
            self._delay_s = float(delay_s)
            self._delay_until = self._clock() + _window_s(duration_s, "inject_link_delay")

    def inject_link_duplicate(self, duration_s: float) -> None:
        self._require_started("inject_link_duplicate")
        with self._lock:
            self._duplicate_until = self._clock() + _window_s(duration_s,
                                                              "inject_link_duplicate")

    def inject_link_reorder(self, duration_s: float) -> None:
        self._require_started("inject_link_reorder")
        with self._lock:
            self._reorder_until = self._clock() + _window_s(duration_s, "inject_link_reorder")

    def inject_autopilot_clock_jump(self, jump_s: float) -> None:
        self._require_started("inject_autopilot_clock_jump")
        if not (math.isfinite(jump_s) and jump_s != 0):
            raise ValueError(f"inject_autopilot_clock_jump: jump_s must be finite and != 0, "
                             f"got {jump_s}")
        with self._lock:
            self._jump_us += int(round(jump_s * 1e6))

    # -- the relay thread ----------------------------------------------------------------------
    def _run(self) -> None:
        from eaglemission.lab.vehicles.emulator.dialect import mavlink

        parser, packer = mavlink.MAVLink(None), mavlink.MAVLink(None)
        parser.robust_parsing = True
        assert self._sock_ap is not None and self._sock_client is not None
        sel = selectors.DefaultSelector()
        sel.register(self._sock_ap, selectors.EVENT_READ, DOWN)
        sel.register(self._sock_client, selectors.EVENT_READ, UP)
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(timeout=self._wait_s()):
                    sock: socket.socket = key.fileobj  # type: ignore[assignment]
                    try:
                        data, addr = sock.recvfrom(65535)
                    except OSError:
                        continue
                    if key.data == DOWN:
                        self._autopilot = addr
                        if first_msgid(data) in TRUTH_MSGIDS:  # the world, not the link
                            self._send(DOWN, data)
                            continue
                        with self._lock:
                            jump = self._jump_us
                        if jump:
                            try:
                                data = shift_stamps(data, jump, parser, packer)
                                self.counts["restamped"] += 1
                            except Exception:  # a relay that dies cuts the link for good
                                log.exception("fault relay: datagram passed on un-stamped")
                    self._accept(key.data, data)
                self._release()
        except OSError as exc:  # sockets closed under us: the relay ends
            if not self._stop.is_set():
                log.warning("fault relay stopped: %s", exc)
        finally:
            sel.close()

    def _wait_s(self) -> float:
        due = self._queue[0][0] - self._clock() if self._queue else 0.05
        return max(0.0, min(0.05, due))

    def _accept(self, direction: int, data: bytes) -> None:
        """One datagram in: dropped, or queued (delayed, duplicated, sent late)."""
        now = self._clock()
        with self._lock:
            lost = now < self._loss_until
            delay = self._delay_s if now < self._delay_until else 0.0
            dup = now < self._duplicate_until
            reorder = now < self._reorder_until
        if lost:
            self.counts["dropped"] += 1
            return
        self.counts["duplicated"] += dup
        self.counts["delayed"] += delay > 0
        for _ in range(2 if dup else 1):
            if reorder and self._rng.random() < 0.5:
                self.counts["reordered"] += 1
                self._push(direction, data, now + delay + REORDER_LATE_S)
            else:
                self._enqueue(direction, data, now + delay)

    def _enqueue(self, direction: int, data: bytes, due: float) -> None:
        due = max(due, self._last_due[direction])  # a queue: never overtakes an earlier one
        self._last_due[direction] = due
        self._push(direction, data, due)

    def _push(self, direction: int, data: bytes, due: float) -> None:
        self._order += 1
        heapq.heappush(self._queue, (due, self._order, direction, data))

    def _release(self) -> None:
        now = self._clock()
        while self._queue and self._queue[0][0] <= now:
            _, _, direction, data = heapq.heappop(self._queue)
            self._send(direction, data)

    def _send(self, direction: int, data: bytes) -> None:
        assert self._sock_ap is not None and self._sock_client is not None
        try:
            if direction == DOWN:
                self._sock_client.sendto(data, ("127.0.0.1", self.client_port))
                self.counts["down"] += 1
            elif self._autopilot is not None:
                self._sock_ap.sendto(data, self._autopilot)
                self.counts["up"] += 1
        except OSError as exc:  # nobody listening yet (ICMP refused): keep going
            log.debug("fault relay send failed: %s", exc)
