"""Where the wall time of a closed-loop simulation goes, and the speed paths against the
straightforward ones they replaced, measured in the same run (the requirement: ``eaglemission run`` at
>= 10x real time; frame-to-setpoint latency p90 <= 18.5 ms at 1280x960).

    python benchmarks/bench_sim_speed.py [CONFIG] [--detector NAME] [--downscale K]
                                         [--runs N] [--skip-components] [--skip-flight]

Components (thread CPU time, median of repeats; the ratio is reference / fast, same process):

* ground rendering from 4-channel texture levels vs the 3-channel path, both cameras at mission
  poses (the images are identical, tests/lab/world/test_world_fast_paths.py);
* the fused MSS pass (numba) vs the numpy/OpenCV reference, at 640x480 and 1280x960;
* the box fit's Levenberg-Marquardt call (``_lm_fit``) vs ``scipy.optimize.least_squares``;
* RPnP's pose refinement compiled (numba) vs its numpy reference;
* the runner's top-plane fit (all hypotheses batched) vs the one-at-a-time reference, and the
  close-range colour region with the compiled mask vs the numpy mask (stand-off / grasp poses).

Flight: ``run_simulation`` of CONFIG (default: the embedded sitl_synthetic.yaml) with the time
split by worker (render, detect, rest of perception: selection + estimation) in wall and thread
CPU time, the event loop's own CPU, the speed-up over real time, and the latency. The machine's
load average is printed: 2 shared cores, so wall figures vary 2x with the load; the CPU figures
do not.
"""

from __future__ import annotations

import argparse
import collections
import logging
import os
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
from eaglemission.detectors import base as det_base
from eaglemission.detectors.mss import mss_distance
from eaglemission.estimators import correspondence as corr
from eaglemission.estimators.rpnp import refine_pose
from eaglemission.lab.cameras.synthetic import geofence_extent_m
from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.lab.vehicles.multicopter.dynamics import attitude_from_acceleration
from eaglemission.lab.world import render as world_mod
from eaglemission.lab.world.synthetic import world_config
from eaglemission.missions import runner as runner_mod
from eaglemission.missions import silhouette as sil
from eaglemission.missions.approach_config import ApproachConfig

from eaglemission.config import MissionFile, load_config
from eaglemission.geometry import camera_pose_ned


def cpu_ms(fn: Callable[[], Any], repeats: int = 15) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        t = time.thread_time()
        fn()
        ts.append(time.thread_time() - t)
    return float(np.median(ts) * 1e3)


def load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.1f} {b:.1f} {c:.1f} on {os.cpu_count() or 0} cores"


def mission_poses(cfg: MissionFile) -> list[tuple[str, tuple[float, float, float], Any]]:
    sim = world_config(cfg)
    tn, te = sim.target_north_m, sim.target_east_m
    alt = cfg.mission.cruise_altitude_m
    so = ApproachConfig.of(cfg).guidance.standoff
    return [("cruise", (tn - 12.0, 0.0, -alt), attitude_from_acceleration((1.0, 0.0, 0.0), 0.0)),
            ("standoff", (tn - so.horizontal_m, te, -(so.height_m + cfg.target.height_m)),
             attitude_from_acceleration((0.0, 0.0, 0.0), 0.0)),
            ("grasp", (tn - 0.5, te, -0.7), attitude_from_acceleration((0.0, 0.0, 0.0), 0.0))]


def components(cfg: MissionFile) -> None:
    print(f"== components ({load()})")
    cv2.setNumThreads(1)  # CPU of one core, comparable between paths
    ext = min(1000.0, geofence_extent_m(cfg))
    fast = world_mod.SyntheticWorld(world_config(cfg), cfg.target, extent_m=ext)
    slow = world_mod.SyntheticWorld(world_config(cfg), cfg.target, extent_m=ext)
    slow.ground.bgra.update({lvl: None for lvl in range(len(slow.textures.base))})  # 3-channel path
    for cam in ("wide", "narrow"):
        model = getattr(cfg.cameras, cam).to_model(cam)
        for name, pos, q in mission_poses(cfg):
            a = cpu_ms(lambda m=model, p=pos, qq=q: fast.render(m, p, qq, 2_000_000_000))
            b = cpu_ms(lambda m=model, p=pos, qq=q: slow.render(m, p, qq, 2_000_000_000))
            same = np.array_equal(fast.render(model, pos, q, 2_000_000_000)[0],
                                  slow.render(model, pos, q, 2_000_000_000)[0])
            print(f"render {cam:6s} {name:8s}: {a:5.1f} ms (3-channel ground {b:5.1f} ms, "
                  f"x{b / a:.2f}; identical {same})")
    rng = np.random.RandomState(3)
    for h, w in ((480, 640), (960, 1280)):
        img = cv2.GaussianBlur(rng.randint(0, 256, (h, w, 3)).astype(np.uint8), (0, 0), 2.0)
        lab8 = cv2.cvtColor(img, cv2.COLOR_BGR2Lab)
        bl = cv2.GaussianBlur(lab8, (0, 0), 1.0)
        a = cpu_ms(lambda x=lab8, y=bl: mss_distance(x, y, full_scale_lab=120.0))
        b = cpu_ms(lambda x=lab8, y=bl: mss_distance(x, y, full_scale_lab=120.0,
                                                     backend="numpy"))
        print(f"MSS pass {w}x{h}: {a:5.2f} ms (numpy reference {b:5.2f} ms, x{b / a:.1f})")
    from scipy.optimize import least_squares

    model = cfg.cameras.narrow.to_model("narrow")
    cam = camera_pose_ned(model, (0.0, 0.0, -2.0), (1.0, 0.0, 0.0, 0.0))
    truth = np.array([3.2, 0.1, -cfg.target.height_m, 20.0])
    R_ct, t_ct = corr.target_pose_in_camera(cam, truth[:3], truth[3])
    t = cfg.target
    obs = corr.project_box_mbr(model, R_ct, t_ct, t.length_m, t.width_m, t.height_m)
    res = corr._region_residual(model, corr.box_corners(t.length_m, t.width_m, t.height_m),
                                np.ascontiguousarray(cam.R.T), np.ascontiguousarray(cam.t),
                                obs + rng.normal(0, 0.3, obs.shape))
    x0 = truth + (0.1, -0.1, 0.0, 8.0)
    a = cpu_ms(lambda: corr._lm_fit(res, res.jac, x0, 40, xtol=1e-7, ftol=1e-6), 50)
    b = cpu_ms(lambda: least_squares(res, x0, jac=res.jac, method="lm", diff_step=1e-6,
                                     xtol=1e-7, ftol=1e-6, max_nfev=40), 50)
    print(f"box-fit LM call: {a:5.2f} ms (least_squares {b:5.2f} ms, x{b / a:.1f}); "
          "a fine estimate makes ~20 of them")
    # RPnP's pose refinement (4 corner shifts per fine estimate)
    Xo = corr.top_face_model(t.length_m, t.width_m)
    Xc = Xo @ R_ct.T + t_ct
    uv = Xc[:, :2] / Xc[:, 2:] + rng.normal(0, 1e-3, (4, 2))
    R0, t0 = cv2.Rodrigues(np.array([0.02, -0.01, 0.03]))[0] @ R_ct, t_ct + 0.02
    a = cpu_ms(lambda: refine_pose(R0, t0, Xo, uv), 50)
    b = cpu_ms(lambda: refine_pose(R0, t0, Xo, uv, backend="numpy"), 50)
    same = np.allclose(refine_pose(R0, t0, Xo, uv)[1], refine_pose(R0, t0, Xo, uv,
                                                                   backend="numpy")[1], atol=1e-9)
    print(f"RPnP refine_pose (numba): {a:5.3f} ms (numpy reference {b:5.3f} ms, x{b / a:.1f}; "
          f"same pose {same})")
    plane_fit_and_colour(cfg, fast)
    cv2.setNumThreads(-1)


def plane_fit_and_colour(cfg: MissionFile, world: Any) -> None:
    """The runner's top-plane fit and close-range colour region at the stand-off (narrow
    camera) and near the grasp pose (wide camera), against their references."""
    poses = mission_poses(cfg)
    for cam_id, pose in (("narrow", poses[1]), ("wide", poses[2])):
        fit_and_colour_at(cfg, world, getattr(cfg.cameras, cam_id).to_model(cam_id), *pose)


def fit_and_colour_at(cfg: MissionFile, world: Any, model: Any, name: str, pos: Any,
                      q: Any) -> None:
    img, truth = world.render(model, pos, q, 2_000_000_000)
    poly = np.asarray(truth.target_polygon_px, dtype=np.float32)
    rect = cv2.minAreaRect(poly)
    args = (model, camera_pose_ned(model, pos, q), np.asarray(rect[0]),
            cv2.boxPoints(rect).astype(np.float64), cfg.target)
    a = cpu_ms(lambda: sil.fit_on_top_plane(*args, iterations=4))
    b = cpu_ms(lambda: sil.fit_on_top_plane_reference(*args, iterations=4))
    same = (sil.fit_on_top_plane(*args, iterations=4)
            == sil.fit_on_top_plane_reference(*args, iterations=4))
    cam_id = model.camera_id
    print(f"top-plane fit {cam_id:6s} {name:8s}: {a:5.2f} ms (one hypothesis at a time "
          f"{b:5.2f} ms, x{b / a:.1f}; identical {same})")
    near, colour = poly.mean(axis=0), cfg.target.color_bgr
    a = cpu_ms(lambda: sil.colour_blob(img, colour, 0.25, near))
    b = cpu_ms(lambda: sil.colour_blob(img, colour, 0.25, near, backend="numpy"))
    print(f"colour region {cam_id:6s} {name:8s}: {a:5.2f} ms (numpy mask {b:5.2f} ms, "
          f"x{b / a:.1f})")


def instrumented_flight(cfg: MissionFile) -> None:
    wall: dict[str, float] = collections.defaultdict(float)
    cpu: dict[str, float] = collections.defaultdict(float)
    count: collections.Counter[str] = collections.Counter()
    restore: list[tuple[Any, str, Any]] = []

    def wrap(owner: Any, attr: str, key: str) -> None:
        fn = getattr(owner, attr)
        restore.append((owner, attr, fn))

        def timed(*a: Any, **k: Any) -> Any:
            t, c = time.perf_counter(), time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                wall[key] += time.perf_counter() - t
                cpu[key] += time.thread_time() - c
                count[key] += 1

        setattr(owner, attr, timed)

    wrap(world_mod.SyntheticWorld, "render", "render")
    wrap(det_base.SaliencyDetector, "detect", "detect")
    orig_rb = runner_mod._run_blocking

    async def rb(fn: Callable[..., Any], *args: Any) -> Any:
        if getattr(fn, "__name__", "") != "work":
            return await orig_rb(fn, *args)

        def work(*a: Any) -> Any:
            t, c = time.perf_counter(), time.thread_time()
            try:
                return fn(*a)
            finally:
                wall["perception"] += time.perf_counter() - t
                cpu["perception"] += time.thread_time() - c
                count["perception"] += 1

        return await orig_rb(work, *args)

    runner_mod._run_blocking = rb
    orig_run = runner_mod.MissionRunner.run

    async def run(self: Any) -> Any:
        c = time.thread_time()
        try:
            return await orig_run(self)
        finally:
            cpu["event loop (main thread)"] += time.thread_time() - c

    runner_mod.MissionRunner.run = run
    try:
        p0 = time.process_time()
        out = run_simulation(cfg)
        proc = time.process_time() - p0
    finally:
        runner_mod._run_blocking = orig_rb
        runner_mod.MissionRunner.run = orig_run
        for owner, attr, fn in restore:
            setattr(owner, attr, fn)
    r, ev = out.result, out.evaluation
    print(f"flight: {r.final_state}; simulated {out.sim_s:.1f} s in {out.wall_s:.2f} s wall -> "
          f"{out.speedup:.1f}x real time (target >= 10x); process CPU {proc:.2f} s "
          f"({out.sim_s / proc:.1f}x sim/CPU); frames {r.frames_processed}; success {ev.success}")
    if r.latencies_ms:
        lat = np.asarray(r.latencies_ms)
        print(f"  frame-to-setpoint latency p50 {np.percentile(lat, 50):.1f} ms, p90 "
              f"{np.percentile(lat, 90):.1f} ms (target <= 18.5 ms) over {len(lat)} setpoints")
    rest_w = wall["perception"] - wall["detect"]
    rest_c = cpu["perception"] - cpu["detect"]
    rows = [("render (camera grabs)", wall["render"], cpu["render"], count["render"]),
            ("detect", wall["detect"], cpu["detect"], count["detect"]),
            ("selection + estimation", rest_w, rest_c, count["perception"]),
            ("event loop (main thread)", math_nan(), cpu["event loop (main thread)"], 1)]
    for name, w, c, n in rows:
        ws = "      " if np.isnan(w) else f"{w:5.2f} s"
        print(f"  {name:26s} wall {ws}  thread CPU {c:5.2f} s  ({1e3 * c / max(n, 1):5.1f} ms "
              f"CPU each, n={n})")


def math_nan() -> float:
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--detector")
    ap.add_argument("--downscale", type=int)
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--skip-components", action="store_true")
    ap.add_argument("--skip-flight", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    cfg = load_config(args.config)
    data = cfg.model_dump()
    if args.detector:
        data["detector"] = {"type": args.detector, "params": {}}
    if args.downscale:
        data["detector"]["params"] = {**data["detector"]["params"], "downscale": args.downscale}
    cfg = MissionFile.model_validate(data)
    if not args.skip_components:
        components(cfg)
    if not args.skip_flight:
        for i in range(args.runs):
            print(f"== flight {i + 1}/{args.runs}: detector {cfg.detector.type}, downscale "
                  f"{args.downscale or 'mission default'} ({load()})")
            instrumented_flight(cfg)


if __name__ == "__main__":
    main()
