"""The renderer's speed paths give the images of the straightforward ones."""

from __future__ import annotations

import cv2
import eaglemission.lab.world.ground as ground_mod
import eaglemission.lab.world.render as world_mod
import numpy as np
from _camera_helpers import looking_at_target
from eaglemission.lab.world.render import SKY_HORIZON_BGR, SKY_ZENITH_BGR, SyntheticWorld

from eaglemission.geometry import euler_to_quat, quat_to_R


def test_four_channel_ground_equals_three_channel(sim_config, target_config, wide_model,
                                                  narrow_model, monkeypatch):
    fast = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    poses = [looking_at_target(d, b) for d, b in ((3.0, 10.0), (12.0, -30.0))]
    imgs = [fast.render(m, p, q, 1_000_000_000)[0] for m in (wide_model, narrow_model)
            for p, q in poses]
    assert any(v is not None for v in fast.ground.bgra.values())  # the 4-channel path was used
    monkeypatch.setattr(ground_mod, "BGRA_LEVEL_BUDGET_BYTES", 0)
    slow = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    ref = [slow.render(m, p, q, 1_000_000_000)[0] for m in (wide_model, narrow_model)
           for p, q in poses]
    assert all(v is None for v in slow.ground.bgra.values())
    for a, b in zip(imgs, ref):
        assert np.array_equal(a, b)


def _sky_reference(img, K, R_no):
    """The former sky fill: (h, W, 3) rays through a matrix product, full-frame mask."""
    H, W = img.shape[:2]
    Kinv = np.linalg.inv(K)
    down = (R_no @ Kinv)[2]
    rect = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    sky = world_mod.clip_polygon(rect, -down[:2], float(down[2]))
    if world_mod.polygon_area(sky) < 0.5:
        return
    mask = np.zeros((H, W), np.uint8)
    cv2.fillConvexPoly(mask, np.round(sky * 16).astype(np.int32), 255, cv2.LINE_8, 4)
    y0 = max(0, int(np.floor(sky[:, 1].min())))
    y1 = min(H, int(np.ceil(sky[:, 1].max())) + 1)
    vv, uu = np.mgrid[y0:y1, 0:W].astype(np.float32)
    ray = np.stack((uu, vv, np.ones_like(uu)), axis=-1) @ (R_no @ Kinv).T.astype(np.float32)
    elev = -ray[..., 2] / np.linalg.norm(ray, axis=-1)
    t = np.clip(elev / 0.5, 0.0, 1.0)[..., None] ** 0.6
    hz = np.asarray(SKY_HORIZON_BGR, np.float32)
    zn = np.asarray(SKY_ZENITH_BGR, np.float32)
    np.copyto(img[y0:y1], (hz + (zn - hz) * t).astype(np.uint8), where=mask[y0:y1, :, None] > 0)


def test_sky_equals_the_reference_fill(sim_config, target_config, wide_model):
    w = SyntheticWorld(sim_config, target_config, extent_m=60.0)
    true = w.true_camera(wide_model)  # the mount and focal errors the world renders with
    diff_px = total = 0
    for roll, pitch in ((0.0, 0.0), (20.0, 25.0), (-35.0, 10.0)):  # horizon tilted, raised
        R_no = quat_to_R(euler_to_quat(roll, pitch, 40.0)) @ true.mount.R_body_optical
        a = np.zeros((wide_model.height_px, wide_model.width_px, 3), np.uint8)
        b = a.copy()
        w.ground.render_sky(a, true.K, R_no)
        _sky_reference(b, true.K, R_no)
        d = np.abs(a.astype(int) - b.astype(int)).max(axis=2)
        assert d.max() <= 1  # float32 rounding order only
        diff_px += int((d > 0).sum())
        total += d.size
        assert (a != 0).any()  # there is sky in every case
    assert diff_px <= 1e-4 * total


def test_blend_with_zero_weight_is_the_identity():
    """The haze skips the edge fade on rows whose weight is 0: blendLinear(a, b, 1, 0) == a."""
    a = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(3, axis=2)
    b = np.full_like(a, 77)
    w1 = np.ones((16, 16), np.float32)
    assert np.array_equal(cv2.blendLinear(a, b, w1, np.zeros_like(w1)), a)


def test_copy_to_writes_into_a_view():
    """The shadow darkens an ROI view of the image in place with cv2.copyTo."""
    img = np.zeros((20, 30, 3), np.uint8)
    roi = img[5:15, 10:25]
    mask = np.zeros(roi.shape[:2], np.uint8)
    mask[2:6, 3:9] = 1
    cv2.copyTo(np.full_like(roi, 9), mask, roi)
    assert (img[7:11, 13:19] == 9).all() and img.sum() == 9 * 3 * 24


def _clip_polygon_reference(poly, normal, offset):
    """Sutherland-Hodgman as first written: every vertex through the loop."""
    if len(poly) == 0:
        return poly
    out = []
    d = poly @ normal - offset
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        da, db = d[i], d[(i + 1) % n]
        if da >= 0:
            out.append(a)
        if (da >= 0) != (db >= 0):
            s = da / (da - db)
            out.append(a + s * (b - a))
    return np.asarray(out, dtype=np.float64).reshape(-1, poly.shape[1])


def test_clip_polygon_shortcuts_equal_the_loop():
    """Polygons wholly kept or wholly clipped skip the vertex loop: same arrays as the loop
    (and partly clipped ones still go through it)."""
    rng = np.random.RandomState(5)
    kinds = {"all": 0, "none": 0, "part": 0}
    for _ in range(600):
        k = int(rng.choice([2, 3]))
        poly = rng.normal(0, 1, (int(rng.randint(3, 9)), k))
        normal = rng.normal(0, 1, k)
        offset = float(rng.normal(0, 2.0))
        d = poly @ normal - offset
        kinds["all" if (d >= 0).all() else "none" if (d < 0).all() else "part"] += 1
        a = world_mod.clip_polygon(poly, normal, offset)
        b = _clip_polygon_reference(poly, normal, offset)
        assert a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b)
        assert a is not poly
    assert min(kinds.values()) >= 50, kinds
