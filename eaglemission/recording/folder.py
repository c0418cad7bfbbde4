"""Recorded runs (core: written by any flight, read by the ``replay`` camera and vehicle): the
folder format, its writer (:class:`RunRecorder`, behind ``eaglemission run --record DIR``) and
the telemetry reader. Format (docs/cameras.md, "Recorded runs")::

    <run>/
      telemetry.jsonl                 one VehicleState per line (JSON, as dataclasses.asdict)
      <camera_id>/camera.json         the camera model (K, distortion, resolution, mount)
      <camera_id>/frames.csv          seq,timestamp_ns,exposure_s,file
      <camera_id>/frames/<seq>.png    (or .jpg), seq zero-padded to 8 digits

Frames are encoded by a writer thread (a bounded queue: when the disk cannot keep up, frames are
dropped and counted, never blocking the caller), written to a temporary name and renamed, and
their CSV line is appended and flushed only after the image file is complete: a crash leaves no
half-written frame listed. Telemetry lines are flushed as they are written.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import os
import queue
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any, Literal

import cv2
import numpy as np

from eaglemission.geometry import CameraModel, CameraMount
from eaglemission.telemetry.history import TelemetryHistory
from eaglemission.types import FlightMode, Frame, GeoPoint, VehicleState

log = logging.getLogger(__name__)

FRAMES_CSV = "frames.csv"
FRAMES_DIR = "frames"
TELEMETRY = "telemetry.jsonl"
CAMERA_JSON = "camera.json"
CSV_HEADER = ("seq", "timestamp_ns", "exposure_s", "file")


# ---------------------------------------------------------------------------------------------
# Serialisation
# ---------------------------------------------------------------------------------------------
def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"cannot serialise {type(o).__name__}")


def _finite_or_none(v: float) -> float | None:
    return v if math.isfinite(v) else None


def state_to_json(state: VehicleState) -> str:
    d = dataclasses.asdict(state)
    d["flight_mode"] = str(state.flight_mode.value)
    d["battery_voltage_v"] = _finite_or_none(state.battery_voltage_v)
    return json.dumps(d, default=_json_default, allow_nan=False)


def state_from_json(line: str) -> VehicleState:
    d = json.loads(line)
    for k in ("position_ned_m", "velocity_ned_mps", "attitude_q", "angular_velocity_frd_radps"):
        if k in d:
            d[k] = tuple(float(v) for v in d[k])
    for k in ("geodetic", "home"):
        if d.get(k) is not None:
            d[k] = GeoPoint(**d[k])
    if "flight_mode" in d:
        d["flight_mode"] = FlightMode(d["flight_mode"])
    if d.get("battery_voltage_v") is None:
        d["battery_voltage_v"] = math.nan
    return VehicleState(**d)


def read_telemetry(run_dir: str | Path) -> list[VehicleState]:
    """All telemetry records of a run, in file order. A truncated last line (crash while
    writing) is skipped with a warning."""
    path = Path(run_dir) / TELEMETRY
    if not path.exists():
        raise FileNotFoundError(f"{path}: no telemetry in this run (expected {TELEMETRY})")
    out: list[VehicleState] = []
    with path.open("r", encoding="utf-8") as f:
        lines = f.readlines()
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            out.append(state_from_json(line))
        except (ValueError, TypeError, KeyError) as exc:
            if i == len(lines) - 1:
                log.warning("%s: skipping truncated last line: %s", path, exc)
                continue
            raise ValueError(f"{path}:{i + 1}: not a VehicleState record: {exc}") from exc
    return out


def recording_start_ns(run_dir: str | Path) -> int | None:
    """The first stamp of a recorded run: its first telemetry record, else its earliest
    frame; None when the folder holds no recorded run."""
    run = Path(run_dir)
    tel = run / TELEMETRY
    if tel.exists():
        with tel.open("r", encoding="utf-8") as f:
            for line in f:
                if line.strip():
                    try:
                        return int(json.loads(line)["timestamp_ns"])
                    except (ValueError, KeyError, TypeError):
                        break
    stamps = []
    for csv_path in run.glob(f"*/{FRAMES_CSV}"):
        with csv_path.open("r", encoding="utf-8", newline="") as f:
            rows = list(csv.reader(f))[1:2]
        if rows:
            try:
                stamps.append(int(rows[0][1]))
            except (ValueError, IndexError):
                pass
    return min(stamps) if stamps else None


def telemetry_history(run_dir: str | Path, *, max_extrapolation_s: float = 0.05
                      ) -> TelemetryHistory:
    """A :class:`TelemetryHistory` holding the whole run (``state_at`` for replayed frames)."""
    states = read_telemetry(run_dir)
    span = 1.0
    if len(states) >= 2:
        span = max(1.0, (states[-1].timestamp_ns - states[0].timestamp_ns) / 1e9 + 1.0)
    h = TelemetryHistory(span_s=span, max_extrapolation_s=max_extrapolation_s)
    for s in states:
        h.append(s)
    return h


def model_to_json(model: CameraModel) -> dict[str, Any]:
    return {"camera_id": model.camera_id, "width_px": model.width_px,
            "height_px": model.height_px, "K": np.asarray(model.K).tolist(),
            "distortion": list(model.distortion), "pixel_size_um": model.pixel_size_um,
            "focal_length_mm": _finite_or_none(model.focal_length_mm),
            "shutter": model.shutter, "exposure_s": model.exposure_s,
            "mount": dataclasses.asdict(model.mount)}


def model_from_json(d: dict[str, Any]) -> CameraModel:
    m = d["mount"]
    mount = CameraMount(m["roll_deg"], m["pitch_deg"], m["yaw_deg"], tuple(m["lever_arm_m"]))
    f = d.get("focal_length_mm")
    return CameraModel(d["camera_id"], int(d["width_px"]), int(d["height_px"]),
                       np.asarray(d["K"], dtype=np.float64), tuple(d.get("distortion", ())),
                       float(d.get("pixel_size_um", 3.75)),
                       float("nan") if f is None else float(f), d.get("shutter", "global"),
                       float(d.get("exposure_s", 0.005)), mount)


def read_camera_model(run_dir: str | Path, camera_id: str) -> CameraModel:
    path = Path(run_dir) / camera_id / CAMERA_JSON
    return model_from_json(json.loads(path.read_text(encoding="utf-8")))


# ---------------------------------------------------------------------------------------------
# Writer
# ---------------------------------------------------------------------------------------------
class RunRecorder:
    """Write a recorded run (frames of any cameras + telemetry) while the mission flies.

    Parameters
    ----------
    run_dir : created if missing; refuses a folder that already holds a run
    image_format : ``"png"`` (lossless, ~30 ms per 1280x960 frame) or ``"jpg"``
    jpeg_quality : for ``"jpg"``
    queue_frames : frames waiting for the writer thread before new ones are dropped (counted
        in ``stats["dropped_frames"]``)
    when_full : ``"drop"`` (real time: never block the caller) or ``"wait"`` (virtual time:
        the caller waits for room, so a simulated flight records every frame it grabbed)
    """

    def __init__(self, run_dir: str | Path, *, image_format: Literal["png", "jpg"] = "png",
                 jpeg_quality: int = 95, queue_frames: int = 64,
                 models: Mapping[str, CameraModel] | None = None,
                 when_full: Literal["drop", "wait"] = "drop") -> None:
        self.when_full = when_full
        self.run_dir = Path(run_dir)
        if (self.run_dir / TELEMETRY).exists() or any(self.run_dir.glob(f"*/{FRAMES_CSV}")):
            raise FileExistsError(f"{self.run_dir}: already holds a recorded run: choose a new "
                                  "folder (recordings are never overwritten)")
        if image_format not in ("png", "jpg"):
            raise ValueError(f"image_format: must be 'png' or 'jpg', got {image_format!r}")
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.image_format = image_format
        self._params = ([cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
                        if image_format == "jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 1])
        self._telemetry: IO[str] = (self.run_dir / TELEMETRY).open("a", encoding="utf-8")
        self._csv: dict[str, tuple[IO[str], Any]] = {}
        self._queue: queue.Queue[Frame | None] = queue.Queue(maxsize=queue_frames)
        self._lock = threading.Lock()
        self.stats = {"frames_written": 0, "dropped_frames": 0, "write_errors": 0,
                      "telemetry_records": 0}
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="run-recorder", daemon=True)
        self._thread.start()
        for cid, model in (models or {}).items():
            self.write_camera_model(model if model.camera_id == cid
                                    else dataclasses.replace(model, camera_id=cid))

    def __enter__(self) -> RunRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def set_models(self, models: Mapping[str, CameraModel]) -> None:
        """Write every camera's model (``<camera_id>/camera.json``)."""
        for cid, model in models.items():
            self.write_camera_model(model if model.camera_id == cid
                                    else dataclasses.replace(model, camera_id=cid))

    def write_camera_model(self, model: CameraModel) -> None:
        d = self.run_dir / model.camera_id
        d.mkdir(parents=True, exist_ok=True)
        tmp = d / (CAMERA_JSON + ".tmp")
        tmp.write_text(json.dumps(model_to_json(model), indent=2), encoding="utf-8")
        os.replace(tmp, d / CAMERA_JSON)

    def write_frame(self, frame: Frame) -> bool:
        """Queue a frame for writing; False (and counted) if the queue is full or closed."""
        if self._closed:
            return False
        try:
            if self.when_full == "wait":
                self._queue.put(frame, timeout=60.0)
            else:
                self._queue.put_nowait(frame)
            return True
        except queue.Full:
            with self._lock:
                self.stats["dropped_frames"] += 1
            return False

    def write_state(self, state: VehicleState) -> None:
        """Append one telemetry record and flush."""
        if self._closed:
            return
        line = state_to_json(state)
        with self._lock:
            self._telemetry.write(line + "\n")
            self._telemetry.flush()
            self.stats["telemetry_records"] += 1

    write_telemetry = write_state  # the mission runner's name for it

    def _writer_for(self, camera_id: str) -> tuple[IO[str], Any]:
        if camera_id not in self._csv:
            d = self.run_dir / camera_id / FRAMES_DIR
            d.mkdir(parents=True, exist_ok=True)
            f = (self.run_dir / camera_id / FRAMES_CSV).open("a", encoding="utf-8", newline="")
            w = csv.writer(f)
            if f.tell() == 0:
                w.writerow(CSV_HEADER)
                f.flush()
            self._csv[camera_id] = (f, w)
        return self._csv[camera_id]

    def _write_one(self, frame: Frame) -> None:
        f, w = self._writer_for(frame.camera_id)
        name = f"{frame.seq:08d}.{self.image_format}"
        final = self.run_dir / frame.camera_id / FRAMES_DIR / name
        ok, buf = cv2.imencode("." + self.image_format, frame.image, self._params)
        if not ok:
            raise OSError(f"cannot encode frame {frame.seq} of {frame.camera_id!r}")
        tmp = final.with_name(name + ".tmp")
        with tmp.open("wb") as out:
            out.write(buf.tobytes())
        os.replace(tmp, final)
        w.writerow((frame.seq, frame.timestamp_ns, repr(float(frame.exposure_s)),
                    f"{FRAMES_DIR}/{name}"))
        f.flush()

    def _run(self) -> None:
        while True:
            frame = self._queue.get()
            if frame is None:
                return
            try:
                self._write_one(frame)
                with self._lock:
                    self.stats["frames_written"] += 1
            except Exception:  # a full disk must not kill the mission: count and log
                log.exception("recorder: cannot write frame %s of %r", frame.seq,
                              frame.camera_id)
                with self._lock:
                    self.stats["write_errors"] += 1

    def close(self, timeout_s: float = 30.0) -> None:
        """Write what is queued (at most ``timeout_s``), then close the files. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            log.warning("recorder: queue still full after %.1f s; frames lost", timeout_s)
        self._thread.join(timeout=timeout_s)
        if self._thread.is_alive():
            log.warning("recorder: writer still busy after %.1f s", timeout_s)
        with self._lock:
            self._telemetry.close()
        for f, _ in self._csv.values():
            f.close()
