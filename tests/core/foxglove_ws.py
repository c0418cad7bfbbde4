"""A minimal client of the Foxglove WebSocket protocol (RFC 6455 framing over a plain socket;
https://github.com/foxglove/foxglove-sdk, ws-protocol ``spec.md``): enough to read what
``run --live`` serves, as Foxglove does: ``serverInfo``, ``advertise`` (channels with their
schemas), ``subscribe``, and binary ``messageData`` frames. For the tests and
``benchmarks/bench_live.py``; foxglove-sdk ships no client."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Any

SUBPROTOCOL = "foxglove.sdk.v1"
_GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
OP_MESSAGE_DATA = 0x01


class Closed(Exception):
    """The server closed the connection (or it broke)."""


@dataclass
class Received:
    """What a client read: channels advertised (id -> advertise entry), messages per topic
    ``(log_time_ns, payload)``, bytes on the wire (frames and headers included)."""

    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    wire_bytes: int = 0
    status: list[str] = field(default_factory=list)
    """The server's ``status`` messages (warnings, errors)."""
    first_message_s: float | None = None
    last_message_s: float | None = None


class FoxgloveClient:
    """Connect, then :meth:`read_all` (subscribes to every channel as it is advertised)."""

    def __init__(self, host: str, port: int, *, timeout_s: float = 10.0,
                 rcvbuf_bytes: int | None = None) -> None:
        deadline = time.monotonic() + timeout_s
        while True:  # the server starts with the flight: retry until it listens
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            if rcvbuf_bytes is not None:  # a slow radio link: a small TCP window
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
            self.sock.settimeout(1.0)
            try:
                self.sock.connect((host, port))
                break
            except OSError:
                self.sock.close()
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.01)
        self.sock.settimeout(timeout_s)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                           f"Sec-WebSocket-Version: 13\r\n"
                           f"Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise Closed("closed during the handshake")
            head += chunk
        head, self._buf = head.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        if " 101 " not in lines[0] + " ":
            raise Closed(f"handshake refused: {lines[0]}")
        accept = base64.b64encode(hashlib.sha1(key.encode() + _GUID).digest()).decode()
        hdrs = {k.strip().lower(): v.strip() for k, v in
                (ln.split(":", 1) for ln in lines[1:] if ":" in ln)}
        if hdrs.get("sec-websocket-accept") != accept:
            raise Closed("bad Sec-WebSocket-Accept")
        self.subprotocol = hdrs.get("sec-websocket-protocol", "")
        self.received = Received(wire_bytes=len(head) + 4)
        self._next_sub = 1
        self._subs: dict[int, str] = {}  # subscription id -> topic

    # -- framing ------------------------------------------------------------------------------
    def _read(self, n: int) -> bytes:
        while len(self._buf) < n:
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise Closed("connection closed")
            self._buf += chunk
        out, self._buf = self._buf[:n], self._buf[n:]
        self.received.wire_bytes += n
        return out

    def _frame(self) -> tuple[int, bytes]:
        b0, b1 = self._read(2)
        n = b1 & 0x7F
        if n == 126:
            n = struct.unpack(">H", self._read(2))[0]
        elif n == 127:
            n = struct.unpack(">Q", self._read(8))[0]
        mask = self._read(4) if b1 & 0x80 else b""
        data = self._read(n)
        if mask:
            data = bytes(c ^ mask[i % 4] for i, c in enumerate(data))
        return b0, data

    def recv(self) -> tuple[int, bytes]:
        """The next data message ``(opcode, payload)`` (1 text, 2 binary); answers pings."""
        parts: list[bytes] = []
        opcode = 0
        while True:
            b0, data = self._frame()
            op = b0 & 0x0F
            if op == 0x8:
                raise Closed("close frame")
            if op == 0x9:
                self._send(0xA, data)
                continue
            if op == 0xA:
                continue
            opcode = opcode or op
            parts.append(data)
            if b0 & 0x80:
                return opcode, b"".join(parts)

    def _send(self, opcode: int, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 1 << 16:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        self.sock.sendall(head + mask + bytes(c ^ mask[i % 4] for i, c in enumerate(payload)))

    def send_json(self, obj: dict[str, Any]) -> None:
        self._send(0x1, json.dumps(obj).encode())

    # -- the protocol -------------------------------------------------------------------------
    def handle(self, opcode: int, data: bytes, *, subscribe: bool = True) -> None:
        r = self.received
        if opcode == 0x1:
            msg = json.loads(data)
            if msg.get("op") == "serverInfo":
                r.server_info = msg
            elif msg.get("op") == "status":
                r.status.append(str(msg.get("message", "")))
            elif msg.get("op") == "advertise":
                subs = []
                for ch in msg["channels"]:
                    r.channels[int(ch["id"])] = ch
                    sid = self._next_sub
                    self._next_sub += 1
                    self._subs[sid] = ch["topic"]
                    subs.append({"id": sid, "channelId": int(ch["id"])})
                if subscribe and subs:
                    self.send_json({"op": "subscribe", "subscriptions": subs})
        elif opcode == 0x2 and data and data[0] == OP_MESSAGE_DATA:
            sid, log_ns = struct.unpack_from("<IQ", data, 1)
            topic = self._subs.get(sid, f"?{sid}")
            r.messages.setdefault(topic, []).append((log_ns, data[13:]))
            now = time.monotonic()
            r.first_message_s = r.first_message_s or now
            r.last_message_s = now

    def read_all(self, *, until_closed_s: float = 120.0) -> Received:
        """Read (subscribing to every advertised channel) until the server closes or
        ``until_closed_s`` passes."""
        deadline = time.monotonic() + until_closed_s
        try:
            while time.monotonic() < deadline:
                try:
                    op, data = self.recv()
                except TimeoutError:
                    continue
                self.handle(op, data)
        except (Closed, OSError):
            pass
        finally:
            self.close()
        return self.received

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass


def decode_schema(channel: dict[str, Any]) -> bytes:
    """The schema bytes of an advertised channel (protobuf: base64 of a FileDescriptorSet)."""
    s = channel.get("schema", "")
    return base64.b64decode(s) if channel.get("schemaEncoding") == "protobuf" else s.encode()
