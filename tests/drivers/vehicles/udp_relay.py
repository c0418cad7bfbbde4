"""A loopback UDP relay between PX4 SITL's offboard link and the driver, that a test can cut.

PX4 SITL (instance 0) sends its offboard/API link from UDP 14580 to ``127.0.0.1:14540``. The
relay binds ``14540`` in place of the driver, forwards what PX4 sends to the driver's port
(``udpin://0.0.0.0:<driver_port>``) and what the driver answers back to where PX4's packets
came from. :meth:`UdpRelay.cut` drops everything, both ways, for a while: the radio link of a
real aircraft going out of range, not a process stopping.
"""

from __future__ import annotations

import select
import socket
import threading
import time


class UdpRelay:
    """``px4_port`` (where PX4 sends) <-> ``127.0.0.1:driver_port`` (the driver's udpin)."""

    def __init__(self, px4_port: int = 14540, driver_port: int = 14541) -> None:
        self.driver_addr = ("127.0.0.1", int(driver_port))
        self._px4_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._px4_side.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._px4_side.bind(("0.0.0.0", int(px4_port)))
        self._driver_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._driver_side.bind(("127.0.0.1", 0))
        self._px4_addr: tuple[str, int] | None = None
        self._cut_until = 0.0
        self._stop = threading.Event()
        self.dropped = 0
        self.forwarded = 0
        self._thread = threading.Thread(target=self._run, name="udp-relay", daemon=True)
        self._thread.start()

    def cut(self, duration_s: float) -> None:
        """Drop every packet, both directions, for ``duration_s`` from now."""
        self._cut_until = time.monotonic() + float(duration_s)

    @property
    def is_cut(self) -> bool:
        return time.monotonic() < self._cut_until

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        self._thread.join(timeout_s)
        self._px4_side.close()
        self._driver_side.close()

    def _run(self) -> None:
        socks = [self._px4_side, self._driver_side]
        while not self._stop.is_set():
            ready, _, _ = select.select(socks, [], [], 0.1)
            for sock in ready:
                try:
                    data, addr = sock.recvfrom(65535)
                except OSError:
                    continue
                if sock is self._px4_side:
                    self._px4_addr = addr
                    dest: tuple[str, int] | None = self.driver_addr
                    out = self._driver_side
                else:
                    dest, out = self._px4_addr, self._px4_side
                if dest is None or self.is_cut:
                    self.dropped += 1
                    continue
                try:
                    out.sendto(data, dest)
                    self.forwarded += 1
                except OSError:  # the driver not listening yet: like a radio, drop
                    self.dropped += 1
