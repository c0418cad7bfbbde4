"""GenICam driver through the real harvesters/GenTL path with the simulated ``viky.cti``
producer of the genicam wheel, plus its pure parts (pixel conversion, clock mapping)."""

from __future__ import annotations

import os
import time

import cv2
import numpy as np
import pytest
from eaglemission.drivers.cameras.genicam import DeviceClockMapper, GenICamCamera, to_bgr

from eaglemission import registry
from eaglemission.errors import CameraLost, ConfigError, FrameError, GrabTimeout
from eaglemission.geometry import CameraModel


@pytest.fixture
def viky() -> str:
    genicam = pytest.importorskip("genicam")
    path = os.path.join(os.path.dirname(genicam.__file__), "viky.cti")
    if not os.path.isfile(path):
        pytest.skip("viky.cti not shipped with this genicam wheel")
    return path


def _cam(cti: str, w: int = 320, h: int = 240, **params) -> GenICamCamera:
    model = CameraModel.from_lens("wide", focal_length_mm=2.8, resolution_px=(w, h))
    return GenICamCamera(GenICamCamera.Config(cti_files=[cti], **params), model=model)


def test_genicam_is_a_registered_camera_plugin():
    assert registry.get("cameras", "genicam") is GenICamCamera


@pytest.mark.parametrize("fmt", ["Mono8", "RGBa8"])
def test_viky_frames_of_requested_size_and_format_with_increasing_stamps(viky, fmt):
    cam = _cam(viky, 400, 300, device_id="VikyTL_DEV_green", pixel_format=fmt,
               frame_rate_hz=60.0, exposure_time_us=2000.0)
    with cam:
        frames = [cam.grab(timeout_s=2.0) for _ in range(5)]
        first = frames[0].image.copy()
        frames += [cam.grab(timeout_s=2.0) for _ in range(5)]  # buffers get requeued/reused
        health = cam.health()
    # frames own their pixels: later fetches did not overwrite the first one
    assert np.array_equal(frames[0].image, first)
    assert not np.array_equal(frames[0].image, frames[-1].image)  # viky's square moves
    assert all(f.image.shape == (300, 400, 3) and f.image.dtype == np.uint8 for f in frames)
    assert [f.seq for f in frames] == list(range(1, 11))
    assert np.all(np.diff([f.timestamp_ns for f in frames]) > 0)
    # the device's own stamp rides beside the mapped one; viky's buffers carry timestamp 0
    # (no device clock), which the driver reports as None, not as a time
    assert [f.device_timestamp_ns for f in frames] == [None] * 10
    assert all(f.exposure_s == pytest.approx(0.002) for f in frames)
    # viky has no ExposureTime node: reported, not silently ignored
    assert "ExposureTime" in health["missing_nodes"]
    assert health["device"]["id_"] == "VikyTL_DEV_green"
    if fmt == "Mono8":
        img = frames[-1].image
        assert np.array_equal(img[..., 0], img[..., 2])


def test_seq_follows_the_devices_frame_counter(viky):
    """Grabbing slower than the device delivers: the frames it produced meanwhile (its GenTL
    frame id; dropped from the full buffer queue) show as gaps in ``seq``, which the mission's
    camera pump counts as skipped."""
    cam = _cam(viky, frame_rate_hz=30.0, num_buffers=2)
    with cam:
        frames = []
        for _ in range(6):
            frames.append(cam.grab(timeout_s=2.0))
            time.sleep(0.2)
    seqs = [f.seq for f in frames]
    assert np.all(np.diff(seqs) > 0), seqs
    assert seqs[-1] - seqs[0] > len(seqs) + 5, seqs  # frames the device delivered unfetched


def test_viky_device_selection_by_serial_and_model(viky):
    with _cam(viky, serial_number="2", model="Viky") as cam:
        assert cam.health()["device"]["id_"] == "VikyTL_DEV_blue"
        cam.grab(timeout_s=2.0)
    with pytest.raises(CameraLost, match="no device matches"):
        _cam(viky, serial_number="does-not-exist").open()


def test_closing_the_producer_under_the_driver_is_survived_and_reported(viky):
    cam = _cam(viky, device_id="VikyTL_DEV_red", reopen_backoff_s=0.2)
    with cam:
        cam.grab(timeout_s=2.0)
        cam._h.reset()  # the GenTL producer goes away under the driver
        with pytest.raises(CameraLost):
            cam.grab(timeout_s=1.0)
        assert cam.health()["is_lost"] and cam.health()["lost"] == 1
        # during the backoff: an immediate CameraLost, no hang
        t = time.monotonic()
        with pytest.raises(CameraLost, match="next reopen"):
            cam.grab(timeout_s=1.0)
        assert time.monotonic() - t < 0.1
        deadline = time.monotonic() + 5.0
        frame = None
        while frame is None and time.monotonic() < deadline:
            try:
                frame = cam.grab(timeout_s=1.0)
            except CameraLost:
                time.sleep(0.05)
        assert frame is not None and frame.image.shape == (240, 320, 3)
        h = cam.health()
        assert h["reopened"] == 1 and not h["is_lost"]


def test_grab_timeout_when_no_frame_arrives(viky):
    """At 1 frame/s, a 50 ms fetch finds no frame: GrabTimeout, within the timeout."""
    cam = _cam(viky, device_id="VikyTL_DEV_red", frame_rate_hz=1.0)
    with cam:
        cam.grab(timeout_s=3.0)
        t = time.monotonic()
        with pytest.raises(GrabTimeout):
            cam.grab(timeout_s=0.05)
        assert time.monotonic() - t < 0.5
        assert cam.health()["timeouts"] == 1


def test_missing_producer_is_a_config_error(monkeypatch):
    monkeypatch.delenv("GENICAM_GENTL64_PATH", raising=False)
    model = CameraModel.from_lens("wide", focal_length_mm=2.8)
    with pytest.raises(ConfigError, match="GENICAM_GENTL64_PATH"):
        GenICamCamera(model=model).open()
    with pytest.raises(ConfigError, match="not found"):
        GenICamCamera(GenICamCamera.Config(cti_files=["/nope.cti"]), model=model).open()


def test_bayer_and_colour_conversions_recover_bgr():
    rng = np.random.RandomState(11)
    bgr = cv2.resize(rng.randint(0, 255, (6, 8, 3), np.uint8), (64, 48),
                     interpolation=cv2.INTER_CUBIC)
    b, g, r = bgr[..., 0], bgr[..., 1], bgr[..., 2]
    # GenICam BayerRG8: R at (0, 0), G at (0, 1) and (1, 0), B at (1, 1)
    mosaic = np.empty((48, 64), np.uint8)
    mosaic[0::2, 0::2], mosaic[0::2, 1::2] = r[0::2, 0::2], g[0::2, 1::2]
    mosaic[1::2, 0::2], mosaic[1::2, 1::2] = g[1::2, 0::2], b[1::2, 1::2]
    out = to_bgr(mosaic.ravel(), 64, 48, "BayerRG8")
    assert np.abs(out[4:-4, 4:-4].astype(int) - bgr[4:-4, 4:-4]).mean() < 6
    rgba = np.dstack((r, g, b, np.full_like(r, 255)))
    assert np.array_equal(to_bgr(rgba.ravel(), 64, 48, "RGBa8"), bgr)
    assert np.array_equal(to_bgr(bgr[..., ::-1].ravel(), 64, 48, "RGB8"), bgr)
    mono16 = (g.astype(np.uint16) << 4)
    assert np.array_equal(to_bgr(mono16.ravel(), 64, 48, "Mono12")[..., 1], g)
    with pytest.raises(FrameError, match="expected"):
        to_bgr(mosaic.ravel()[:-5], 64, 48, "BayerRG8")  # truncated buffer
    with pytest.raises(FrameError, match="PixelFormat"):
        to_bgr(mosaic.ravel(), 64, 48, "YCbCr422_8")


def test_device_clock_mapper_recovers_offset_and_drift():
    rng = np.random.RandomState(5)
    m = DeviceClockMapper(window=1000)
    offset_ns, drift = 123_456_789_000, 40e-6
    dev = np.arange(1200) * 33_333_333 + 5_000_000_000
    for d in dev:
        latency = 200_000 + rng.exponential(300_000)  # transfer delay, >= 0.2 ms
        m.add(int(d), int(offset_ns + d * (1 + drift) + latency))
    st = m.stats()
    assert st["pairs"] == 1000
    assert st["drift_ppm"] == pytest.approx(40.0, abs=5.0)
    d = int(dev[-1])
    err = m.to_host_ns(d) - (offset_ns + d * (1 + drift))
    assert 0 <= err <= 400_000  # lower envelope: the minimal 0.2 ms latency stays in
    m.add(1_000, 10**12)  # device clock reset: history restarts
    assert m.stats()["pairs"] == 1


def test_trigger_nodes_missing_are_reported_and_bad_values_refused(viky):
    with _cam(viky, device_id="VikyTL_DEV_blue", trigger="line1") as cam:
        missing = cam.health()["missing_nodes"]
        assert {"TriggerMode", "TriggerSource"} <= set(missing)
        cam.grab(timeout_s=2.0)
    with pytest.raises(ConfigError, match="PixelFormat"):
        _cam(viky, device_id="VikyTL_DEV_blue", pixel_format="BayerRG8").open()
    # the failed open released the device: it can be opened again
    with _cam(viky, device_id="VikyTL_DEV_blue") as cam:
        cam.grab(timeout_s=2.0)
