"""Target estimation against the synthetic world (the synthetic renderer's ground truth):

1. the bias of the paper's "MBR corners = top-face corners" and the region-model correction
   (narrow camera, the configured box, the mission's geometry), on perfect silhouettes with
   0 and 1 px noise;
2. end to end through ``detectors.regions.find_regions`` on a simple colour saliency of the
   rendered narrow image;
3. the coarse estimators (``bearing`` top / mid-height plane, Eq. (16) ``pixel_offset``) on the
   wide camera;
4. the camera-switch predicate vs the narrow camera's render.

Usage: ``python benchmarks/bench_target.py [--views 12] [--seed 0]`` (reports/pose_estimation.md quotes
its output).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from eaglemission.estimators.bearing import BearingConfig, BearingEstimator  # noqa: E402
from eaglemission.estimators.correspondence import order_corners  # noqa: E402
from eaglemission.estimators.pixel_offset import PixelOffsetEstimator  # noqa: E402
from eaglemission.estimators.rpnp import RPnPConfig, RPnPEstimator  # noqa: E402
from eaglemission.lab.world.render import SyntheticWorld  # noqa: E402
from eaglemission.lab.world.synthetic import world_config

from eaglemission.config import load_config  # noqa: E402
from eaglemission.geometry import euler_to_quat  # noqa: E402
from eaglemission.geometry.fov import target_in_narrow_view  # noqa: E402
from eaglemission.interfaces.estimator import CameraView  # noqa: E402
from eaglemission.perception.regions import RegionsConfig, find_regions  # noqa: E402
from eaglemission.types import Detection, VehicleState  # noqa: E402


def detection_from_polygon(poly: np.ndarray, camera_id: str) -> Detection:
    rect = cv2.minAreaRect(np.asarray(poly, dtype=np.float32))
    corners = order_corners(cv2.boxPoints(rect).astype(np.float64))
    w, h = rect[1]
    return Detection(1.0, (float(rect[0][0]), float(rect[0][1])), corners,
                     (float(max(w, h)), float(min(w, h))), float(rect[2]), float(w * h), camera_id)


def view_at(model, pos, q, t_ns: int = 10**9) -> CameraView:
    return CameraView(model, VehicleState(t_ns, tuple(float(v) for v in pos), (0.0, 0.0, 0.0), q), t_ns)


def approach(tgt, range_m, dep_deg, az_deg, yaw_off, roll, pitch):
    dep, az = math.radians(dep_deg), math.radians(az_deg)
    hd, vh = range_m * math.cos(dep), range_m * math.sin(dep)
    pos = np.asarray(tgt) + np.array([-hd * math.cos(az), -hd * math.sin(az), -vh])
    return pos, euler_to_quat(roll, pitch, az_deg + yaw_off)


def stats(v: list[float]) -> str:
    a = np.array([x for x in v if np.isfinite(x)])
    if a.size == 0:
        return "      -"
    return f"{a.mean() * 100:6.2f} / {a.max() * 100:6.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--views", type=int, default=12, help="views per range")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg = load_config(check_plugins=False)
    world = SyntheticWorld(world_config(cfg), cfg.target, seed=1, extent_m=80.0)
    narrow = cfg.cameras.narrow.to_model("narrow")
    wide = cfg.cameras.wide.to_model("wide")
    tgt = np.array(world.target_position_ned_m)
    t = cfg.target
    print(f"# bench_target: box {t.length_m} x {t.width_m} x {t.height_m} m, narrow f="
          f"{narrow.fx:.0f} px, wide f={wide.fx:.0f} px, {args.views} views/range, seed {args.seed}")

    # 1 + 2. MBR bias and correction, narrow camera.
    print("\n## target position error, cm (mean / max), narrow camera, 30+-5 deg depression;"
          " fails = EstimationFailed")
    print("range   | silhouette MBR: none (paper)   auto (0 px)      auto (1 px)    "
          "| region pipeline: none            auto       ms/estimate")
    rs = np.random.RandomState(args.seed)
    for r in (1.5, 2.5, 4.0, 6.0, 8.0, 10.0):
        cols: dict[str, list[float]] = {k: [] for k in ("none", "auto0", "auto1", "p_none", "p_auto")}
        fails = {k: 0 for k in cols}
        ms: list[float] = []
        for _ in range(args.views):
            pos, q = approach(tgt, r, 30 + rs.uniform(-5, 5), rs.uniform(-180, 180),
                              rs.uniform(-3, 3), rs.uniform(-3, 3), rs.uniform(-3, 3))
            img, gt = world.render(narrow, pos, q, 10**9)
            poly = gt.target_polygon_px
            if not gt.target_visible or not narrow.in_image(poly, 2.0).all():
                continue
            view = view_at(narrow, pos, q)
            noisy = poly + rs.normal(scale=1.0, size=poly.shape)
            b, g, rr = (c.astype(np.float32) for c in cv2.split(img))
            sal = np.clip((rr - np.maximum(b, g)) / 120.0, 0, 1).astype(np.float32)
            dets, _ = find_regions(sal, RegionsConfig(), camera_id="narrow")
            jobs = [("none", "none", detection_from_polygon(poly, "narrow")),
                    ("auto0", "auto", detection_from_polygon(poly, "narrow")),
                    ("auto1", "auto", detection_from_polygon(noisy, "narrow"))]
            if dets:
                jobs += [("p_none", "none", dets[0]), ("p_auto", "auto", dets[0])]
            for key, mode, det in jobs:
                est = RPnPEstimator(RPnPConfig(mbr_correction=mode), target=t)
                t0 = time.perf_counter()
                res = est.estimate(det, view)
                if key == "p_auto":
                    ms.append((time.perf_counter() - t0) * 1e3)
                if not res:
                    fails[key] += 1
                    continue
                cols[key].append(float(np.linalg.norm(np.array(res.position_ned_m) - tgt)))

        cell = {k: f"{stats(cols[k])} ({fails[k]:d}f)" for k in cols}
        print(f"{r:5.1f} m | {cell['none']:>22s} {cell['auto0']:>20s} {cell['auto1']:>20s} | "
              f"{cell['p_none']:>22s} {cell['p_auto']:>20s}  {np.mean(ms) if ms else float('nan'):5.1f}")

    # 3. Coarse estimators, wide camera.
    print("\n## coarse estimators, wide camera, horizontal error cm (median / p90), detection ="
          " silhouette MBR centre")
    b_mid = BearingEstimator(BearingConfig(), target=t)
    b_top = BearingEstimator(BearingConfig(plane_height_fraction=1.0), target=t)
    eq16 = PixelOffsetEstimator(target=t)
    rows = []
    rs = np.random.RandomState(args.seed + 1)
    while len(rows) < 150:
        alt = rs.uniform(3.0, 6.0)
        dep = rs.uniform(15.0, 65.0)
        hd = (alt - t.height_m) / math.tan(math.radians(dep))
        az = rs.uniform(-180, 180)
        pos = tgt + np.array([-hd * math.cos(math.radians(az)), -hd * math.sin(math.radians(az)),
                              -(alt - t.height_m)])
        q = euler_to_quat(rs.uniform(-4, 4), rs.uniform(-4, 4), az + rs.uniform(-25, 25))
        _, gt = world.render(wide, pos, q, 10**9)
        if not gt.target_visible or not wide.in_image(gt.top_corners_px, 2.0).all():
            continue
        det = detection_from_polygon(gt.target_polygon_px, "wide")
        v = view_at(wide, pos, q)
        errs = []
        for e in (b_mid, b_top, eq16):
            res = e.estimate(det, v)
            errs.append(float(np.hypot(*(np.array(res.position_ned_m) - tgt)[:2])) if res else np.nan)
        rows.append((hd, *errs))
    a = np.array(rows)
    print("horizontal distance | bearing (mid-height) | bearing (top plane) | Eq. (16)")
    for lo, hi in ((0, 4), (4, 8), (8, 12), (12, 30)):
        s = a[(a[:, 0] >= lo) & (a[:, 0] < hi)]
        if len(s):
            cells = [f"{np.nanmedian(s[:, k]) * 100:7.1f} / {np.nanpercentile(s[:, k], 90) * 100:7.1f}"
                     for k in (1, 2, 3)]
            print(f"{lo:3d}-{hi:<3d} m (n={len(s):3d}) | " + " | ".join(cells))

    # 4. Camera-switch predicate.
    rs = np.random.RandomState(args.seed + 2)
    agree = total = fp = fn = 0
    for _ in range(120):
        alt = rs.uniform(1.5, 6.0)
        dep = rs.uniform(22.0, 40.0)
        hd = (alt - t.height_m) / math.tan(math.radians(dep))
        az = rs.uniform(-180, 180)
        pos = tgt + np.array([-hd * math.cos(math.radians(az)), -hd * math.sin(math.radians(az)),
                              -(alt - t.height_m)])
        q = euler_to_quat(rs.uniform(-4, 4), rs.uniform(-4, 4), az + rs.uniform(-12, 12))
        _, gw = world.render(wide, pos, q, 10**9)
        if not gw.target_visible or not wide.in_image(gw.target_polygon_px, 1.0).all():
            continue
        _, gn = world.render(narrow, pos, q, 10**9)
        truth = bool(gn.top_face_visible)
        det = detection_from_polygon(gw.target_polygon_px, "wide")
        pred = target_in_narrow_view(wide, narrow, det.corners_px,
                                     height_above_ground_m=float(tgt[2] - pos[2]), attitude_q=q)
        total += 1
        agree += pred == truth
        fp += pred and not truth
        fn += truth and not pred
    print(f"\n## camera switch: target_in_narrow_view (margin 20 px) vs narrow render (all top"
          f" corners inside): {agree}/{total} agree, {fp} false positives, {fn} false negatives")
    return 0


if __name__ == "__main__":
    sys.exit(main())
