"""Rendering speed of the synthetic world: both cameras (2.8 mm wide + 12 mm narrow, 1280x960)
on one core, along the default mission's flight (cruise at 5 m, approach, stand-off).

Usage::

    python benchmarks/bench_render.py [--frames 60] [--threads 1] [--config FILE] [--effects]

Prints the median and 90th-percentile time per camera and per pair, the pair rate (target:
>= 30 pairs/s, i.e. both cameras in <= 33 ms), and the ratio to a reference measured in the same
run: one plain ``cv2.warpPerspective`` of a 1280x960 BGR image (the floor of the ground pass).

``--effects``: the cost of each imaging effect (docs/simulation.md, "Imaging effects"): the same
frames rendered with the config's world and with one effect turned on, interleaved frame by
frame (so a load change on the machine hits every variant alike); per camera the median time
and its ratio to the render without the effect. Motion blur uses the trajectory's speeds
(3 m/s cruise, 1.5 m/s approach) and a 30 deg/s yaw rate; its cost per blur length follows.
"""

from __future__ import annotations

import argparse
import math
import time

import cv2
import numpy as np
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import world_config
from eaglemission.missions.approach_config import ApproachConfig

from eaglemission.config import load_config
from eaglemission.geometry import euler_to_quat


def trajectory(cfg, n: int) -> list[tuple[tuple[float, float, float], tuple[float, ...]]]:
    """Cruise towards the target at 5 m, then descend to the stand-off pose."""
    sim = world_config(cfg)
    tn, te = sim.target_north_m, sim.target_east_m
    out = []
    for i in range(n):
        s = i / max(1, n - 1)
        if s < 0.5:  # cruise leg from home
            pos = (s * 2 * (tn - 8.0), 0.0, -cfg.mission.cruise_altitude_m)
            yaw = 0.0
        else:  # approach: to the stand-off
            a = (s - 0.5) * 2
            so = ApproachConfig.of(cfg).guidance.standoff
            start = np.array([tn - 8.0, 0.0, -cfg.mission.cruise_altitude_m])
            end = np.array([tn - so.horizontal_m, te, -(so.height_m + cfg.target.height_m)])
            p = start + a * (end - start)
            pos = (float(p[0]), float(p[1]), float(p[2]))
            yaw = math.degrees(math.atan2(te - p[1], tn - p[0]))
        out.append((pos, euler_to_quat(0.0, -3.0, yaw)))
    return out


EFFECTS = {
    "white balance": {"white_balance_gains_bgr": (0.9, 1.0, 1.1)},
    "Bayer (BayerRG)": {"bayer_pattern": "BayerRG"},
    "JPEG q80": {"jpeg_quality": 80},
    "motion blur": {"motion_blur": True},
    "all four": {"white_balance_gains_bgr": (0.9, 1.0, 1.1), "bayer_pattern": "BayerRG",
                 "jpeg_quality": 80, "motion_blur": True},
}


def exposure_start(poses, k: int, exposure_s: float, yaw_rate_degps: float = 30.0):
    """The pose half an exposure before pose k: back along the trajectory at its speed (3 m/s
    on the cruise half, 1.5 m/s on the approach), yawed back at ``yaw_rate_degps``."""
    from eaglemission.lab.cameras.synthetic import pose_moved_back

    n = len(poses)
    a, b = poses[max(0, k - 1)][0], poses[min(n - 1, max(1, k))][0]
    d = np.subtract(b, a)
    speed = 3.0 if k < n // 2 else 1.5
    v = d / max(float(np.linalg.norm(d)), 1e-9) * speed
    w = (0.0, 0.0, math.radians(yaw_rate_degps))
    return pose_moved_back(poses[k][0], poses[k][1], tuple(v), w, exposure_s / 2)


def effects(cfg, frames: int) -> None:
    from eaglemission.lab.cameras.imaging import motion_blur

    sim = world_config(cfg)
    variants = {"none": sim, **{name: sim.model_copy(update=u) for name, u in EFFECTS.items()}}
    worlds = {name: SyntheticWorld(s, cfg.target) for name, s in variants.items()}
    models = {cid: getattr(cfg.cameras, cid).to_model(cid) for cid in ("wide", "narrow")}
    poses = trajectory(cfg, frames)
    times = {(name, cid): [] for name in worlds for cid in models}
    blur = {cid: [] for cid in models}
    for w in worlds.values():
        for m in models.values():
            w.render(m, poses[0][0], poses[0][1], 1_000_000_000)
    for k, (pos, q) in enumerate(poses):
        t_ns = 1_000_000_000 + k * 33_333_333
        for cid, m in models.items():
            start = exposure_start(poses, k, m.exposure_s)
            for name, w in worlds.items():
                t = time.perf_counter()
                _, truth = w.render(m, pos, q, t_ns, exposure_start_pose=start)
                times[(name, cid)].append(time.perf_counter() - t)
                if name == "motion blur":
                    blur[cid].append(math.hypot(*truth.motion_blur_px))
    print(f"imaging effects, {frames} frames per camera, 1280x960 (median ms, ratio to none):")
    base = {cid: float(np.median(times[("none", cid)])) for cid in models}
    for name in worlds:
        cells = []
        for cid in models:
            med = float(np.median(times[(name, cid)]))
            cells.append(f"{cid} {med * 1e3:6.2f} ms ({med / base[cid]:.2f} x)")
        print(f"  {name:16s} " + "   ".join(cells))
    for cid, b in blur.items():
        print(f"  blur length {cid}: median {np.median(b):.1f} px, max {np.max(b):.1f} px")
    img = worlds["none"].render(models["narrow"], poses[-1][0], poses[-1][1], 10**9)[0]
    print(f"motion blur alone on a 1280x960 frame, by length (ratio to the plain narrow "
          f"render, {base['narrow'] * 1e3:.1f} ms):")
    for length in (1.0, 2.0, 4.0, 8.0, 12.0, 16.0, 24.0):
        ts = []
        for _ in range(7):
            t = time.perf_counter()
            motion_blur(img, length * 0.8, length * 0.6)
            ts.append(time.perf_counter() - t)
        med = float(np.median(ts))
        print(f"  {length:4.0f} px  {med * 1e3:6.2f} ms  (+{med / base['narrow']:.2f} x)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--threads", type=int, default=1, help="OpenCV threads (1 = one core)")
    ap.add_argument("--config", default=None, help="mission YAML (default: embedded)")
    ap.add_argument("--effects", action="store_true",
                    help="the cost of each imaging effect instead (interleaved variants)")
    args = ap.parse_args()
    cv2.setNumThreads(args.threads)
    cfg = load_config(args.config, check_plugins=False)
    if args.effects:
        effects(cfg, args.frames)
        return
    t0 = time.perf_counter()
    world = SyntheticWorld(world_config(cfg), cfg.target)
    t_world = time.perf_counter() - t0
    models = {cid: getattr(cfg.cameras, cid).to_model(cid) for cid in ("wide", "narrow")}
    poses = trajectory(cfg, args.frames)
    for m in models.values():  # warm-up: per-camera caches (noise bank)
        world.render(m, poses[0][0], poses[0][1], 1_000_000_000)
    times: dict[str, list[float]] = {cid: [] for cid in models}
    pair: list[float] = []
    for k, (pos, q) in enumerate(poses):
        t_ns = 1_000_000_000 + k * 33_333_333
        tp = time.perf_counter()
        for cid, m in models.items():
            t = time.perf_counter()
            world.render(m, pos, q, t_ns)
            times[cid].append(time.perf_counter() - t)
        pair.append(time.perf_counter() - tp)
    # reference: one plain warp of a 1280x960 BGR frame
    src = np.random.RandomState(0).randint(0, 255, (2048, 2048, 3), np.uint8)
    M = np.array([[1.2, 0.1, 20.0], [0.05, 1.1, 10.0], [1e-5, 2e-5, 1.0]])
    ref = []
    for _ in range(20):
        t = time.perf_counter()
        cv2.warpPerspective(src, M, (1280, 960), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        ref.append(time.perf_counter() - t)
    ref_ms = float(np.median(ref)) * 1e3
    print(f"world build (textures {world.extent_m:.0f} m, {world.textures.nbytes / 1e6:.0f} MB): "
          f"{t_world:.2f} s")
    print(f"OpenCV threads: {args.threads}; frames: {args.frames}; reference warp: {ref_ms:.2f} ms")
    for cid, ts in times.items():
        med, p90 = np.median(ts) * 1e3, np.percentile(ts, 90) * 1e3
        print(f"  {cid:7s} median {med:6.2f} ms  p90 {p90:6.2f} ms  ({med / ref_ms:.1f} x ref)")
    med, p90 = np.median(pair) * 1e3, np.percentile(pair, 90) * 1e3
    print(f"  pair    median {med:6.2f} ms  p90 {p90:6.2f} ms  -> {1e3 / med:.1f} pairs/s "
          f"(target >= 30: {'met' if 1e3 / med >= 30 else 'NOT met'})")


if __name__ == "__main__":
    main()
