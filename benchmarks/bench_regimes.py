"""DTDMI in the mission's two regimes: a static ground target seen by a moving, then hovering UAV.

The synthetic world (``eaglemission.lab.world.render``) renders the wide camera of
configs/sitl_synthetic.yaml along a straight flight north at 5 m: cruise at 3 m/s, a
deceleration to 0 over 2 s (nose up by atan(a/g)), then a hover of ``--hover-s`` seconds with
small hover motion (+-2 cm, +-0.3 deg at 0.7 Hz). Every pose is rendered twice: with the target
and in the same world with the target moved behind the camera (target-free frames).

Per phase and detector configuration it prints

- ``det rate``: fraction of target-visible frames whose best detection's centre lies on the
  target (within ``--margin-px`` of its projected outline);
- ``any``: fraction of target-visible frames with any detection on the target;
- ``FP/frame``: detections per target-free frame (any detection there is false);
- ``peak ratio``: median over target-visible frames of (max of the map on the target, dilated
  by ``--margin-px``) / (max elsewhere): > 1 means the target is the most salient thing.

Usage::

    python benchmarks/bench_regimes.py [--resolution 640x480] [--hover-s 5] [--configs ...]
        [--textures vegetation soil snow grass] [--camera wide|narrow] [--alt-m 5]
        [--target-north-m 22] [--target-east-m 1.5] [--per-texture] [--light-gain 1]
        [--target-image colour]

Rows are summed over the ground textures (``--per-texture`` also prints each one). The narrow
camera (12 mm) sees the ground 6-13 m ahead from 5 m; use it closer in, e.g. ``--camera narrow
--alt-m 3 --target-north-m 17.5 --target-east-m 0.3`` (hover 5.5 m short of the target, which is
in view from the end of the cruise through the hover).

Each ``--configs`` entry is a JSON object of DTDMIConfig overrides (``{"detector": "midbrain"}``
picks another plugin). Regions use each config's defaults and no target prior.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from eaglemission.lab.world.render import SyntheticWorld
from eaglemission.lab.world.synthetic import SyntheticWorldConfig

from eaglemission import registry
from eaglemission.config import TargetConfig
from eaglemission.geometry import CameraModel, CameraMount, euler_to_quat
from eaglemission.types import Frame

FPS = 30.0
ALT_M = 5.0
CRUISE_MPS = 3.0
CRUISE_S = 3.0
DECEL_S = 2.0
G = 9.81

DEFAULT_CONFIGS = [
    '{"preset": "field"}',
    '{"preset": "field", "use_dynamic": false}',
    '{"preset": "aerial"}',
    '{"preset": "default", "centre_sigma_frac": 0}',
    '{"detector": "ft"}',
    '{"detector": "mss"}',
]
LENSES = {"wide": (2.8, (0.10, -0.03, 0.05)), "narrow": (12.0, (0.10, 0.03, 0.05))}


def trajectory(hover_s: float, alt_m: float = ALT_M):
    """Yield (phase, t_s, position_ned_m, attitude_q) at FPS."""
    n = int(round((CRUISE_S + DECEL_S + hover_s) * FPS))
    a = CRUISE_MPS / DECEL_S
    for i in range(n):
        t = i / FPS
        if t < CRUISE_S:
            phase, north, pitch, roll = "cruise", CRUISE_MPS * t, 0.0, 0.0
        elif t < CRUISE_S + DECEL_S:
            u = t - CRUISE_S
            phase = "decel"
            north = CRUISE_MPS * CRUISE_S + CRUISE_MPS * u - 0.5 * a * u * u
            pitch, roll = math.degrees(math.atan(a / G)), 0.0
        else:
            u = t - CRUISE_S - DECEL_S
            phase = "hover"
            north = CRUISE_MPS * CRUISE_S + 0.5 * CRUISE_MPS * DECEL_S
            north += 0.02 * math.sin(2 * math.pi * 0.7 * u)
            pitch = 0.3 * math.sin(2 * math.pi * 0.7 * u + 1.0)
            roll = 0.3 * math.sin(2 * math.pi * 0.5 * u)
        east = 0.02 * math.sin(2 * math.pi * 0.3 * t) if phase == "hover" else 0.0
        yield phase, t, (north, east, -alt_m), euler_to_quat(roll, pitch, 0.0)


@dataclass
class Tally:
    visible: int = 0
    best_hits: int = 0
    any_hits: int = 0
    free_frames: int = 0
    free_dets: int = 0
    ms: list[float] = field(default_factory=list)
    peak_ratio: list[float] = field(default_factory=list)


def on_target(center, poly, margin_px: float) -> bool:
    if poly is None or len(poly) < 3:
        return False
    d = cv2.pointPolygonTest(np.asarray(poly, np.float32).reshape(-1, 1, 2),
                             (float(center[0]), float(center[1])), True)
    return d >= -margin_px


def peak_ratio(sal, poly, margin_px: float) -> float:
    mask = np.zeros(sal.shape, np.uint8)
    cv2.fillPoly(mask, [np.round(np.asarray(poly)).astype(np.int32)], 1)
    k = 2 * int(math.ceil(margin_px)) + 1
    mask = cv2.dilate(mask, np.ones((k, k), np.uint8)) > 0
    inside = float(sal[mask].max()) if mask.any() else 0.0
    outside = float(sal[~mask].max()) if (~mask).any() else 0.0
    return inside / outside if outside > 0 else (np.inf if inside > 0 else 0.0)


def make_detector(spec: str, appearance=None):
    over = json.loads(spec)
    name = over.pop("detector", "dtdmi")
    cls = registry.get("detectors", name)
    return cls(cls.Config(**over), **({"appearance": appearance} if appearance is not None else {}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--hover-s", type=float, default=5.0)
    ap.add_argument("--margin-px", type=float, default=6.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--target-north-m", type=float, default=22.0,
                    help="the hover point is 12 m north of home")
    ap.add_argument("--target-east-m", type=float, default=1.5)
    ap.add_argument("--alt-m", type=float, default=ALT_M)
    ap.add_argument("--camera", choices=sorted(LENSES), default="wide")
    ap.add_argument("--textures", nargs="*", default=["vegetation"],
                    choices=["vegetation", "soil", "snow", "grass"])
    ap.add_argument("--per-texture", action="store_true")
    ap.add_argument("--light-gain", type=float, default=1.0, help="scene lighting gain")
    ap.add_argument("--configs", nargs="*", default=DEFAULT_CONFIGS)
    ap.add_argument("--target-image", choices=["colour"], default=None,
                    help="give the detectors a 24 x 40 px patch of the target's colour as their "
                         "example image (context `appearance`)")
    a = ap.parse_args()
    cv2.setNumThreads(1)
    w, h = (int(v) for v in a.resolution.lower().split("x"))
    focal_mm, lever = LENSES[a.camera]
    model = CameraModel.from_lens(
        a.camera, focal_length_mm=focal_mm, pixel_size_um=3.75 * 1280 / w, resolution_px=(w, h),
        mount=CameraMount(pitch_deg=-30.0, lever_arm_m=lever))
    target = TargetConfig(length_m=0.40, width_m=0.25, height_m=0.15, color_bgr=(30, 40, 210))
    phases = ("cruise", "decel", "hover")
    tallies = {(spec, ph): Tally() for spec in a.configs for ph in phases}
    per_tex = {(tex, spec, ph): Tally() for tex in a.textures for spec in a.configs
               for ph in phases}
    t_start = time.perf_counter()
    for tex in a.textures:
        sim = SyntheticWorldConfig(seed=a.seed, target_north_m=a.target_north_m,
                               target_east_m=a.target_east_m, target_yaw_deg=20.0,
                               noise_sigma=2.0, frame_rate_hz=FPS, ground_texture=tex,
                               light_gain=a.light_gain)
        world = SyntheticWorld(sim, target, seed=a.seed)
        empty = SyntheticWorld(sim.model_copy(update={"target_north_m": -30.0}), target,
                               seed=a.seed)
        app = (np.full((24, 40, 3), target.color_bgr, np.uint8)
               if a.target_image == "colour" else None)
        dets = {spec: (make_detector(spec, app), make_detector(spec, app)) for spec in a.configs}
        run_texture(a, model, world, empty, dets, tallies, per_tex, tex)
    print(f"# bench_regimes: {w}x{h} {a.camera} camera at {a.alt_m:g} m, cruise {CRUISE_S:g} s "
          f"at {CRUISE_MPS:g} m/s, decel {DECEL_S:g} s, hover {a.hover_s:g} s, {FPS:g} fps, "
          f"textures {','.join(a.textures)}, light gain {a.light_gain:g} "
          f"({time.perf_counter() - t_start:.0f} s)")
    hover_north_m = CRUISE_MPS * CRUISE_S + 0.5 * CRUISE_MPS * DECEL_S
    print(f"# target {a.target_north_m:g} m north, {a.target_east_m:g} m east of home "
          f"(hover point {hover_north_m:g} m north)")
    print_table(tallies)
    if a.per_texture:
        for tex in a.textures:
            print(f"\n## {tex}")
            print_table({(spec, ph): per_tex[(tex, spec, ph)] for spec in a.configs
                         for ph in phases})


def print_table(tallies: dict) -> None:
    print("| config | phase | visible | det rate | any | FP/frame | peak ratio | ms median |")
    print("|---|---|---|---|---|---|---|---|")
    for (spec, ph), tal in tallies.items():
        rate = tal.best_hits / tal.visible if tal.visible else float("nan")
        anyr = tal.any_hits / tal.visible if tal.visible else float("nan")
        fp = tal.free_dets / tal.free_frames if tal.free_frames else float("nan")
        pr = np.median(tal.peak_ratio) if tal.peak_ratio else float("nan")
        print(f"| `{spec}` | {ph} | {tal.visible} | {rate:.2f} | {anyr:.2f} | {fp:.2f} | "
              f"{pr:.2f} | {np.median(tal.ms):.1f} |")


def run_texture(a, model, world, empty, dets, tallies, per_tex, tex) -> None:
    """Fly the trajectory over one ground texture, tallying every detector configuration."""
    cam = model.camera_id
    for i, (phase, _t, pos, q) in enumerate(trajectory(a.hover_s, a.alt_m)):
        stamp = int(1e9 + i * 1e9 / FPS)
        img, truth = world.render(model, pos, q, stamp)
        img_free, _ = empty.render(model, pos, q, stamp)
        for spec, (det, det_free) in dets.items():
            t0 = time.perf_counter()
            res = det.detect(Frame(img, stamp, cam, i))
            ms = (time.perf_counter() - t0) * 1e3
            res_free = det_free.detect(Frame(img_free, stamp, cam, i))
            hit_best = hit_any = False
            ratio = None
            if truth.target_visible:
                hits = [on_target(d.center_px, truth.target_polygon_px, a.margin_px)
                        for d in res.detections]
                hit_best, hit_any = bool(hits) and hits[0], any(hits)
                ratio = peak_ratio(res.saliency, truth.target_polygon_px, a.margin_px)
            for tal in (tallies[(spec, phase)], per_tex[(tex, spec, phase)]):
                tal.ms.append(ms)
                tal.free_frames += 1
                tal.free_dets += len(res_free.detections)
                if truth.target_visible:
                    tal.visible += 1
                    tal.best_hits += int(hit_best)
                    tal.any_hits += int(hit_any)
                    tal.peak_ratio.append(ratio)


if __name__ == "__main__":
    main()
