"""Live view of a flight in Foxglove (``eaglemission run --live [HOST:PORT]``; docs/recording.md,
"Live view in Foxglove").

:class:`LiveSink` is a :class:`~eaglemission.interfaces.FlightRecorder`: it gets what the MCAP
recorder gets (every mission-log record with its JSON line, every processed frame, both
calibrations), through the same hooks (:class:`Tee` hands them to both), and publishes them on
the recording's topics and schemas (:mod:`eaglemission.recording.mcap_writer`) over the Foxglove
WebSocket protocol (``foxglove-sdk``, ``pip install eaglemission[live]``), throttled for a
radio link:

* ``/camera/<id>/image``: a thumbnail (``image_width_px`` wide, JPEG at ``jpeg_quality``) of at
  most ``image_hz`` processed frames per camera and second of mission time, with its
  ``/camera/<id>/frame`` companion; ``/camera/<id>/calibration`` scaled to the thumbnail size,
  ``/camera/<id>/model`` (the full camera model) as recorded;
* ``/log/<kind>``: every mission-log record, the kinds in ``THROTTLED`` (telemetry, setpoints)
  at most ``telemetry_hz`` per second of mission time.

Nothing here blocks the mission: the mission's side only compares time stamps and puts onto a
bounded queue (a full queue drops, counted); thumbnails are encoded and published on the
sink's own thread; the server (the SDK's own threads) drops a slow client's oldest messages
(``backlog_messages``) and never waits for a client. The server is started before take-off
(:func:`start`): a port in use refuses the flight (exit 5).
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from eaglemission.geometry import CameraModel
from eaglemission.names import CAMERA_NARROW, CAMERA_WIDE
from eaglemission.recording import foxglove as fox
from eaglemission.recording import mcap_writer as mr
from eaglemission.recording.folder import model_to_json
from eaglemission.types import Frame

log = logging.getLogger(__name__)
OBJECT_SCHEMA = mr._OBJECT_SCHEMA  # the recording's schema of its JSON companions

DEFAULT_LISTEN = "127.0.0.1:8765"
THROTTLED = frozenset({"telemetry", "setpoint"})
"""Log kinds sent at most ``telemetry_hz`` (the others are rare: every one is sent)."""
CHECK_NAME = "live: Foxglove WebSocket"
LOG_KINDS = ("start", "config", "autopilot_params", "failsafe_params", "param_set", "state",
             "telemetry", "setpoint", "detection", "estimate", "filter", "command",
             "event", "end", "evaluation")
"""The mission log's kinds (missions/log.py): their channels are advertised at the start; a
kind not listed gets its channel with its first record."""


class LiveError(RuntimeError):
    """The live server cannot start (port in use, bad address, foxglove-sdk missing)."""


def parse_listen(text: str, *, where: str = "--live") -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT``, ``:PORT`` (localhost) or ``HOST`` (port 8765);
    raises ValueError naming ``where``."""
    s = str(text).strip()
    host, port_s = "127.0.0.1", "8765"
    if s.startswith("["):
        h, sep, rest = s[1:].partition("]")
        if not sep or (rest and not rest.startswith(":")):
            raise ValueError(f"{where}: expected [IPv6]:PORT, got {text!r}")
        host, port_s = h, rest[1:] or port_s
    elif s.count(":") == 1:
        h, port_s = s.split(":")
        host = h or host
    elif s and ":" not in s:
        host = s
    else:
        raise ValueError(f"{where}: expected HOST:PORT (e.g. {DEFAULT_LISTEN}), got {text!r}")
    if not port_s.isdigit() or not 0 <= int(port_s) <= 65535:
        raise ValueError(f"{where}: port must be 0..65535, got {port_s!r} in {text!r}")
    if not host:
        raise ValueError(f"{where}: empty host in {text!r}")
    return host, int(port_s)


@dataclass(frozen=True)
class LiveOptions:
    """How a flight is served live (``run --live``, the mission file's ``live`` section)."""

    host: str = "127.0.0.1"
    """Bound to localhost unless told otherwise (``0.0.0.0``: every interface)."""
    port: int = 8765
    image_hz: float = 2.0
    """Thumbnails per camera and second of mission time, at most."""
    image_width_px: int = 320
    jpeg_quality: int = 60
    telemetry_hz: float = 10.0
    """``telemetry`` and ``setpoint`` records per second of mission time, at most."""
    queue_items: int = 64
    """Items waiting for the sink's thread; beyond them an item is dropped (counted)."""
    backlog_messages: int = 256
    """Messages the server buffers per client; a slow client loses its oldest ones."""
    repeat_s: float = 5.0
    """Both calibrations and camera models are sent again this often (host time), so a
    ground station that connects mid-flight gets them."""

    def __post_init__(self) -> None:
        for name in ("image_hz", "telemetry_hz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"live.{name}: must be > 0, got {getattr(self, name)}")
        if not 16 <= self.image_width_px <= 8192:
            raise ValueError(f"live.image_width_px: 16..8192, got {self.image_width_px}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"live.jpeg_quality: 1..100, got {self.jpeg_quality}")

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"


def options_from_config(section: Any, listen: str | None = None) -> LiveOptions:
    """The options of a ``live`` config section (None: the defaults), ``listen`` (``--live
    HOST:PORT``) over its own."""
    where = "--live" if listen is not None else "live.listen"
    text = listen if listen is not None else (DEFAULT_LISTEN if section is None
                                              else section.listen)
    host, port = parse_listen(text, where=where)
    if section is None:
        return LiveOptions(host, port)
    return LiveOptions(host, port, image_hz=section.image_hz,
                       image_width_px=section.image_width_px,
                       jpeg_quality=section.jpeg_quality, telemetry_hz=section.telemetry_hz)


def thumbnail_calibration(model: CameraModel, camera_id: str, t_ns: int, width_px: int) -> Any:
    """``foxglove.CameraCalibration`` of ``model`` scaled to an image ``width_px`` wide."""
    msg = fox.calibration_message(model, camera_id, t_ns)
    s = min(1.0, width_px / float(model.width_px))
    if s < 1.0:
        msg.width, msg.height = thumb_size(model.width_px, model.height_px, width_px)
        k = list(msg.K)
        msg.K[:] = [k[0] * s, k[1] * s, (k[2] + 0.5) * s - 0.5,
                    0.0, k[4] * s, (k[5] + 0.5) * s - 0.5, 0.0, 0.0, 1.0]
        msg.P[:] = [msg.K[0], msg.K[1], msg.K[2], 0.0, 0.0, msg.K[4], msg.K[5], 0.0,
                    0.0, 0.0, 1.0, 0.0]
    return msg


def thumb_size(width_px: int, height_px: int, max_width_px: int) -> tuple[int, int]:
    """The thumbnail's (width, height): at most ``max_width_px`` wide, aspect kept."""
    if width_px <= max_width_px:
        return int(width_px), int(height_px)
    return int(max_width_px), max(1, round(height_px * max_width_px / width_px))


def _latched_cameras(items: queue.Queue[tuple[Any, ...] | None]) -> Any:
    """A server listener: a client subscribing to a calibration or camera-model channel gets
    the last one at once (else it waits for ``repeat_s``, and a short flight may end first)."""
    from foxglove.websocket import ChannelView, Client, ServerListener

    class LatchedCameras(ServerListener):
        def on_subscribe(self, client: Client, channel: ChannelView) -> None:
            topic = str(channel.topic)
            if topic.endswith(("/calibration", "/model")):
                try:
                    items.put_nowait(("subscribed", topic))
                except queue.Full:
                    pass  # the periodic repeat still sends it

    return LatchedCameras()


class LiveSink:
    """Serve one flight over the Foxglove WebSocket protocol (see the module docstring).

    Raises :class:`LiveError` when the server cannot start (port in use, no foxglove-sdk).
    """

    def __init__(self, options: LiveOptions, *, name: str = "eaglemission") -> None:
        try:
            import foxglove
        except ImportError as exc:
            raise LiveError("--live needs foxglove-sdk: pip install eaglemission[live]"
                            ) from exc
        self.options = options
        self._fg = foxglove
        self._context = foxglove.Context()
        self._queue: queue.Queue[tuple[Any, ...] | None] = queue.Queue(
            maxsize=max(1, options.queue_items))
        try:
            self._server = foxglove.start_server(
                name=name, host=options.host, port=options.port, context=self._context,
                message_backlog_size=options.backlog_messages,
                server_listener=_latched_cameras(self._queue))
        except Exception as exc:  # the SDK raises RuntimeError (FoxgloveError)
            hint = ("another program or flight uses that port: choose another with --live "
                    "HOST:PORT" if "in use" in str(exc) else f"is {options.host} an address "
                    "of this machine? 127.0.0.1: localhost only, 0.0.0.0: every interface")
            raise LiveError(f"cannot serve {options.url}: {exc} ({hint})") from None
        self.port = int(self._server.port)
        self.stats: dict[str, Any] = {
            "url": LiveOptions(options.host, self.port).url, "messages": 0, "bytes": 0,
            "images": 0, "records": 0, "throttled": 0, "dropped": 0, "errors": 0, "error": ""}
        self._channels: dict[str, Any] = {}
        self._last_ns: dict[str, int] = {}
        self._image_period_ns = int(1e9 / options.image_hz)
        self._record_period_ns = int(1e9 / options.telemetry_hz)
        self._lock = threading.Lock()
        self._log_write: Callable[..., Any] | None = None
        self._drop_reported = False
        self._cameras: dict[str, tuple[CameraModel, int]] = {}
        self._repeat_at = time.monotonic() + options.repeat_s
        self._closed = False
        self._advertise((CAMERA_WIDE, CAMERA_NARROW))
        self._thread = threading.Thread(target=self._run, name="live-sink", daemon=True)
        self._thread.start()

    # -- the mission's side (any thread; never blocks, never raises) ---------------------------
    def bind(self, write: Callable[..., Any]) -> None:
        self._log_write = write

    def record(self, record: Mapping[str, Any], line: str) -> None:
        kind = str(record.get("kind", "unknown"))
        t_ns = int(record.get("t_ns", 0))
        if kind in THROTTLED and not self._due("log:" + kind, t_ns, self._record_period_ns):
            return
        self._put(("record", kind, t_ns, line))

    def frame(self, frame: Frame) -> None:
        if self._due("img:" + frame.camera_id, int(frame.timestamp_ns), self._image_period_ns):
            self._put(("frame", frame, time.time_ns()))

    def saliency(self, frame: Frame, thumb: Any) -> None:
        """Not served live: the thumbnails of the frames are (the recording has the maps)."""

    def calibration(self, camera_id: str, model: CameraModel, t_ns: int) -> None:
        self._put(("calibration", camera_id, model, int(t_ns)))

    def close(self, timeout_s: float = 5.0) -> dict[str, Any]:
        """Publish what is queued and stop the server (each at most ``timeout_s``: a stalled
        client is not waited for); the counts."""
        if not self._closed:
            self._closed = True
            try:
                self._queue.put(None, timeout=timeout_s)
            except queue.Full:
                log.warning("live: queue still full after %.1f s", timeout_s)
            self._thread.join(timeout=timeout_s)
            for ch in self._channels.values():
                ch.close()
            # stop() waits for every client to take what is queued for it (foxglove-sdk
            # 0.30.3): a stalled client must not hold up the end of a flight
            stopper = threading.Thread(target=self._server.stop, name="live-stop", daemon=True)
            stopper.start()
            stopper.join(timeout=timeout_s)
            if stopper.is_alive():
                log.warning("live: a client is not reading; leaving the server to stop alone")
                with self._lock:
                    self.stats["error"] = self.stats["error"] or "a stalled client: the server "\
                        "stopped without waiting for it"
        with self._lock:
            return dict(self.stats)

    def _due(self, key: str, t_ns: int, period_ns: int) -> bool:
        last = self._last_ns.get(key)
        if last is not None and 0 <= t_ns - last < period_ns:
            with self._lock:
                self.stats["throttled"] += 1
            return False
        self._last_ns[key] = t_ns
        return True

    def _put(self, item: tuple[Any, ...]) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            with self._lock:
                self.stats["dropped"] += 1
            if not self._drop_reported and self._log_write is not None:
                self._drop_reported = True  # once: the end counts have the total
                try:
                    self._log_write("event", source="live", text="live view behind: dropping "
                                    "messages (the flight goes on)")
                except Exception:  # noqa: BLE001 - the live view must not stop a mission
                    log.exception("live: cannot report to the mission log")

    # -- the sink's thread --------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            try:
                item = self._queue.get(timeout=self.options.repeat_s)
            except queue.Empty:
                item = ("repeat",)
            if item is None:
                return
            try:
                if time.monotonic() >= self._repeat_at and self._cameras:
                    self._repeat_at = time.monotonic() + self.options.repeat_s
                    for cid, (model, t_ns) in list(self._cameras.items()):
                        self._publish_calibration(cid, model, t_ns)
                self._handle(item)
            except Exception as exc:  # noqa: BLE001 - count, never stop the flight
                with self._lock:
                    self.stats["errors"] += 1
                    self.stats["error"] = self.stats["error"] or f"{type(exc).__name__}: {exc}"
                log.warning("live: %s: %s", item[0], exc)

    def _handle(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "record":
            _, rkind, t_ns, line = item
            self._log(mr.TOPIC_LOG.format(rkind), mr.LOG_SCHEMA.format(rkind), "jsonschema",
                      mr.log_json_schema(rkind), "json", line.encode("utf-8"), t_ns)
            self._count("records")
        elif kind == "frame":
            self._publish_frame(item[1], item[2])
        elif kind == "calibration":
            _, cid, model, t_ns = item
            self._cameras[cid] = (model, t_ns)
            self._publish_calibration(cid, model, t_ns)
        elif kind == "subscribed":  # latched: a new subscriber gets the camera's models now
            for cid, (model, t_ns) in list(self._cameras.items()):
                if item[1] in (mr.TOPIC_CALIBRATION.format(cid), mr.TOPIC_MODEL.format(cid)):
                    self._publish_calibration(cid, model, t_ns)

    def _publish_calibration(self, cid: str, model: CameraModel, t_ns: int) -> None:
        cal = thumbnail_calibration(model, cid, t_ns, self.options.image_width_px)
        self._log(mr.TOPIC_CALIBRATION.format(cid), "foxglove.CameraCalibration",
                  "protobuf", fox.file_descriptor_set(CameraCalibration), "protobuf",
                  cal.SerializeToString(), t_ns)
        self._log(mr.TOPIC_MODEL.format(cid), "eaglemission.CameraModel", "jsonschema",
                  OBJECT_SCHEMA, "json", json.dumps(model_to_json(model)).encode(), t_ns)

    def _publish_frame(self, frame: Frame, host_ns: int) -> None:
        h, w = frame.image.shape[:2]
        tw, th = thumb_size(w, h, self.options.image_width_px)
        img = frame.image if tw == w else cv2.resize(frame.image, (tw, th),
                                                     interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY,
                                             self.options.jpeg_quality])
        if not ok:
            raise OSError(f"cannot encode a thumbnail of {frame.camera_id} seq {frame.seq}")
        data = buf.tobytes()
        cid, t_ns = frame.camera_id, int(frame.timestamp_ns)
        msg = CompressedImage(frame_id=cid, data=data, format="jpeg")
        msg.timestamp.FromNanoseconds(t_ns)
        self._log(mr.TOPIC_IMAGE.format(cid), "foxglove.CompressedImage", "protobuf",
                  fox.file_descriptor_set(CompressedImage), "protobuf",
                  msg.SerializeToString(), t_ns)
        meta = {"camera_id": cid, "seq": int(frame.seq), "timestamp_ns": t_ns,
                "host_time_ns": int(host_ns), "exposure_s": float(frame.exposure_s),
                "width_px": int(w), "height_px": int(h), "thumbnail_width_px": tw,
                "thumbnail_height_px": th, "jpeg_quality": self.options.jpeg_quality,
                "jpeg_bytes": len(data)}
        self._log(mr.TOPIC_FRAME.format(cid), "eaglemission.FrameInfo", "jsonschema",
                  OBJECT_SCHEMA, "json", json.dumps(meta).encode(), t_ns)
        self._count("images")

    def _advertise(self, cameras: tuple[str, ...]) -> None:
        """Every channel a flight uses, before any client connects: a channel created while
        a client subscribes may be refused to it ("unknown channel"; foxglove-sdk 0.30.3)."""
        for cid in cameras:
            self._channel(mr.TOPIC_IMAGE.format(cid), "foxglove.CompressedImage", "protobuf",
                          fox.file_descriptor_set(CompressedImage), "protobuf")
            self._channel(mr.TOPIC_FRAME.format(cid), "eaglemission.FrameInfo", "jsonschema",
                          OBJECT_SCHEMA, "json")
            self._channel(mr.TOPIC_CALIBRATION.format(cid), "foxglove.CameraCalibration",
                          "protobuf", fox.file_descriptor_set(CameraCalibration), "protobuf")
            self._channel(mr.TOPIC_MODEL.format(cid), "eaglemission.CameraModel", "jsonschema",
                          OBJECT_SCHEMA, "json")
        for kind in LOG_KINDS:
            self._channel(mr.TOPIC_LOG.format(kind), mr.LOG_SCHEMA.format(kind), "jsonschema",
                          mr.log_json_schema(kind), "json")

    def _channel(self, topic: str, schema_name: str, schema_encoding: str, schema: bytes,
                 message_encoding: str) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            fg = self._fg
            ch = self._channels[topic] = fg.Channel(
                topic, schema=fg.Schema(name=schema_name, encoding=schema_encoding, data=schema),
                message_encoding=message_encoding, context=self._context)
        return ch

    def _log(self, topic: str, schema_name: str, schema_encoding: str, schema: bytes,
             message_encoding: str, data: bytes, t_ns: int) -> None:
        ch = self._channel(topic, schema_name, schema_encoding, schema, message_encoding)
        ch.log(data, log_time=int(t_ns))
        with self._lock:
            self.stats["messages"] += 1
            self.stats["bytes"] += len(data)

    def _count(self, key: str) -> None:
        with self._lock:
            self.stats[key] += 1


class Tee:
    """One :class:`~eaglemission.interfaces.FlightRecorder` handing everything to several
    (the MCAP recorder and the live view get the same records and frames)."""

    def __init__(self, *sinks: Any) -> None:
        self.sinks = tuple(s for s in sinks if s is not None)

    def bind(self, write: Callable[..., Any]) -> None:
        for s in self.sinks:
            s.bind(write)

    def record(self, record: Mapping[str, Any], line: str) -> None:
        for s in self.sinks:
            s.record(record, line)

    def frame(self, frame: Any) -> None:
        for s in self.sinks:
            s.frame(frame)

    def saliency(self, frame: Any, thumb: Any) -> None:
        for s in self.sinks:
            s.saliency(frame, thumb)


def start(options: LiveOptions | None, say: Callable[[str], None] | None = None
          ) -> tuple[LiveSink | None, tuple[str, bool, str] | None]:
    """Before take-off: the running sink and its check line ``(name, passed, detail)``
    (``(None, None)`` without ``options``; a failed check when the server cannot start)."""
    if options is None:
        return None, None
    try:
        sink = LiveSink(options)
        check = (CHECK_NAME, True, f"serving {sink.stats['url']} (Foxglove: Open connection, "
                                   "Foxglove WebSocket)")
    except LiveError as exc:
        sink, check = None, (CHECK_NAME, False, str(exc))
    if say is not None:
        say(f"  [{'ok' if check[1] else 'FAIL'}] {check[0]}: {check[2]}")
    return sink, check


def attach(sink: LiveSink | None, hooks: Any, models: Mapping[str, CameraModel], t_ns: int
           ) -> Any:
    """The mission hooks with ``sink`` beside the hooks' recorder (both get everything)."""
    if sink is None:
        return hooks
    import dataclasses

    for cid, model in models.items():
        sink.calibration(cid, model, t_ns)
    return dataclasses.replace(hooks, recorder=sink if hooks.recorder is None
                               else Tee(hooks.recorder, sink))


def stop(sink: LiveSink | None) -> dict[str, Any] | None:
    """Close ``sink`` (None: nothing); its counts."""
    return None if sink is None else sink.close()
