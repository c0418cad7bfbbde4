"""Error budget of one campaign run's final approach (diagnostic, reads ground truth).

For every fused estimate of the fine approach it prints the estimate's error *in the vehicle's
own (drifting) estimated frame* -- estimate - (true target + vehicle estimate error at the
frame) -- which is what the mission can be judged on, next to the vehicle's estimate error
itself. Usage::

    python benchmarks/diag_grasp.py CONFIG --seed 7 --run 39 [--last 30]
"""

from __future__ import annotations

import argparse
import json
import logging

import numpy as np
from eaglemission.lab.campaign.campaign import randomise
from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.lab.world.synthetic import world_config

from eaglemission.config import load_config


def campaign_config(config: str | None, seed: int, run: int):  # type: ignore[no-untyped-def]
    base = load_config(config)
    rng = np.random.RandomState(seed)
    seeds = [int(rng.randint(0, 2**31 - 1)) for _ in range(run + 1)]
    return randomise(base, np.random.RandomState(seeds[run]))


def ablate(cfg, what):  # type: ignore[no-untyped-def]
    """A copy of ``cfg`` with the named error sources of the simulated world switched off."""
    from eaglemission.config import MissionFile

    d = cfg.model_dump(mode="json")
    sim, dyn = d["world"]["params"], d["vehicle"]["params"].setdefault("dynamics", {})
    for w in what:
        if w == "focal":
            sim["focal_error_fraction"] = 0.0
        elif w == "mount":
            sim["mount_error_deg"] = 0.0
        elif w == "drift":
            dyn["estimate_vertical_std_m"] = dyn["estimate_horizontal_std_m"] = 0.0
        elif w == "wind":
            sim["wind_ne_mps"] = [0.0, 0.0]
        elif w == "offset":
            sim["camera_time_offset_s"] = 0.0
        else:
            raise SystemExit(f"--ablate: unknown error source {w!r}")
    return MissionFile.model_validate(d)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("config", nargs="?")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--run", type=int, default=0)
    ap.add_argument("--last", type=int, default=25)
    ap.add_argument("--ablate", default="", help="comma list of error sources to switch off: "
                    "focal,mount,drift,wind,offset")
    a = ap.parse_args()
    logging.disable(logging.WARNING)
    cfg = campaign_config(a.config, a.seed, a.run) if a.run >= 0 else load_config(a.config)
    if a.ablate:
        cfg = ablate(cfg, a.ablate.split(","))
    out = run_simulation(cfg, keep_log=True)
    truth = out.trajectory
    t_true = np.array([s.timestamp_ns for s in truth], dtype=np.float64)
    p_true = np.array([s.position_ned_m for s in truth])
    t_est = np.array([t for t, _ in out.estimated_trajectory], dtype=np.float64)
    p_est = np.array([p for _, p in out.estimated_trajectory])
    tgt = np.asarray(out.target_position_ned_m)

    def veh_err(t_ns: float) -> np.ndarray:
        pe = np.array([np.interp(t_ns, t_est, p_est[:, k]) for k in range(3)])
        pt = np.array([np.interp(t_ns, t_true, p_true[:, k]) for k in range(3)])
        return pe - pt

    rows = [r for r in out.log.records if r.get("kind") in ("estimate", "state", "detection")]
    sim = world_config(cfg)
    print(json.dumps({k: sim.model_dump()[k] for k in (
        "target_yaw_deg", "ground_texture", "wind_ne_mps", "camera_time_offset_s")}))
    from eaglemission.lab.world import render as world_mod
    for cam_id in ("wide", "narrow"):
        rng_c = world_mod.seed_rng(sim.seed, "camera", cam_id)
        world_mod.random_rotation(sim.mount_error_deg, rng_c)
        e = rng_c.uniform(-sim.focal_error_fraction, sim.focal_error_fraction)
        print(f"true focal error {cam_id}: {e * 100:+.2f} %")
    print("evaluation:", out.evaluation.explanation or "SUCCESS",
          f"h {out.evaluation.horizontal_error_m or -1:.3f} d {out.evaluation.grasp_distance_m or -1:.3f}",
          "mission's own:", out.result.estimated_tool_errors_m)
    fine = []
    state = ""
    frame_t = {}
    for r in rows:
        if r["kind"] == "state":
            state = r.get("state", r.get("new", ""))
            print(f"{r['t_s']:7.2f} STATE {state}")
        elif r["kind"] == "detection":
            frame_t[r["camera"]] = r["frame_t_ns"]
        elif r.get("ok") and state in ("FINE_APPROACH", "GRASP_READY", "COARSE_APPROACH"):
            t = frame_t.get(r["camera"], r["t_ns"])
            e_v = veh_err(t)
            err = np.asarray(r["position_ned_m"]) - (tgt + e_v)
            rng_m = float(np.linalg.norm(r["position_cam_m"]))
            fine.append((r["t_s"], r["camera"], rng_m, err, e_v, r["source"]))
    for t, cam, rng_m, err, e_v, src in fine[-a.last:]:
        print(f"{t:7.2f} {cam:6s} r {rng_m:5.2f}  err N {err[0]*100:+6.1f} E {err[1]*100:+6.1f} "
              f"D {err[2]*100:+6.1f} cm  veh_err D {e_v[2]*100:+5.1f}  {src[:60]}")
    t_gr = out.result.t_grasp_ready_s
    if t_gr is not None:
        e = veh_err(out.t0_ns + t_gr * 1e9)
        print(f"vehicle estimate error at GRASP_READY: N {e[0]*100:+.1f} E {e[1]*100:+.1f} "
              f"D {e[2]*100:+.1f} cm")


if __name__ == "__main__":
    main()
