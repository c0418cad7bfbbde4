"""The synthetic camera plugin, make_synthetic_rig and the camera rig."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from _camera_helpers import StaticPose, looking_at_target
from eaglemission.lab.cameras.rig import CameraRig
from eaglemission.lab.cameras.synthetic import SyntheticCamera, make_synthetic_rig
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import world_config

from eaglemission import registry
from eaglemission.clock import ManualClock
from eaglemission.errors import GrabTimeout
from eaglemission.types import Frame


def test_synthetic_is_a_registered_camera_plugin():
    assert registry.get("cameras", "synthetic") is SyntheticCamera


def test_time_offset_renders_the_earlier_pose(sim_config, target_config, wide_model):
    sim = sim_config.model_copy(update={"camera_time_offset_s": 0.04})
    world = SyntheticWorld(sim, target_config, extent_m=60.0)
    pos, q = looking_at_target(5.0, 0.0)
    source = StaticPose(pos, q, velocity_ned_mps=(2.0, 0.0, 0.0))
    clock = ManualClock(2_000_000_000)
    cam = SyntheticCamera(model=wide_model, clock=clock, world=world, pose_source=source)
    f = cam.grab(timeout_s=1.0)
    gt = cam.truth(f.seq)
    assert f.timestamp_ns == 2_000_000_000 == gt.timestamp_ns
    assert gt.render_time_ns == 2_000_000_000 - 40_000_000 == source.calls[-1]
    # the image is the one of the earlier pose, not of the stamp's pose
    p_early = source(gt.render_time_ns)[0]
    img, _ = world.render(wide_model, p_early, q, gt.render_time_ns)
    assert np.array_equal(img, f.image)


def test_no_pose_is_a_grab_timeout(sim_config, target_config, wide_model):
    world = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    cam = SyntheticCamera(model=wide_model, clock=ManualClock(), world=world,
                          pose_source=lambda t: None)
    with pytest.raises(GrabTimeout):
        cam.grab(timeout_s=0.1)
    assert cam.health()["no_pose"] == 1


def test_make_synthetic_rig_from_the_default_mission(sitl_config):
    clock = ManualClock(1_000_000_000)
    sim = world_config(sitl_config)
    tn, te = sim.target_north_m, sim.target_east_m
    pose = StaticPose((tn - 8.0, te, -5.0), (1.0, 0.0, 0.0, 0.0))
    rig = make_synthetic_rig(sitl_config, pose, clock)
    assert isinstance(rig, CameraRig) and isinstance(rig.world, SyntheticWorld)
    assert rig.world.extent_m >= 2 * sitl_config.safety.geofence.radius_m
    with rig:
        pair = rig.grab_pair(timeout_s=2.0)
        assert pair.synced and pair.skew_s == 0.0
        assert pair.wide.image.shape == (960, 1280, 3) and pair.narrow.image.shape == (960, 1280, 3)
        gt_w = rig.world.truth("wide", pair.wide.seq)
        assert gt_w.target_visible
        clock.advance(1 / 30)
        only = rig.grab("wide", timeout_s=1.0)
        assert only.seq == 2 and rig.narrow.seq == 1  # cruise: one camera only
    h = rig.health()
    assert h["rig"]["pairs"] == 1 and h["cameras"]["wide"]["frames"] == 2


class _FakeCam:
    """A camera producing frames with scripted timestamps (a fake, not a mock)."""

    def __init__(self, cid: str, stamps: list[int]) -> None:
        from eaglemission.geometry import CameraModel

        self.camera_id = cid
        self.model = CameraModel.from_lens(cid, focal_length_mm=2.8, resolution_px=(8, 6))
        self.stamps = list(stamps)
        self.seq = 0

    def open(self) -> None: ...

    def close(self) -> None: ...

    def grab(self, *, timeout_s: float) -> Frame:
        if not self.stamps:
            raise GrabTimeout(self.camera_id, timeout_s)
        self.seq += 1
        return Frame(np.zeros((6, 8, 3), np.uint8), self.stamps.pop(0), self.camera_id, self.seq)


@pytest.mark.parametrize("threaded", [True, False])
def test_rig_pairs_by_timestamp_and_reports_skew(threaded):
    ms = 1_000_000
    wide = _FakeCam("wide", [100 * ms, 133 * ms, 166 * ms])
    narrow = _FakeCam("narrow", [70 * ms, 103 * ms, 136 * ms, 169 * ms])
    with CameraRig(wide, narrow, max_skew_s=0.005, threaded=threaded) as rig:
        p1 = rig.grab_pair(timeout_s=1.0)  # narrow 30 ms older: re-grabbed once
        assert (p1.wide.timestamp_ns, p1.narrow.timestamp_ns) == (100 * ms, 103 * ms)
        assert p1.synced and p1.skew_s == pytest.approx(0.003)
        p2 = rig.grab_pair(timeout_s=1.0)
        assert p2.skew_s == pytest.approx(0.003)
    st = rig.health()["rig"]
    assert st["pairs"] == 2 and st["regrabs"] == 1 and st["max_abs_skew_s"] == pytest.approx(0.003)


def test_rig_reports_unsynced_pairs_instead_of_hanging():
    ms = 1_000_000
    wide = _FakeCam("wide", [100 * ms])
    narrow = _FakeCam("narrow", [10 * ms])  # no newer narrow frame will come
    rig = CameraRig(wide, narrow, max_skew_s=0.005, threaded=False)
    pair = rig.grab_pair(timeout_s=0.5)
    assert not pair.synced and pair.skew_s == pytest.approx(-0.09)
    assert rig.health()["rig"]["unsynced_pairs"] == 1


def test_grab_from_a_worker_thread_under_virtual_time(sim_config, target_config, wide_model):
    """The runner renders in a worker thread (run_blocking) with the loop's virtual clock."""
    from eaglemission.clock import LoopClock, run_blocking, run_virtual

    world = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    pos, q = looking_at_target(5.0, 0.0)

    async def main() -> list[int]:
        cam = SyntheticCamera(model=wide_model, clock=LoopClock(), world=world,
                              pose_source=StaticPose(pos, q))
        stamps = []
        for _ in range(3):
            f = await run_blocking(lambda: cam.grab(timeout_s=1.0))
            stamps.append(f.timestamp_ns)
            await asyncio.sleep(1 / 30)
        return stamps

    stamps = run_virtual(main())
    assert stamps[0] == 1_000_000_000
    assert np.diff(stamps) == pytest.approx([33_333_333] * 2, abs=2)
