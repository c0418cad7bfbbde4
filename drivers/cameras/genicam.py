"""``genicam`` camera plugin: GenICam cameras (Basler daA1280-54uc, ...) through harvesters.

This is the only module that imports ``harvesters`` (lazily, on ``open``). GenTL producers
(``.cti`` files) come from ``Config.cti_files`` or from the folders listed in
``GENICAM_GENTL64_PATH`` (on a Basler rig, the pylon installation's producers). The device is
chosen by serial number, user id, model or GenTL id (the first match of all given keys).

On ``open`` the driver sets, through the node map, every configured feature whose node exists
(``PixelFormat``, ``Width``/``Height`` from the camera model, ``ExposureTime``, ``Gain``,
``AcquisitionFrameRate``, trigger: free run, or ``TriggerMode=On`` on a hardware line so that
two cameras expose together) and reports the ones the device lacks
(``health()["missing_nodes"]``).

``grab`` fetches with a timeout (``GrabTimeout``), copies the pixels **inside**
``with ia.fetch(...) as buffer:`` (harvesters requeues the buffer on exit), converts
Bayer / RGB / RGBa / BGR / Mono (8 to 16 bit) to BGR uint8, checks the size (``FrameError``)
and stamps the frame at mid-exposure on the host monotonic clock:

* with device timestamps, :class:`DeviceClockMapper` fits ``host = offset + (1 + drift) *
  device`` by least squares over a sliding window of (device timestamp, host receive time)
  pairs and takes the lower envelope (the least-delayed frames), the exposure-start latch is
  then mapped and half the exposure added;
* without (the device reports 0), the stamp is the host receive time minus
  ``transfer_latency_s`` minus half the exposure.

A failing fetch other than a timeout marks the device lost (``CameraLost``); later grabs reopen
it with exponential backoff (``reopen_backoff_s`` doubling up to ``reopen_backoff_max_s``),
raising ``CameraLost`` at once while waiting: never a hang.
"""

from __future__ import annotations

import glob
import importlib
import logging
import math
import os
import threading
import time
from collections import deque
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.clock import Clock, MonotonicClock
from eaglemission.errors import CameraLost, ConfigError, FrameError, GrabTimeout
from eaglemission.geometry import CameraModel
from eaglemission.types import Frame

log = logging.getLogger(__name__)

INSTALL_HINT = ("the genicam driver needs harvesters and genicam: "
                "pip install 'eaglemission[genicam]' (or pip install harvesters genicam)")

# GenICam PFNC Bayer names -> OpenCV codes (OpenCV names the pattern by its second row).
_BAYER = {"BayerRG": cv2.COLOR_BayerBG2BGR, "BayerBG": cv2.COLOR_BayerRG2BGR,
          "BayerGR": cv2.COLOR_BayerGB2BGR, "BayerGB": cv2.COLOR_BayerGR2BGR}


def _u8(img: Any) -> NDArray[np.uint8]:
    """An OpenCV result as the uint8 array it is (no copy)."""
    return np.asarray(img, dtype=np.uint8)


def _import_harvesters() -> Any:
    try:  # harvesters ships no type information: imported as a module object
        return importlib.import_module("harvesters.core")
    except ImportError as exc:
        raise ImportError(f"{INSTALL_HINT} ({exc})") from exc


# ---------------------------------------------------------------------------------------------
# Pixel conversion (pure)
# ---------------------------------------------------------------------------------------------
def _bits(pixel_format: str) -> int:
    for b in (16, 14, 12, 10, 8):
        if pixel_format.endswith(str(b)) or f"{b}p" in pixel_format or f"{b}Packed" in pixel_format:
            return b
    return 8


def to_bgr(data: NDArray[Any], width: int, height: int, pixel_format: str) -> NDArray[np.uint8]:
    """Convert a buffer's pixels (1-D or 2-D array as harvesters gives them) to an owned BGR
    uint8 image. Raises :class:`FrameError` on a size mismatch or an unsupported format."""
    fmt = pixel_format
    bits = _bits(fmt)
    if "Packed" in fmt or fmt.endswith("p"):
        raise FrameError("UNSUPPORTED_FORMAT", "to_bgr", fmt,
                         "packed pixel formats are not supported: choose an unpacked "
                         "PixelFormat (e.g. BayerRG8, Mono8, RGB8)")
    channels = 1
    if fmt.startswith(("RGBa", "BGRa", "RGBA", "BGRA")):
        channels = 4
    elif fmt.startswith(("RGB", "BGR")):
        channels = 3
    elif not fmt.startswith(("Mono", "Bayer")):
        raise FrameError("UNSUPPORTED_FORMAT", "to_bgr", fmt,
                         "set PixelFormat to a Mono, Bayer, RGB or BGR format")
    if width <= 0 or height <= 0:
        raise FrameError("WRONG_SIZE", "to_bgr", fmt,
                         f"the buffer says {width}x{height} px: an empty or corrupted frame")
    arr = np.asarray(data)
    need = width * height * channels
    if arr.size != need:
        raise FrameError("WRONG_SIZE", "to_bgr", fmt,
                         f"buffer holds {arr.size} values, {width}x{height}x{channels} expected "
                         "(corrupted or incomplete frame)")
    arr = arr.reshape(height, width, channels) if channels > 1 else arr.reshape(height, width)
    if arr.dtype != np.uint8:
        arr = (arr.astype(np.uint32) >> max(0, bits - 8)).astype(np.uint8)
    if fmt.startswith("Bayer"):
        code = _BAYER.get(fmt[:7])
        if code is None:
            raise FrameError("UNSUPPORTED_FORMAT", "to_bgr", fmt, "unknown Bayer pattern")
        return _u8(cv2.cvtColor(arr, code))
    if channels == 1:
        return _u8(cv2.cvtColor(arr, cv2.COLOR_GRAY2BGR))
    if fmt.startswith(("RGBa", "RGBA")):
        return _u8(cv2.cvtColor(arr, cv2.COLOR_RGBA2BGR))
    if fmt.startswith(("BGRa", "BGRA")):
        return _u8(cv2.cvtColor(arr, cv2.COLOR_BGRA2BGR))
    if fmt.startswith("RGB"):
        return _u8(cv2.cvtColor(arr, cv2.COLOR_RGB2BGR))
    return np.array(arr, dtype=np.uint8, copy=True)


# ---------------------------------------------------------------------------------------------
# Device clock -> host monotonic clock
# ---------------------------------------------------------------------------------------------
class DeviceClockMapper:
    """Least-squares fit ``host_ns = offset + (1 + drift) * device_ns`` over the last
    ``window`` (device, host receive) pairs, shifted to their lower envelope (the frames with
    the least transfer delay). Times are centred for numerical stability."""

    def __init__(self, window: int = 1000) -> None:
        if window < 2:
            raise ValueError(f"window: must be >= 2, got {window}")
        self._pairs: deque[tuple[int, int]] = deque(maxlen=window)
        self._fit: tuple[float, float, float, float] | None = None  # dev0, host0, slope, rms
        self._dirty = False

    def __len__(self) -> int:
        return len(self._pairs)

    def add(self, device_ns: int, host_ns: int) -> None:
        if self._pairs and device_ns <= self._pairs[-1][0]:
            self._pairs.clear()  # device clock reset (reopen, power cycle)
        self._pairs.append((int(device_ns), int(host_ns)))
        self._dirty = True

    def _solve(self) -> tuple[float, float, float, float] | None:
        if not self._dirty:
            return self._fit
        self._dirty = False
        if not self._pairs:
            self._fit = None
            return None
        d = np.array([p[0] for p in self._pairs], dtype=np.float64)
        h = np.array([p[1] for p in self._pairs], dtype=np.float64)
        d0, h0 = d[0], h[0]
        x, y = d - d0, h - h0
        if len(d) >= 3 and np.ptp(x) > 0:
            slope, icpt = np.polyfit(x, y, 1)
        else:
            slope, icpt = 1.0, float(np.mean(y - x))
        res = y - (icpt + slope * x)
        rms = float(np.sqrt(np.mean(res ** 2)))
        icpt = icpt + float(res.min())  # lower envelope: least-delayed frames
        self._fit = (d0, h0 + icpt, float(slope), rms)
        return self._fit

    def to_host_ns(self, device_ns: int) -> int | None:
        fit = self._solve()
        if fit is None:
            return None
        d0, h0, slope, _ = fit
        return int(round(h0 + slope * (device_ns - d0)))

    def stats(self) -> dict[str, float]:
        fit = self._solve()
        if fit is None:
            return {"pairs": 0}
        d0, h0, slope, rms = fit
        return {"pairs": len(self._pairs), "offset_ns": h0 - d0, "drift_ppm": (slope - 1) * 1e6,
                "residual_rms_s": rms / 1e9}


def gentl_producers(cti_files: list[str]) -> list[str]:
    """The .cti files to load: the configured ones, else those in ``GENICAM_GENTL64_PATH``."""
    if cti_files:
        missing = [f for f in cti_files if not os.path.isfile(f)]
        if missing:
            raise ConfigError(f"cti_files: {missing} not found: give the GenTL producer files "
                              "(.cti) of your camera vendor (pylon: <pylon>/lib/gentlproducer)")
        return list(cti_files)
    out: list[str] = []
    for folder in os.environ.get("GENICAM_GENTL64_PATH", "").split(os.pathsep):
        if folder:
            out += sorted(glob.glob(os.path.join(folder, "*.cti")))
    if not out:
        raise ConfigError("no GenTL producer: set params.cti_files or GENICAM_GENTL64_PATH "
                          "(the folders holding your vendor's .cti files)")
    return out


class _SharedHarvesters:
    """One :class:`harvesters.core.Harvester` per set of GenTL producers in this process,
    shared by every camera that uses them: a producer loaded by a second Harvester lists no
    devices (measured with the genicam wheel's viky.cti, and two Basler cameras on one pylon
    producer are the same case), so both cameras of the rig must open through one."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: dict[tuple[str, ...], list[Any]] = {}

    def acquire(self, core: Any, cti_files: list[str]) -> Any:
        key = tuple(cti_files)
        with self._lock:
            item = self._items.get(key)
            if item is None:
                h = core.Harvester()
                try:
                    for f in cti_files:
                        h.add_file(f)
                    h.update()
                except BaseException:
                    h.reset()
                    raise
                item = self._items[key] = [h, 0]
            item[1] += 1
            return item[0]

    def release(self, harvester: Any) -> None:
        with self._lock:
            for key, item in list(self._items.items()):
                if item[0] is harvester:
                    item[1] -= 1
                    if item[1] <= 0:
                        del self._items[key]
                        try:
                            harvester.reset()
                        except Exception:  # the producer may be gone already
                            log.debug("harvester reset failed", exc_info=True)
                    return

    def refresh(self, harvester: Any) -> None:
        """Update the device list (a reopen after a device was lost) when no other camera
        uses this Harvester (``update()`` would invalidate their device infos)."""
        with self._lock:
            for item in self._items.values():
                if item[0] is harvester and item[1] <= 1:
                    harvester.update()


HARVESTERS = _SharedHarvesters()


# ---------------------------------------------------------------------------------------------
# The plugin
# ---------------------------------------------------------------------------------------------
class GenICamCamera:
    """A GenICam camera through harvesters (GenTL)."""

    description = "GenICam camera through harvesters/GenTL (Basler USB3 Vision, ...)"
    wall_clock = True  # a real device: frames arrive in host time
    extra = "genicam"  # harvesters + genicam (eaglemission.extras)

    class Config(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

        cti_files: list[str] = Field(default_factory=list,
                                     description="GenTL producers; default GENICAM_GENTL64_PATH")
        serial_number: str | None = None
        user_id: str | None = None
        model: str | None = Field(default=None, description="device model name")
        device_id: str | None = Field(default=None, description="GenTL device id")
        pixel_format: str | None = Field(default=None, description="e.g. BayerRG8, Mono8")
        set_resolution: bool = Field(default=True,
                                     description="write Width/Height from the camera model")
        exposure_time_us: float | None = Field(default=None, gt=0)
        gain_db: float | None = None
        frame_rate_hz: float | None = Field(default=None, gt=0)
        trigger: str = Field(default="free_run",
                             description="free_run, or a hardware line (line1, Line2, ...)")
        trigger_activation: Literal["RisingEdge", "FallingEdge"] = "RisingEdge"
        num_buffers: int = Field(default=4, ge=1, le=64)
        transfer_latency_s: float = Field(default=0.0, ge=0, le=1,
                                          description="subtracted from host receive stamps "
                                                      "when the device has no timestamps")
        clock_window: int = Field(default=1000, ge=2, le=100000,
                                  description="(device, host) pairs in the clock fit")
        reopen_backoff_s: float = Field(default=0.5, gt=0, le=60)
        reopen_backoff_max_s: float = Field(default=10.0, gt=0, le=600)

    def __init__(self, config: Config | None = None, *, model: CameraModel,
                 clock: Clock | None = None, camera_id: str | None = None,
                 **_context: Any) -> None:
        self.config = config or self.Config()
        self.model = model
        self.camera_id = camera_id or model.camera_id
        self.clock: Clock = clock or MonotonicClock()
        self._h: Any = None
        self._ia: Any = None
        self._lock = threading.RLock()
        self._lost = False
        self._next_reopen = 0.0
        self._backoff = self.config.reopen_backoff_s
        self._seq = 0
        self._device_frame_id: int | None = None  # the last buffer's frame id
        self._exposure_s = model.exposure_s
        self.clock_mapper = DeviceClockMapper(self.config.clock_window)
        self.missing_nodes: list[str] = []
        self.device_info: dict[str, str] = {}
        self.stats = {"frames": 0, "timeouts": 0, "frame_errors": 0, "lost": 0,
                      "reopen_attempts": 0, "reopened": 0}

    # -- opening -----------------------------------------------------------------------------
    def _search_key(self) -> dict[str, str]:
        c = self.config
        key = {}
        if c.serial_number is not None:
            key["serial_number"] = c.serial_number
        if c.user_id is not None:
            key["user_defined_name"] = c.user_id
        if c.model is not None:
            key["model"] = c.model
        if c.device_id is not None:
            key["id_"] = c.device_id
        return key

    def _select_device(self, h: Any) -> Any:
        def attr(d: Any, name: str) -> str | None:
            try:
                return str(getattr(d, name))
            except Exception:  # the producer may not support the field
                return None

        key = self._search_key()
        infos = list(h.device_info_list)
        matches = [d for d in infos if all(attr(d, k) == v for k, v in key.items())]
        if not matches:
            seen = [{k: attr(d, k) for k in ("id_", "model", "serial_number")} for d in infos]
            raise CameraLost("NO_DEVICE", f"camera {self.camera_id!r}.open()", key,
                             f"no device matches; found {seen}: check serial_number / user_id "
                             "/ model, the cabling and GENICAM_GENTL64_PATH")
        d = matches[0]
        self.device_info = {k: v for k in ("id_", "model", "serial_number", "vendor")
                            if (v := attr(d, k)) is not None}
        return d

    def _set(self, nm: Any, name: str, value: Any) -> None:
        try:
            node = getattr(nm, name)
        except Exception:
            self.missing_nodes.append(name)
            return
        try:
            node.value = value
        except Exception as exc:
            raise ConfigError(f"cameras.{self.camera_id}.params: cannot set {name} = "
                              f"{value!r} on {self.device_info.get('model', 'the device')}: "
                              f"{exc}") from exc

    def _configure(self, nm: Any) -> None:
        c = self.config
        self.missing_nodes = []
        if c.pixel_format is not None:
            self._set(nm, "PixelFormat", c.pixel_format)
        if c.set_resolution:
            self._set(nm, "Width", int(self.model.width_px))
            self._set(nm, "Height", int(self.model.height_px))
        if c.exposure_time_us is not None:
            self._set(nm, "ExposureAuto", "Off") if hasattr(nm, "ExposureAuto") else None
            self._set(nm, "ExposureTime", float(c.exposure_time_us))
            self._exposure_s = c.exposure_time_us * 1e-6
        if c.gain_db is not None:
            self._set(nm, "GainAuto", "Off") if hasattr(nm, "GainAuto") else None
            self._set(nm, "Gain", float(c.gain_db))
        if c.frame_rate_hz is not None:
            if hasattr(nm, "AcquisitionFrameRateEnable"):
                self._set(nm, "AcquisitionFrameRateEnable", True)
            self._set(nm, "AcquisitionFrameRate", float(c.frame_rate_hz))
        if c.trigger.lower() in ("free_run", "freerun", "off"):
            if hasattr(nm, "TriggerMode"):
                self._set(nm, "TriggerMode", "Off")
        else:
            line = c.trigger[0].upper() + c.trigger[1:]
            self._set(nm, "TriggerSelector", "FrameStart")
            self._set(nm, "TriggerMode", "On")
            self._set(nm, "TriggerSource", line)
            self._set(nm, "TriggerActivation", c.trigger_activation)
        if self.missing_nodes:
            log.warning("camera %r (%s): nodes not available, not set: %s", self.camera_id,
                        self.device_info.get("model", "?"), ", ".join(self.missing_nodes))

    def open(self) -> None:
        with self._lock:
            if self._ia is not None:
                return
            core = _import_harvesters()
            h = HARVESTERS.acquire(core, gentl_producers(self.config.cti_files))
            try:
                if self._lost:
                    HARVESTERS.refresh(h)
                dev = self._select_device(h)
                ia = h.create(dev)
                try:
                    self._configure(ia.remote_device.node_map)
                    ia.num_buffers = self.config.num_buffers
                    ia.start()
                except BaseException:
                    ia.destroy()
                    raise
            except BaseException:
                HARVESTERS.release(h)
                raise
            self._h, self._ia = h, ia
            self._lost = False
            self._backoff = self.config.reopen_backoff_s

    def _teardown(self) -> None:
        ia, h = self._ia, self._h
        self._ia = self._h = None
        for step in ("stop", "destroy"):
            try:
                if ia is not None:
                    getattr(ia, step)()
            except Exception:  # tearing down a lost device: errors are expected
                log.debug("camera %r: teardown step failed", self.camera_id, exc_info=True)
        if h is not None:
            HARVESTERS.release(h)

    def close(self) -> None:
        with self._lock:
            self._teardown()
            self._lost = False

    def __enter__(self) -> GenICamCamera:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- acquisition ---------------------------------------------------------------------------
    def _mark_lost(self, detail: str) -> CameraLost:
        self.stats["lost"] += 1
        self._lost = True
        self._teardown()
        self._next_reopen = time.monotonic() + self._backoff
        log.error("camera %r lost: %s; reopening in %.1f s", self.camera_id, detail,
                  self._backoff)
        return CameraLost("DEVICE_LOST", f"camera {self.camera_id!r}.grab()", None,
                          f"{detail}; reopening with backoff (next try in {self._backoff:.1f} s)")

    def _try_reopen(self) -> None:
        now = time.monotonic()
        if now < self._next_reopen:
            raise CameraLost("DEVICE_LOST", f"camera {self.camera_id!r}.grab()", None,
                             f"device lost; next reopen attempt in {self._next_reopen - now:.1f} s")
        self.stats["reopen_attempts"] += 1
        try:
            self.open()
        except Exception as exc:
            self._backoff = min(self._backoff * 2.0, self.config.reopen_backoff_max_s)
            self._next_reopen = time.monotonic() + self._backoff
            raise CameraLost("REOPEN_FAILED", f"camera {self.camera_id!r}.grab()", None,
                             f"{exc}; next attempt in {self._backoff:.1f} s") from exc
        self.stats["reopened"] += 1
        log.warning("camera %r reopened", self.camera_id)

    def grab(self, *, timeout_s: float) -> Frame:
        if not timeout_s > 0 or not math.isfinite(timeout_s):
            raise ValueError(f"timeout_s: must be a finite number > 0, got {timeout_s}")
        with self._lock:
            if self._lost:
                self._try_reopen()
            if self._ia is None:
                self.open()
            core = _import_harvesters()
            try:
                with self._ia.fetch(timeout=timeout_s) as buffer:
                    host_ns = int(self.clock.now_ns())
                    comp = buffer.payload.components[0]
                    # copy out of the buffer before it is requeued
                    width, height = int(comp.width), int(comp.height)
                    fmt = str(comp.data_format)
                    raw = np.array(comp.data, copy=True)
                    dev_ns = self._device_timestamp_ns(buffer)
                    frame_id = _frame_id(buffer)
            except core.TimeoutException:
                self.stats["timeouts"] += 1
                raise GrabTimeout(self.camera_id, timeout_s) from None
            except Exception as exc:
                raise self._mark_lost(f"{type(exc).__name__}: {exc}") from exc
        try:
            image = to_bgr(raw, width, height, fmt)
        except FrameError:
            self.stats["frame_errors"] += 1
            raise
        if (width, height) != (self.model.width_px, self.model.height_px):
            self.stats["frame_errors"] += 1
            raise FrameError("WRONG_SIZE", f"camera {self.camera_id!r}.grab()", None,
                             f"{width}x{height} px but the camera model is "
                             f"{self.model.width_px}x{self.model.height_px}: fix resolution_px "
                             "or the device's Width/Height")
        ts = self._stamp(dev_ns, host_ns)
        self._seq += self._seq_step(frame_id)
        self.stats["frames"] += 1
        return Frame(image, ts, self.camera_id, self._seq, exposure_s=float(self._exposure_s),
                     device_timestamp_ns=dev_ns if dev_ns > 0 else None)

    def _seq_step(self, frame_id: int | None) -> int:
        """How far ``seq`` advances: the device's frame-id step (the frames it delivered that
        were not fetched show as a gap, counted as skipped), else 1; a frame id that does not
        advance (the device restarted its count) also steps by 1, so ``seq`` keeps rising."""
        last, self._device_frame_id = self._device_frame_id, frame_id
        if frame_id is None or last is None or frame_id <= last:
            return 1
        return frame_id - last

    @staticmethod
    def _device_timestamp_ns(buffer: Any) -> int:
        for attr in ("timestamp_ns",):
            try:
                v = int(getattr(buffer, attr))
                if v > 0:
                    return v
            except Exception:
                pass
        try:
            ticks = int(buffer.timestamp)
        except Exception:
            return 0
        return ticks  # USB3 Vision / GigE with 1 GHz tick: ticks are ns

    def _stamp(self, dev_ns: int, host_ns: int) -> int:
        half = int(round(self._exposure_s * 0.5e9))
        if dev_ns > 0:
            self.clock_mapper.add(dev_ns, host_ns)
            mapped = self.clock_mapper.to_host_ns(dev_ns)
            if mapped is not None and len(self.clock_mapper) >= 3:
                return mapped + half  # device latches the exposure start
        return host_ns - int(round(self.config.transfer_latency_s * 1e9)) - half

    def summary(self) -> str:
        d = self.device_info
        who = d.get("id_") or d.get("serial_number") or "not open"
        return f"{d.get('vendor', '')} {d.get('model', '')} {who}".strip()

    @property
    def frame_rate_hz(self) -> float:
        return float(self.config.frame_rate_hz or math.inf)

    def health(self) -> dict[str, Any]:
        return {"camera_id": self.camera_id, "open": self._ia is not None, "is_lost": self._lost,
                "device": dict(self.device_info), "missing_nodes": list(self.missing_nodes),
                "clock": self.clock_mapper.stats(), **self.stats}


def _frame_id(buffer: Any) -> int | None:
    """The GenTL buffer's frame id (the device's frame counter), None when it has none."""
    try:
        v = int(buffer.frame_id)
    except Exception:  # noqa: BLE001 - GenTL raises NotAvailable when the producer has none
        return None
    return v if v > 0 else None
