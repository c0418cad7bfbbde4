"""The MAVLink emulator's link: a UDP socket or in-process bytes (MAVSDK's ``raw://``), with
the faults a test injects (loss in one or both directions, a delay)."""

from __future__ import annotations

import heapq
import logging
import queue
import socket
import threading
import time
from collections.abc import Callable, Iterator

from eaglemission.errors import ConfigError

log = logging.getLogger(__name__)


def parse_link(url: str) -> tuple[str, str, int]:
    """``udpin://host:port`` / ``udpout://host:port`` (also pymavlink's ``udpin:host:port``)."""
    for scheme in ("udpin", "udpout"):
        for sep in ("://", ":"):
            prefix = scheme + sep
            if url.startswith(prefix):
                host, _, port = url[len(prefix):].rpartition(":")
                if not host or not port.isdigit():
                    break
                return scheme, host, int(port)
    raise ConfigError(f"emulator link {url!r}: use udpin://HOST:PORT or udpout://HOST:PORT "
                      "(or no link and feed()/set_output() for MAVSDK's raw://)")


class UdpLink:
    """One UDP socket: ``udpin`` binds and answers the last sender, ``udpout`` sends first."""

    def __init__(self, url: str) -> None:
        scheme, host, port = parse_link(url)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(0.1)
        self.peer: tuple[str, int] | None
        if scheme == "udpin":
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((host, port))
            self.peer = None
        else:
            self.sock.bind(("0.0.0.0", 0))
            self.peer = (host, port)
        self.fixed_peer = scheme == "udpout"

    def send(self, data: bytes) -> None:
        if self.peer is not None:
            try:
                self.sock.sendto(data, self.peer)
            except OSError as exc:  # nobody listening yet (ICMP refused): keep going
                log.debug("udp send failed: %s", exc)

    def recv(self) -> bytes | None:
        try:
            data, addr = self.sock.recvfrom(65535)
        except OSError:  # includes the socket timeout
            return None
        if not self.fixed_peer:
            self.peer = addr
        return data

    def close(self) -> None:
        self.sock.close()


class Transport:
    """Bytes in (:meth:`feed`, any thread) and out (:meth:`send`), with injected faults.

    ``feed`` runs on the client's thread (MAVSDK's, for ``raw://``): it never waits for the
    emulator's lock, which the emulator thread holds while handing bytes to MAVSDK.
    """

    def __init__(self) -> None:
        self._out_lock = threading.Lock()
        self._in_lock = threading.Lock()
        self._output: Callable[[bytes], None] | None = None
        self._inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        self.link_down_until = 0.0  # both directions (wall time)
        self._uplink_down_until = 0.0  # client -> vehicle only (a client that died)
        self._delay_s = 0.0
        self._delayed_out: list[tuple[float, int, bytes]] = []
        self._delayed_in: list[tuple[float, int, bytes]] = []
        self._seq_in = 0
        self._seq_out = 0

    def set_output(self, fn: Callable[[bytes], None] | None) -> None:
        """Where outgoing bytes go. Once this returns with None, nothing is sent."""
        with self._out_lock:
            self._output = fn

    def feed(self, data: bytes) -> None:
        now = time.monotonic()
        if now < self.link_down_until or now < self._uplink_down_until:
            return
        if self._delay_s > 0:
            with self._in_lock:
                self._seq_in += 1
                heapq.heappush(self._delayed_in, (now + self._delay_s, self._seq_in, data))
            return
        self._inbox.put(data)

    def inject_loss(self, duration_s: float, direction: str) -> None:
        until = time.monotonic() + float(duration_s)
        if direction == "both":
            self.link_down_until = until
        elif direction == "uplink":
            self._uplink_down_until = until
        else:
            raise ValueError(f"direction: 'both' or 'uplink', got {direction!r}")

    def set_delay(self, delay_s: float) -> None:
        self._delay_s = max(0.0, float(delay_s))

    def send(self, data: bytes, now: float) -> None:
        if now < self.link_down_until:
            return
        with self._out_lock:
            if self._delay_s > 0:
                self._seq_out += 1
                heapq.heappush(self._delayed_out, (now + self._delay_s, self._seq_out, data))
            elif self._output is not None:
                self._output(data)

    def get(self, timeout_s: float) -> bytes | None:
        """The next inbound packet, waiting at most ``timeout_s`` (0: do not wait)."""
        try:
            return self._inbox.get(timeout=timeout_s) if timeout_s > 0 else self._inbox.get_nowait()
        except queue.Empty:
            return None

    def inbound(self, wall: float) -> Iterator[bytes]:
        """Packets that arrived, then delayed ones that are due."""
        while not self._inbox.empty():
            yield self._inbox.get_nowait()
        while True:
            with self._in_lock:
                if not (self._delayed_in and self._delayed_in[0][0] <= wall):
                    return
                data = heapq.heappop(self._delayed_in)[2]
            yield data

    def flush(self, wall: float) -> None:
        """Send the delayed outbound packets that are due."""
        with self._out_lock:
            while self._delayed_out and self._delayed_out[0][0] <= wall:
                data = heapq.heappop(self._delayed_out)[2]
                if self._output is not None and wall >= self.link_down_until:
                    self._output(data)
