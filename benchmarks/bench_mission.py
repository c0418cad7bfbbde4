"""Mission figures, printed (never asserted): speed-up over real time, time to
GRASP_READY, true tool-point errors, frame-to-setpoint latency, and the detection rate of the
static target with the mission defaults (cruise, deceleration, 5 s hover) plus false
detections per frame on a target-free flight.

    python benchmarks/bench_mission.py [CONFIG] [--detector NAME] [--downscale K] [--skip-flight]

The detection part flies a scripted kinematic path (no controller) and runs the mission's own
detection selection (`perception.select_detection` + `plausible_size`) on the wide camera at the
mission's processing rate; the truth comes from the synthetic world's side channel.
"""

from __future__ import annotations

import argparse
import logging
import time

import cv2
import numpy as np
from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.lab.vehicles.multicopter.dynamics import attitude_from_acceleration
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import world_config
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.perception import plausible_size, select_detection

from eaglemission import registry
from eaglemission.config import MissionFile, load_config
from eaglemission.flight.assembly import detector_params
from eaglemission.types import Frame, VehicleState


def _with_detector(cfg: MissionFile, name: str | None, downscale: int | None) -> MissionFile:
    data = cfg.model_dump()
    if name:
        data["detector"] = {"type": name, "params": {}}
    if downscale:
        data["detector"]["params"] = {**data["detector"]["params"], "downscale": downscale}
    return MissionFile.model_validate(data)


def scripted_path(cfg: MissionFile, rate_hz: float, *, hover_s: float = 5.0):
    """(t_s, position, attitude) along: cruise north at cruise speed, brake to a stop 10 m short
    of the target (deceleration tilts the body), hover."""
    sim = world_config(cfg)
    v0 = cfg.mission.cruise_speed_mps
    decel = 2.0
    stop_n = sim.target_north_m - 10.0
    brake_n = stop_n - v0 * v0 / (2 * decel)
    alt = cfg.mission.cruise_altitude_m
    e = sim.target_east_m * 0.3
    dt = 1.0 / rate_hz
    t, n, v = 0.0, max(0.0, brake_n - 15.0), v0
    phase_of = []
    while True:
        if n < brake_n:
            a = 0.0
            phase = "cruise"
        elif v > 0:
            a = -decel
            phase = "deceleration"
        else:
            a = 0.0
            phase = "hover"
        q = attitude_from_acceleration((a, 0.0, 0.0), 0.0)
        phase_of.append((t, (n, e, -alt), q, phase))
        if phase == "hover" and phase_of[-1][0] - min(p[0] for p in phase_of if p[3] == "hover") >= hover_s:
            break
        v = max(0.0, v + a * dt)
        n += v * dt
        t += dt
    return phase_of


def detection_rate(cfg: MissionFile, *, target_free: bool = False) -> dict[str, tuple[int, int, int]]:
    params = ApproachConfig.of(cfg).perception
    sim = world_config(cfg)
    if target_free:
        sim = sim.model_copy(update={"target_north_m": -30.0, "target_east_m": 0.0})
    world = SyntheticWorld(sim, cfg.target, extent_m=200)
    model = cfg.cameras.wide.to_model("wide")
    det = registry.load("detectors", cfg.detector.type, detector_params(cfg, "wide"),
                        camera_id="wide")
    stats: dict[str, list[int]] = {}
    t0 = 1_000_000_000
    for t_s, pos, q, phase in scripted_path(cfg, params.process_rate_hz):
        ts = t0 + int(t_s * 1e9)
        img, truth = world.render(model, pos, q, ts)
        frame = Frame(img, ts, "wide", len(stats))
        res = det.detect(frame)
        state = VehicleState(ts, pos, (0.0, 0.0, 0.0), q)
        chosen = select_detection(res, None, model.width_px, model.height_px,
                                  params.image_border_px, 1e9,
                                  lambda d, st=state: plausible_size(
                                      d, model, st, cfg.target, *params.size_ratio_range))
        s = stats.setdefault(phase, [0, 0, 0])  # frames in view, hits, false
        in_view = truth.target_visible and truth.top_face_visible and not target_free
        hit = False
        if chosen is not None and truth.target_visible:
            mask = np.zeros(img.shape[:2], np.uint8)
            cv2.fillPoly(mask, [np.round(truth.target_polygon_px).astype(np.int32)], 1)
            mask = cv2.dilate(mask, np.ones((9, 9), np.uint8))
            u, v = (int(round(c)) for c in chosen.center_px)
            hit = 0 <= v < mask.shape[0] and 0 <= u < mask.shape[1] and bool(mask[v, u])
        if in_view:
            s[0] += 1
            s[1] += hit
        if chosen is not None and not hit:
            s[2] += 1
    return {k: (v[0], v[1], v[2]) for k, v in stats.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?")
    ap.add_argument("--detector")
    ap.add_argument("--downscale", type=int)
    ap.add_argument("--skip-flight", action="store_true")
    ap.add_argument("--skip-detection", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    cfg = _with_detector(load_config(args.config), args.detector, args.downscale)
    params = ApproachConfig.of(cfg).perception
    print(f"detector: {cfg.detector.type} {dict(cfg.detector.params)}, "
          f"process rate {params.process_rate_hz} Hz, frames "
          f"{cfg.cameras.wide.resolution_px[0]}x{cfg.cameras.wide.resolution_px[1]}")
    if not args.skip_flight:
        t = time.perf_counter()
        out = run_simulation(cfg)
        r, ev = out.result, out.evaluation
        print(f"flight: {r.final_state} ({r.reason}); simulated {out.sim_s:.1f} s in "
              f"{out.wall_s:.1f} s wall -> {out.speedup:.1f}x real time")
        print(f"  GRASP_READY at {r.t_grasp_ready_s} s; true tool-point error horizontal "
              f"{ev.horizontal_error_m}, grasp distance {ev.grasp_distance_m}; success {ev.success}")
        if r.latencies_ms:
            lat = np.asarray(r.latencies_ms)
            print(f"  frame-to-setpoint latency (wall): p50 {np.percentile(lat, 50):.1f} ms, "
                  f"p90 {np.percentile(lat, 90):.1f} ms over {len(lat)} setpoints")
        pm = np.asarray(r.perception_ms)
        if len(pm):
            print(f"  perception per frame: median {np.median(pm):.1f} ms, p90 "
                  f"{np.percentile(pm, 90):.1f} ms; frames {r.frames_processed}")
        print(f"  envelope violations: {len(ev.violations)}  ({time.perf_counter() - t:.1f} s)")
    if not args.skip_detection:
        for free in (False, True):
            st = detection_rate(cfg, target_free=free)
            label = "target-free" if free else "static target"
            for phase, (n_in, hits, false) in st.items():
                rate = f"{hits}/{n_in} = {hits / n_in:.0%} detected" if n_in else "not in view"
                print(f"detection ({label}) {phase:<13}: {rate}; false detections {false}")
            total_false = sum(v[2] for v in st.values())
            if free:
                n = sum(1 for _ in scripted_path(cfg, params.process_rate_hz))
                print(f"  target-free: {total_false} false detections in {n} frames = "
                      f"{total_false / n:.3f} per frame")


if __name__ == "__main__":
    main()
