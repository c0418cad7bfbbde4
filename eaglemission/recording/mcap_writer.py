"""MCAP flight recordings (``eaglemission run --record FILE.mcap``; docs/recording.md).

:class:`McapRecorder` is the :class:`~eaglemission.interfaces.FlightRecorder` the assembly
opens for a flight (:func:`open_recorder`). It writes, on its own thread:

* ``/camera/<id>/image``: every frame the mission processed, ``foxglove.CompressedImage``
  (protobuf, JPEG at ``jpeg_quality``, or PNG: ``lossless``), encoded here, off the event loop;
* ``/camera/<id>/frame``: its companion (JSON): camera id, seq, ``timestamp_ns`` (mid-exposure
  on the mission clock), ``host_time_ns`` (host UTC when the mission processed it), exposure;
* ``/camera/<id>/calibration``: ``foxglove.CameraCalibration`` (protobuf) and
  ``/camera/<id>/model`` (JSON: the full camera model, mount included), once at the start;
* ``/log/<kind>``: every mission-log record, the very JSON line the ``--log`` file gets, on a
  topic per ``kind`` with a JSON schema;
* ``/vehicle/*`` (JSON): what the mission got from the vehicle (:mod:`eaglemission.recording.vehicle_tap`,
  what ``eaglemission replay`` answers from);
* ``/recorder/stats`` (JSON): the recorder's own counts and the mission's frame counts per
  camera (grabbed, processed, skipped, dropped: the ``end`` record's ``frame_counts``), at the
  end.

Splitting (``split_bytes``): once a closed chunk leaves the file at that size, the file is
finished (footer, index) and the recording goes on in ``NAME.001.mcap``, ``NAME.002.mcap``...;
each part starts with its metadata, schemas and channels and with copies of the messages a
reader needs to use it alone (both calibrations and camera models, the ``start`` and ``config``
records; the part's ``eaglemission.part`` metadata says how many: ``carried``).

Log time is the mission clock (virtual in simulation); publish time is the host's UTC time.
Crash safety: a chunk is closed and the file flushed after every ``chunk_s`` of mission time
(or of host time), and after ``chunk_bytes``; ``eaglemission log --recover`` rebuilds a file
cut short. Write errors never reach the mission: the recording stops, the error is counted and
reported in the mission log (an ``event`` record with ``source: recorder``).
"""

from __future__ import annotations

import json
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any, Literal

import cv2
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.writer import CompressionType, Writer

from eaglemission.geometry import CameraModel
from eaglemission.recording import foxglove as fox
from eaglemission.recording.folder import model_to_json
from eaglemission.recording.foxglove import calibration_message, file_descriptor_set
from eaglemission.recording.options import RecordOptions, part_path
from eaglemission.recording.vehicle_tap import TOPIC_STATE
from eaglemission.types import Frame

log = logging.getLogger(__name__)

TOPIC_IMAGE = "/camera/{}/image"
TOPIC_FRAME = "/camera/{}/frame"
TOPIC_CALIBRATION = "/camera/{}/calibration"
TOPIC_MODEL = "/camera/{}/model"
TOPIC_LOG = "/log/{}"
TOPIC_STATS = "/recorder/stats"
TOPIC_ANNOTATIONS = "/camera/{}/annotations"
TOPIC_SALIENCY = "/camera/{}/saliency"
TOPIC_MOUNT = "/camera/{}/mount"
TOPIC_TF = "/tf"
TOPIC_LOCATION = "/location"  # not under /vehicle/: those are the replay's JSON
CARRIED_LOG = ("/log/start", "/log/config")
"""Log topics whose first message every part of a split recording starts with."""
LOG_SCHEMA = "eaglemission.log.{}"
ENCODER_NICENESS = 10
"""The encoder thread runs this much nicer than the mission (Linux: per thread): on a busy
computer perception and the setpoint loop get the cores first; the bounded queue absorbs it."""
PROFILE = ""  # no ROS profile: protobuf and JSON channels


def log_json_schema(kind: str) -> bytes:
    schema = {"title": f"eaglemission mission-log record {kind!r} (missions/log.py)",
              "type": "object",
              "properties": {"kind": {"const": kind}, "t_s": {"type": "number"},
                             "t_ns": {"type": "integer"}, "wall_time": {"type": "string"}},
              "required": ["kind", "t_s", "t_ns"], "additionalProperties": True}
    return json.dumps(schema).encode()


def _plain(o: Any) -> Any:
    """numpy scalars and arrays as JSON values (the vehicle tap's messages)."""
    return o.tolist() if hasattr(o, "tolist") else repr(o)


_OBJECT_SCHEMA = json.dumps({"type": "object", "additionalProperties": True}).encode()


def lower_thread_priority(niceness: int) -> None:
    """Make the calling thread ``niceness`` nicer (Linux threads have their own nice value;
    elsewhere, or when refused, it keeps its priority and says so at debug level)."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + niceness)
    except (AttributeError, OSError) as exc:
        log.debug("thread priority unchanged: %s", exc)


class McapRecorder:
    """Record one flight into an MCAP file (see the module docstring).

    Parameters
    ----------
    path : the file (overwritten); ``stream``: write there instead (tests)
    when_full : ``"drop"`` (real time: never block the mission) or ``"wait"`` (virtual time:
        the mission waits for the encoder, so every processed frame is recorded)
    metadata : string pairs for the file's ``eaglemission`` metadata record
    """

    def __init__(self, path: str | Path | None, *, jpeg_quality: int = 75,
                 queue_frames: int = 32, when_full: Literal["drop", "wait"] = "drop",
                 chunk_s: float = 1.0, chunk_bytes: int = 4 << 20,
                 compression: str = "zstd", metadata: Mapping[str, str] | None = None,
                 stream: IO[bytes] | None = None, split_bytes: int | None = None,
                 image_format: Literal["jpeg", "png"] = "jpeg") -> None:
        if when_full not in ("drop", "wait") or image_format not in ("jpeg", "png"):
            raise ValueError(f"when_full: 'drop' or 'wait', got {when_full!r}; image_format: "
                             f"'jpeg' or 'png', got {image_format!r}")
        if not 1 <= int(jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality: 1..100, got {jpeg_quality}")
        self.path = None if path is None else Path(path)
        self.jpeg_quality = int(jpeg_quality)
        self.image_format = image_format
        self.when_full = when_full
        self.chunk_ns = int(chunk_s * 1e9)
        self.chunk_s = float(chunk_s)
        self.split_bytes = None if split_bytes is None or stream is not None else int(split_bytes)
        self.chunk_bytes = int(chunk_bytes) if self.split_bytes is None else max(
            1, min(int(chunk_bytes), self.split_bytes // 4))
        self.compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                            "none": CompressionType.NONE}[compression]
        self.metadata = dict(metadata or {})
        self.stats: dict[str, Any] = {
            "frames_written": 0, "frames_dropped": 0, "records_written": 0,
            "records_dropped": 0, "messages_lost": 0, "write_errors": 0, "chunks": 0,
            "bytes": 0, "parts": 1, "path": "" if path is None else str(path), "error": ""}
        self._stream = stream
        self._fh: IO[bytes] | None = None
        self._writer: Any = None  # mcap's Writer: flush()/finish() are untyped
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._carry: dict[str, tuple[Any, ...]] = {}
        """Topic -> the first message written on it, for the topics every part starts with."""
        self._part = 0
        self._bytes_before = 0
        self._queue: queue.Queue[tuple[Any, ...] | None] = queue.Queue()
        self._frame_slots = threading.Semaphore(max(1, int(queue_frames)))
        self._records_pending = 0
        self._max_records = 100_000
        self._lock = threading.Lock()
        self._unreported: list[str] = []
        self._log_write: Callable[..., Any] | None = None
        self._reporting = False
        self._closed = False
        self._last_state_ns: int | None = None
        self._chunk_t0: int | None = None
        self._t_max = 0
        self._chunk_size = 0
        self._last_flush = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="mcap-recorder", daemon=True)
        self._thread.start()

    # -- the mission's side (any thread; never blocks long, never raises) ----------------------
    def bind(self, write: Callable[..., Any]) -> None:
        self._log_write = write
        self._report()

    def _admit(self) -> bool:
        """Room for one more record (counted as pending), else counted as dropped."""
        if self._closed:
            return False
        with self._lock:
            if self._records_pending >= self._max_records:
                self.stats["records_dropped"] += 1
                return False
            self._records_pending += 1
        return True

    def record(self, record: Mapping[str, Any], line: str) -> None:
        if not self._admit():
            return
        if record.get("kind") == "end" and "frame_counts" in record:
            with self._lock:
                self.stats["cameras"] = record["frame_counts"]
        kind = str(record.get("kind", "unknown"))
        self._queue.put(("record", kind, int(record["t_ns"]), time.time_ns(), line,
                         record if kind == "detection" else None))
        self._report()

    def message(self, topic: str, t_ns: int, payload: Mapping[str, Any]) -> None:
        """Any JSON message on ``topic`` at mission time ``t_ns`` (the vehicle tap's)."""
        if not self._admit():
            return
        self._queue.put(("json", topic, int(t_ns), time.time_ns(), payload))

    def frame(self, frame: Frame) -> None:
        if self._closed:
            return
        if not self._frame_slots.acquire(blocking=self.when_full == "wait", timeout=(
                60.0 if self.when_full == "wait" else None)):
            with self._lock:
                self.stats["frames_dropped"] += 1
                n = self.stats["frames_dropped"]
            if n in (1, 10, 100, 1000) or n % 10_000 == 0:
                self._problem(f"dropped {n} frame(s) so far (the encoder is behind; last: "
                              f"{frame.camera_id} seq {frame.seq})")
            self._report()
            return
        self._queue.put(("frame", frame, time.time_ns()))
        self._report()

    def saliency(self, frame: Frame, thumb: Any) -> None:
        """The detector's map of a processed frame, shrunk (``/camera/<id>/saliency``)."""
        if thumb is not None and self._admit():
            self._queue.put(("saliency", frame.camera_id, int(frame.timestamp_ns),
                             time.time_ns(), thumb))

    def calibration(self, camera_id: str, model: CameraModel, t_ns: int) -> None:
        """Both messages describing a camera (``/camera/<id>/calibration`` and ``/model``)."""
        if not self._closed:
            self._queue.put(("calibration", camera_id, model, int(t_ns), time.time_ns()))

    def close(self, timeout_s: float = 60.0) -> dict[str, Any]:
        """Write what is queued, the stats message and the footer; the final stats."""
        if not self._closed:
            self._closed = True
            self._queue.put(None)
            self._thread.join(timeout=timeout_s)
            if self._thread.is_alive():
                log.warning("recorder: still writing after %.0f s; the file may lack its "
                            "footer (eaglemission log --recover)", timeout_s)
        return dict(self.stats)

    def _problem(self, text: str) -> None:
        log.warning("recorder: %s", text)
        with self._lock:
            self._unreported.append(text)

    def _report(self) -> None:
        """Write pending problems as ``event`` records (on the caller's thread)."""
        if self._log_write is None or self._reporting or not self._unreported:
            return
        self._reporting = True
        try:
            with self._lock:
                texts, self._unreported = self._unreported, []
            for text in texts:
                self._log_write("event", source="recorder", text=text,
                                recorder={k: v for k, v in self.stats.items() if k != "error"})
        except Exception:  # noqa: BLE001 - reporting must not stop a mission either
            log.exception("recorder: cannot report to the mission log")
        finally:
            self._reporting = False

    # -- the writer thread --------------------------------------------------------------------
    def _run(self) -> None:
        lower_thread_priority(ENCODER_NICENESS)
        try:
            self._open()
        except Exception as exc:  # noqa: BLE001 - an unwritable path must not stop a flight
            self._fail(f"cannot create {self.path}: {exc}")
        while True:
            try:
                item = self._queue.get(timeout=self.chunk_s)
            except queue.Empty:
                self._flush_if_due(idle=True)
                continue
            if item is None:
                break
            self._handle(item)
        self._finish()

    def _handle(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        try:
            if kind == "frame":
                self._write_frame(item[1], item[2])
            elif kind == "record":
                self._write(TOPIC_LOG.format(item[1]), LOG_SCHEMA.format(item[1]), "jsonschema",
                            log_json_schema(item[1]), "json", item[2], item[3],
                            item[4].encode("utf-8"))
                if self._writer is not None:
                    self.stats["records_written"] += 1
                if item[5] is not None:  # a detection: its overlay on the frame
                    self._proto(TOPIC_ANNOTATIONS.format(item[5]["camera"]),
                                fox.detection_annotations(item[5]), int(item[5]["frame_t_ns"]),
                                item[3])
            elif kind == "saliency":
                _, cid, t_ns, host_ns, thumb = item
                self._proto(TOPIC_SALIENCY.format(cid), fox.saliency_image(cid, t_ns, thumb),
                            t_ns, host_ns)
            elif kind == "json":
                data = json.dumps(item[4], separators=(",", ":"), default=_plain).encode()
                self._write(item[1], "eaglemission" + item[1].replace("/", "."), "jsonschema",
                            _OBJECT_SCHEMA, "json", item[2], item[3], data)
                if item[1] == TOPIC_STATE:
                    self._vehicle_views(item[4].get("state") or {}, item[2], item[3])
            elif kind == "calibration":
                _, cid, model, t_ns, host_ns = item
                msg = calibration_message(model, cid, t_ns)
                self._write(TOPIC_CALIBRATION.format(cid), "foxglove.CameraCalibration",
                            "protobuf", file_descriptor_set(CameraCalibration), "protobuf",
                            t_ns, host_ns, msg.SerializeToString())
                self._write(TOPIC_MODEL.format(cid), "eaglemission.CameraModel", "jsonschema",
                            _OBJECT_SCHEMA, "json", t_ns, host_ns,
                            json.dumps(model_to_json(model)).encode())
                self._proto(TOPIC_MOUNT.format(cid), fox.mount_transform(t_ns, cid, model),
                            t_ns, host_ns)
        except Exception as exc:  # noqa: BLE001 - disk full, I/O error: count, report, stop
            self._fail(f"write failed: {type(exc).__name__}: {exc}")
        finally:
            if kind == "frame":
                self._frame_slots.release()
            elif kind in ("record", "json", "saliency"):
                with self._lock:
                    self._records_pending -= 1
        self._flush_if_due()

    def _open(self) -> None:
        if self._stream is not None:
            self._fh = self._stream
        else:
            assert self.path is not None
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # closed in _finish / _fail / _split
            self._fh = open(part_path(self.path, self._part), "wb")  # noqa: SIM115
        w = Writer(self._fh, chunk_size=1 << 30, compression=self.compression)
        w.start(profile=PROFILE, library="eaglemission")
        if self.metadata:
            w.add_metadata("eaglemission", {str(k): str(v) for k, v in self.metadata.items()})
        if self.split_bytes is not None:
            assert self.path is not None
            w.add_metadata("eaglemission.part", {
                "part": str(self._part), "first": self.path.name,
                "carried": str(len(self._carry) if self._part else 0)})
        self._writer = w
        self._channels, self._schemas = {}, {}
        if self._part:
            for args in list(self._carry.values()):
                self._write(*args, carry=False)
        self._fh.flush()

    def _split(self) -> None:
        """Finish this part (footer, index) and go on in the next one."""
        w, fh = self._writer, self._fh
        assert w is not None and fh is not None
        w.finish()
        self.stats["chunks"] += 1
        self._bytes_before += fh.tell()
        fh.close()
        self._writer = self._fh = None
        self._part += 1
        self.stats["parts"] = self._part + 1
        self._open()

    def _write_frame(self, frame: Frame, host_ns: int) -> None:
        if self._writer is None:
            self.stats["messages_lost"] += 2
            return
        t0 = time.perf_counter()
        png = self.image_format == "png"
        ok, buf = cv2.imencode(".png" if png else ".jpg", frame.image,
                               [cv2.IMWRITE_PNG_COMPRESSION, 1] if png
                               else [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise OSError(f"cannot encode frame {frame.seq} of {frame.camera_id!r} as "
                          f"{self.image_format}")
        encode_ms = (time.perf_counter() - t0) * 1e3
        data = buf.tobytes()
        img = CompressedImage(frame_id=frame.camera_id, data=data, format=self.image_format)
        img.timestamp.FromNanoseconds(int(frame.timestamp_ns))
        cid = frame.camera_id
        self._write(TOPIC_IMAGE.format(cid), "foxglove.CompressedImage", "protobuf",
                    file_descriptor_set(CompressedImage), "protobuf", frame.timestamp_ns,
                    host_ns, img.SerializeToString(), sequence=frame.seq)
        meta = {"camera_id": cid, "seq": int(frame.seq), "timestamp_ns": int(frame.timestamp_ns),
                "host_time_ns": int(host_ns), "exposure_s": float(frame.exposure_s),
                "device_timestamp_ns": frame.device_timestamp_ns,
                "width_px": frame.width_px, "height_px": frame.height_px,
                "jpeg_quality": self.jpeg_quality, "jpeg_bytes": len(data),
                "encode_ms": round(encode_ms, 3)}
        self._write(TOPIC_FRAME.format(cid), "eaglemission.FrameInfo", "jsonschema",
                    _OBJECT_SCHEMA, "json", frame.timestamp_ns, host_ns,
                    json.dumps(meta).encode(), sequence=frame.seq)
        if self._writer is not None:
            self.stats["frames_written"] += 1

    def _vehicle_views(self, state: Mapping[str, Any], log_ns: int, host_ns: int) -> None:
        """The vehicle in Foxglove's 3D panel (``/tf``) and on its map (``/location``), once
        per telemetry sample (not again for the same sample changed by a command)."""
        t_ns = int(state.get("timestamp_ns") or log_ns)
        if t_ns == self._last_state_ns:
            return
        self._last_state_ns = t_ns
        tf = fox.vehicle_transform(t_ns, state)
        if tf is not None:
            self._proto(TOPIC_TF, tf, log_ns, host_ns)
        fix = fox.location_fix(t_ns, state)
        if fix is not None:
            self._proto(TOPIC_LOCATION, fix, log_ns, host_ns)

    def _proto(self, topic: str, msg: Any, log_ns: int, host_ns: int) -> None:
        """A Foxglove protobuf message (its schema named by its full protobuf name)."""
        self._write(topic, msg.DESCRIPTOR.full_name, "protobuf", fox.schema_of(type(msg)),
                    "protobuf", log_ns, host_ns, msg.SerializeToString())

    def _write(self, topic: str, schema_name: str, schema_encoding: str, schema: bytes,
               message_encoding: str, log_ns: int, publish_ns: int, data: bytes, *,
               sequence: int = 0, carry: bool = True) -> None:
        w = self._writer
        if w is None:
            self.stats["messages_lost"] += 1
            return
        if carry and self.split_bytes is not None and topic not in self._carry and (
                topic in CARRIED_LOG or topic.endswith(("/calibration", "/model", "/mount"))):
            self._carry[topic] = (topic, schema_name, schema_encoding, schema,
                                  message_encoding, log_ns, publish_ns, data)
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas.get(schema_name)
            if sid is None:
                sid = self._schemas[schema_name] = w.register_schema(schema_name,
                                                                     schema_encoding, schema)
            cid = self._channels[topic] = w.register_channel(topic, message_encoding, sid)
        w.add_message(cid, log_time=int(log_ns), data=data, publish_time=int(publish_ns),
                      sequence=int(sequence) & 0xFFFFFFFF)
        if self._chunk_t0 is None:
            self._chunk_t0 = int(log_ns)
        self._t_max = max(self._t_max, int(log_ns))
        self._chunk_size += len(data)

    def _flush_if_due(self, *, idle: bool = False) -> None:
        if self._writer is None or self._chunk_t0 is None:
            return
        due = (self._chunk_size >= self.chunk_bytes
               or self._t_max - self._chunk_t0 >= self.chunk_ns
               or time.monotonic() - self._last_flush >= self.chunk_s or idle)
        if not due:
            return
        try:
            self._writer.flush()  # closes the chunk, writes its indexes, flushes the stream
            self.stats["chunks"] += 1
            if self._fh is not None:
                size = self._fh.tell()
                self.stats["bytes"] = self._bytes_before + size
                if self.split_bytes is not None and size >= self.split_bytes:
                    self._split()
        except Exception as exc:  # noqa: BLE001
            self._fail(f"write failed: {type(exc).__name__}: {exc}")
        self._chunk_t0, self._chunk_size = None, 0
        self._last_flush = time.monotonic()

    def _fail(self, text: str) -> None:
        self.stats["write_errors"] += 1
        if not self.stats["error"]:
            self.stats["error"] = text
        self._writer = None
        fh, self._fh = self._fh, None
        if fh is not None and self._stream is None:
            try:
                fh.close()
            except Exception:  # noqa: BLE001 - the disk is already failing
                pass
        self._problem(f"recording stopped: {text} (the file keeps what was written before; "
                      "eaglemission log --recover FILE rebuilds it)")

    def _finish(self) -> None:
        w = self._writer
        if w is None:
            return
        try:
            stats = {k: v for k, v in self.stats.items() if k != "bytes"}
            self._write(TOPIC_STATS, "eaglemission.RecorderStats", "jsonschema", _OBJECT_SCHEMA,
                        "json", self._t_max, time.time_ns(), json.dumps(stats).encode())
            w.finish()
            self.stats["chunks"] += 1
            if self._fh is not None:
                self.stats["bytes"] = self._bytes_before + self._fh.tell()
                if self._stream is None:
                    self._fh.close()
                else:
                    self._fh.flush()
        except Exception as exc:  # noqa: BLE001
            self._fail(f"cannot finish the file: {type(exc).__name__}: {exc}")
        self._writer = None


def open_recorder(options: RecordOptions, models: Mapping[str, CameraModel], *,
                  virtual: bool, t_ns: int, metadata: Mapping[str, str]) -> McapRecorder:
    """The assembly's recorder for one flight, with both cameras' calibration written."""
    split = None if options.split_mb is None else int(options.split_mb * 1e6)
    rec = McapRecorder(options.path, jpeg_quality=options.jpeg_quality,
                       queue_frames=options.queue_frames,
                       when_full="wait" if virtual else "drop", chunk_s=options.chunk_s,
                       chunk_bytes=options.chunk_bytes, compression=options.compression,
                       metadata=metadata, split_bytes=split,
                       image_format="png" if options.lossless else "jpeg")
    for cid, model in models.items():
        rec.calibration(cid, model, t_ns)
    return rec


def flight_recorder(cfg: Any, options: RecordOptions | None, asm: Any, virtual: bool,
                    hooks: Any) -> tuple[McapRecorder | None, Any]:
    """The assembly's recorder for a flight (``options`` None: none) and the mission hooks
    that feed it."""
    if options is None:
        return None, hooks
    import dataclasses

    from eaglemission.recording.provenance import config_sha256, package_versions
    from eaglemission.recording.vehicle_tap import VehicleTap

    t0_ns = asm.clock.now_ns()
    meta = {"config_sha256": config_sha256(cfg), "versions": json.dumps(package_versions()),
            "clock": "virtual" if virtual else "wall", "t0_ns": str(t0_ns),
            "images": "png" if options.lossless else "jpeg"}
    rec = open_recorder(options, {c: cam.model for c, cam in asm.cameras.items()},
                        virtual=virtual, t_ns=t0_ns, metadata=meta)
    tap = getattr(asm.vehicle, "inner", None)
    if isinstance(tap, VehicleTap):  # what the mission gets from the vehicle (replay)
        tap.bind(rec.message)
    return rec, dataclasses.replace(hooks, recorder=rec)
