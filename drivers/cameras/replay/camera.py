"""``replay`` camera plugin: frames from image folders, video files or recorded runs.

Sources (``Config.path``), detected in this order:

* a **recorded run** (``<path>/<camera>/frames.csv``, written by
  :class:`~eaglemission.recording.folder.RunRecorder`): frames stamped with their
  recorded ``timestamp_ns`` (they match the run's ``telemetry.jsonl``);
* a **DAVIS-layout sequence** (``<path>/frames/*.jpg``) or any **image folder**
  (``*.png|*.jpg|*.jpeg|*.bmp|*.tif*``, natural name order);
* a **video file** (anything ``cv2.VideoCapture`` opens: mp4v .mp4, MJPG/XVID .avi);
* an **MCAP flight recording** (``FILE.mcap``, ``run --record``): the camera's processed
  frames with their recorded stamps (:mod:`.replay_mcap`).

Without recorded stamps, frame ``k`` is stamped ``start_ns + k / frame_rate_hz`` (the video's
own rate when ``frame_rate_hz`` is unset). Pacing ``as_fast_as_consumed`` hands the next
frame at once; ``realtime`` holds each frame until its offset from the first frame has elapsed
on the host monotonic clock; ``clock`` (the mission's replay deployment) serves, at each grab,
the newest frame whose recorded stamp has been reached on the flight's clock (virtual or real;
the recording's time base is shared with the ``replay`` vehicle through the assembly), skipping
older ones (counted) and raising :class:`~eaglemission.errors.GrabTimeout` when no new frame is
due yet. Frames keep their recorded stamps shifted by that common offset (zero in virtual time,
where the flight's clock starts at the recording's first stamp). Replays are deterministic; past the last frame ``grab`` raises
:class:`~eaglemission.errors.EndOfStream` (unless ``loop``). An undecodable or wrong-size
frame raises :class:`~eaglemission.errors.FrameError` (counted; the next grab moves on).
"""

from __future__ import annotations

import csv
import math
import re
import threading
import time
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from eaglemission.drivers.cameras.replay.mcap import McapFrames
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock
from eaglemission.errors import CameraError, ConfigError, EndOfStream, FrameError, GrabTimeout
from eaglemission.flight.context import REPLAY_EPOCH_NS, SharedContext
from eaglemission.geometry import CameraModel
from eaglemission.recording.folder import FRAMES_CSV, recording_start_ns
from eaglemission.recording.folder import RunRecorder as Recorder
from eaglemission.recording.mcap_reader import start_ns as mcap_start_ns
from eaglemission.types import Frame

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _natural_key(p: Path) -> list[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


def list_images(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                   and p.is_file()), key=_natural_key)


class _Entry:
    __slots__ = ("path", "timestamp_ns", "exposure_s", "seq")

    def __init__(self, path: Path | None, timestamp_ns: int, exposure_s: float, seq: int) -> None:
        self.path, self.timestamp_ns, self.exposure_s, self.seq = path, timestamp_ns, exposure_s, seq


def read_frames_csv(path: Path) -> list[_Entry]:
    """Rows of a recorded camera's frames.csv (a truncated last row is ignored)."""
    out: list[_Entry] = []
    with path.open("r", encoding="utf-8", newline="") as f:
        rows = list(csv.reader(f))
    if not rows or tuple(rows[0]) != ("seq", "timestamp_ns", "exposure_s", "file"):
        raise ConfigError(f"{path}: not a frames.csv (header must be "
                          "seq,timestamp_ns,exposure_s,file)")
    for i, row in enumerate(rows[1:], start=2):
        try:
            seq, ts, exp, name = int(row[0]), int(row[1]), float(row[2]), row[3]
        except (ValueError, IndexError):
            if i == len(rows):
                continue  # interrupted while writing the last line
            raise ConfigError(f"{path}:{i}: malformed row {row!r}") from None
        out.append(_Entry(path.parent / name, ts, exp, seq))
    return out


class ReplayCamera:
    """Replays frames from disk as a camera."""

    description = "Replay camera: image folders (DAVIS layout), video files, recorded runs"

    class Config(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        path: str = Field(default=".", description="run folder, image folder or video file")
        camera: str | None = Field(default=None,
                                   description="camera folder inside a recorded run "
                                               "(default: the rig's camera id)")
        pacing: Literal["realtime", "as_fast_as_consumed", "clock"] = "as_fast_as_consumed"
        frame_rate_hz: float | None = Field(default=None, gt=0, le=1000)
        start_ns: int = Field(default=1_000_000_000, ge=0,
                              description="stamp of frame 0 for sources without stamps")
        loop: bool = False
        check_size: bool = Field(default=True,
                                 description="frames must match the camera model's resolution")

    def __init__(self, config: Config | None = None, *, model: CameraModel,
                 clock: Clock | None = None, camera_id: str | None = None,
                 shared: SharedContext | None = None, **_context: Any) -> None:
        self.config = config or self.Config()
        self.clock = clock
        self._epoch_ns = 0
        if self.config.pacing == "clock":
            if clock is None:
                raise ConfigError(f"cameras.{camera_id or model.camera_id}.params.pacing: "
                                  "'clock' needs the flight's clock (use it through the assembly)")
            self._epoch_ns = replay_epoch_ns(shared, clock, Path(self.config.path).expanduser())
        self.model = model
        self.camera_id = camera_id or model.camera_id
        self._lock = threading.Lock()
        self._entries: list[_Entry] | None = None
        self._video: cv2.VideoCapture | None = None
        self._mcap: McapFrames | None = None
        self._video_fps = 30.0
        self._video_count = -1
        self._index = 0
        self._served = 0
        self._wall0: float | None = None
        self._ts0: int | None = None
        self.kind = ""
        self._closed = False
        self.stats = {"frames": 0, "frame_errors": 0, "timeouts": 0, "loops": 0}

    # -- lifetime --------------------------------------------------------------------------
    def open(self) -> None:
        with self._lock:
            self._closed = False
            if self._entries is not None or self._video is not None:
                return
            self._open_source()

    def _open_source(self) -> None:
        p = Path(self.config.path).expanduser()
        cam = self.config.camera or self.camera_id
        if not p.exists():
            raise ConfigError(f"cameras.{self.camera_id}.params.path: {str(p)!r} does not "
                              "exist: give a recorded run, an image folder or a video file")
        if p.is_file() and p.suffix.lower() == ".mcap":
            self._mcap = McapFrames(p, cam, where=f"cameras.{self.camera_id}.params.path")
            self._entries = [_Entry(None, ts, exp, seq) for seq, ts, exp in self._mcap.entries]
            self.kind = "mcap"
            return
        if p.is_file():
            cap = cv2.VideoCapture(str(p))
            if not cap.isOpened():
                raise ConfigError(f"cameras.{self.camera_id}.params.path: cannot open video "
                                  f"{str(p)!r} (OpenCV reads mp4v .mp4 and MJPG/XVID .avi)")
            fps = cap.get(cv2.CAP_PROP_FPS)
            self._video_fps = fps if fps and math.isfinite(fps) and fps > 0 else 30.0
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            self._video_count = n if n > 0 else -1
            self._video = cap
            self.kind = "video"
            return
        if (p / cam / FRAMES_CSV).exists():
            self._entries = read_frames_csv(p / cam / FRAMES_CSV)
            self.kind = "run"
            return
        folder = p / "frames" if (p / "frames").is_dir() else p
        images = list_images(folder)
        if not images:
            hint = f" (recorded run cameras: {sorted(d.name for d in p.iterdir() if (d / FRAMES_CSV).exists())})" \
                if any((d / FRAMES_CSV).exists() for d in p.iterdir() if d.is_dir()) else ""
            raise ConfigError(f"cameras.{self.camera_id}.params.path: no images in "
                              f"{str(folder)!r} and no {cam}/{FRAMES_CSV}{hint}")
        period = 1e9 / (self.config.frame_rate_hz or 30.0)
        self._entries = [_Entry(q, self.config.start_ns + int(round(k * period)), 0.0, k + 1)
                         for k, q in enumerate(images)]
        self.kind = "folder"

    def close(self) -> None:
        with self._lock:
            if self._video is not None:
                self._video.release()
            self._video = None
            self._entries = None
            self._mcap = None
            self._index = 0
            self._served = 0
            self._wall0 = self._ts0 = None
            self._closed = True

    def __enter__(self) -> ReplayCamera:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        if self._entries is not None:
            return len(self._entries)
        return max(0, self._video_count)

    # -- acquisition -----------------------------------------------------------------------
    def grab(self, *, timeout_s: float) -> Frame:
        if not timeout_s > 0 or not math.isfinite(timeout_s):
            raise ValueError(f"timeout_s: must be a finite number > 0, got {timeout_s}")
        with self._lock:
            if self._closed:
                raise CameraError("CLOSED", f"camera {self.camera_id!r}.grab()", None,
                                  "the camera is closed: open() it again to replay from the start")
            if self._entries is None and self._video is None:
                self._open_source()
            if self._video is not None:
                return self._grab_video(timeout_s)
            return self._grab_entry(timeout_s)

    def _pace(self, timestamp_ns: int, timeout_s: float) -> None:
        if self.config.pacing != "realtime":
            return
        now = time.monotonic()
        if self._wall0 is None or self._ts0 is None:
            self._wall0, self._ts0 = now, timestamp_ns
            return
        wait = self._wall0 + (timestamp_ns - self._ts0) / 1e9 - now
        if wait > timeout_s:
            time.sleep(timeout_s)
            self.stats["timeouts"] += 1
            raise GrabTimeout(self.camera_id, timeout_s)
        if wait > 0:
            time.sleep(wait)

    def _check(self, img: NDArray[Any] | None, what: str) -> NDArray[np.uint8]:
        if img is None or img.size == 0:
            self.stats["frame_errors"] += 1
            raise FrameError("CORRUPT_FRAME", f"camera {self.camera_id!r}.grab()", None,
                             f"{what}: cannot decode the image (corrupted or truncated file)")
        if self.config.check_size and (img.shape[1], img.shape[0]) != (
                self.model.width_px, self.model.height_px):
            self.stats["frame_errors"] += 1
            raise FrameError("WRONG_SIZE", f"camera {self.camera_id!r}.grab()", None,
                             f"{what}: {img.shape[1]}x{img.shape[0]} px but the camera model "
                             f"is {self.model.width_px}x{self.model.height_px}: fix "
                             "resolution_px or set params.check_size: false")
        return np.asarray(img, dtype=np.uint8)

    def _end(self) -> None:
        raise EndOfStream(self.camera_id, self._served)

    def _read(self, k: int, e: _Entry) -> NDArray[np.uint8]:
        """The checked image of entry ``k``."""
        if self._mcap is not None:
            return self._check(self._mcap.image(k), f"{self.config.path} frame {e.seq}")
        img = cv2.imread(str(e.path), cv2.IMREAD_COLOR) if e.path is not None else None
        return self._check(img, str(e.path))

    def _grab_due(self, timeout_s: float) -> Frame:
        """``pacing: clock``: the newest frame due on the flight's clock."""
        assert self._entries is not None and self.clock is not None
        due_ns = int(self.clock.now_ns()) - self._epoch_ns
        if self._index >= len(self._entries):
            if self._mcap is not None and due_ns <= self._mcap.end_ns:
                self.stats["timeouts"] += 1  # the recorded flight goes on without frames
                raise GrabTimeout(self.camera_id, timeout_s)
            self._end()
        k = self._index
        if self._entries[k].timestamp_ns > due_ns:
            self.stats["timeouts"] += 1
            raise GrabTimeout(self.camera_id, timeout_s)
        while k + 1 < len(self._entries) and self._entries[k + 1].timestamp_ns <= due_ns:
            k += 1
        self.stats["skipped"] = self.stats.get("skipped", 0) + (k - self._index)
        e = self._entries[k]
        self._index = k + 1
        img = self._read(k, e)
        self._served += 1
        self.stats["frames"] += 1
        return Frame(img, e.timestamp_ns + self._epoch_ns, self.camera_id, e.seq,
                     exposure_s=e.exposure_s)

    def _grab_entry(self, timeout_s: float) -> Frame:
        assert self._entries is not None
        if self.config.pacing == "clock":
            return self._grab_due(timeout_s)
        if self._index >= len(self._entries):
            if not self.config.loop or not self._entries:
                self._end()
            self._index = 0
            self._wall0 = self._ts0 = None
            self.stats["loops"] += 1
        e = self._entries[self._index]
        ts = e.timestamp_ns
        if self.config.loop and self.stats["loops"]:
            span = self._entries[-1].timestamp_ns - self._entries[0].timestamp_ns
            period = 1e9 / (self.config.frame_rate_hz or 30.0)
            ts += int(self.stats["loops"] * (span + period))
        self._pace(ts, timeout_s)
        self._index += 1  # a bad frame is skipped by the next grab
        img = self._read(self._index - 1, e)
        self._served += 1
        self.stats["frames"] += 1
        seq = e.seq + (self.stats["loops"] * len(self._entries) if self.config.loop else 0)
        return Frame(img, ts, self.camera_id, seq, exposure_s=e.exposure_s)

    def _grab_video(self, timeout_s: float) -> Frame:
        assert self._video is not None
        fps = self.config.frame_rate_hz or self._video_fps
        k = self._index
        ts = self.config.start_ns + int(round(k * 1e9 / fps))
        self._pace(ts, timeout_s)
        ok, img = self._video.read()
        if not ok:
            if self._video_count < 0 or k >= self._video_count:
                if self.config.loop and k > 0:
                    self._video.set(cv2.CAP_PROP_POS_FRAMES, 0)
                    ok, img = self._video.read()
                    self.stats["loops"] += 1
                if not ok:
                    self._end()
            else:
                self._index += 1
                self._check(None, f"{self.config.path} frame {k}")
        self._index += 1
        img = self._check(img, f"{self.config.path} frame {k}")
        self._served += 1
        self.stats["frames"] += 1
        return Frame(np.ascontiguousarray(img), ts, self.camera_id, k + 1)

    def health(self) -> dict[str, Any]:
        return {"camera_id": self.camera_id, "source": self.kind, "served": self._served,
                **self.stats}


def replay_epoch_ns(shared: SharedContext | None, clock: Clock, run_dir: Path) -> int:
    """Flight clock minus recorded time, the same for every replay plugin of one flight (set
    by the first one built: at that instant the flight's clock stands at the recording's first
    stamp in virtual time, so the offset is 0 there)."""
    def make() -> int:
        start = (mcap_start_ns(run_dir) if run_dir.suffix.lower() == ".mcap"
                 else recording_start_ns(run_dir))
        return 0 if start is None else int(clock.now_ns()) - start

    return make() if shared is None else shared.get_or_create(REPLAY_EPOCH_NS, make)


__all__ = ["ReplayCamera", "Recorder", "list_images", "read_frames_csv", "CameraError"]
