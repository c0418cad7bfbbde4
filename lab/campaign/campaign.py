"""Randomised simulation campaign: ``eaglemission campaign CONFIG --runs 50 --seed S``.

Each run draws, from ``np.random.RandomState(seed + run)``: target position (along the route,
+-3 m across it) and heading, ground texture, 0-2 distractors, lighting gain, wind (0-3 m/s, any
direction), camera mount error (up to 2 deg, drawn by the world per camera), focal error (up
to 3%), camera-to-telemetry offset (0-40 ms) and the world seed; then, from an RNG of that
seed, the imaging effects (motion blur and BayerRG demosaicing on, a white-balance error, JPEG
in half the runs; ``--no-imaging-effects`` leaves them as the mission file has them). Runs are
independent processes
(``--workers``, default 2) of a local pool or Ray tasks (``--executor ray``,
:mod:`~eaglemission.lab.campaign.executors`); the evaluator judges every run against the
truth. ``--out DIR`` keeps each finished run there and resumes from it.
"""

from __future__ import annotations

import json
import math
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from eaglemission.lab.campaign.emulator import VEHICLES
from eaglemission.lab.campaign.executors import Executor, make_executor
from eaglemission.lab.campaign.faults import judge, with_drawn_fault
from eaglemission.lab.campaign.resume import RunStore
from eaglemission.lab.evaluation.evaluator import GRASPED_WITHIN_M
from eaglemission.lab.faults.config import faults_of

from eaglemission.config import MissionFile, load_config
from eaglemission.config.models import validate_mapping
from eaglemission.flight.assembly import build_world


def randomise(cfg: MissionFile, rng: np.random.RandomState,
              ground_images: list[Path] | None = None, *,
              imaging_effects: bool = True) -> MissionFile:
    """A copy of ``cfg`` with a randomised simulated world (pure given the RNG state): the
    world plugin draws the variant (``World.randomised_params``). With ``ground_images`` the
    run's ground is one of them, drawn (with its offset from home) from an RNG of the drawn
    world seed, so the other draws stay those of a campaign without photos.
    ``imaging_effects=False`` keeps ``cfg``'s values of the keys the world lists in
    ``imaging_keys`` (the synthetic world: white balance, motion blur, Bayer, JPEG): the
    worlds of the campaigns flown before those effects were drawn."""
    world = build_world(cfg)
    if world is None or cfg.world is None:
        raise ValueError("world: the campaign needs a simulated world (`world:` section)")
    route = [(w.north_m, w.east_m) for w in cfg.mission.route]
    params = world.randomised_params(rng, route)
    if not imaging_effects:
        base = world.config.model_dump()
        params.update({k: base[k] for k in getattr(world, "imaging_keys", ()) if k in base})
    if ground_images:
        g = np.random.RandomState(int(params.get("seed", 0)) ^ 0x9E3779B9)
        image = ground_images[int(g.randint(0, len(ground_images)))]
        params["ground_image"] = {"path": str(image.resolve()),
                                  "offset_ne_m": (float(g.uniform(-30, 30)),
                                                  float(g.uniform(-30, 30)))}
    return MissionFile.model_validate(
        {**cfg.model_dump(), "world": {"type": cfg.world.type, "params": params}})


def with_manipulator(cfg: MissionFile, kind: str) -> MissionFile:
    """``cfg`` flown with the manipulator ``kind`` (its params kept when it is already that
    type, else the plugin's defaults); the world's draws do not depend on it."""
    params = dict(cfg.manipulator.params) if cfg.manipulator.type == kind else {}
    data = {**cfg.model_dump(), "manipulator": {"type": kind, "params": params}}
    return validate_mapping(data, source=f"--manipulator {kind}")


def crash_explanation(exc: BaseException) -> str:
    """``Type: message (file:line in function)`` of each innermost exception of ``exc``: an
    ExceptionGroup from a TaskGroup names its sub-exceptions, not just their count."""
    if isinstance(exc, BaseExceptionGroup):
        return "; ".join(crash_explanation(e) for e in exc.exceptions)
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" ({Path(frames[-1].filename).name}:{frames[-1].lineno} in {frames[-1].name})" \
        if frames else ""
    return f"{type(exc).__name__}: {exc}{where}"


def _one_run(job: tuple[Any, ...]) -> dict[str, Any]:
    index, cfg_dict, out_dir = job[:3]
    vehicle = job[3] if len(job) > 3 else "simulated"
    import logging

    logging.disable(logging.WARNING)
    from eaglemission.lab.campaign.emulator import fly_on_emulator
    from eaglemission.lab.campaign.sim import run_simulation

    cfg = MissionFile.model_validate(cfg_dict)
    log_path = None if out_dir is None else Path(out_dir) / f"run_{index:03d}.jsonl"
    faults = faults_of(cfg)
    faulted = faults is not None and bool(faults.inject)
    try:
        out = (fly_on_emulator(cfg, log_path=log_path, keep_log=faulted)
               if vehicle == "emulator" else
               run_simulation(cfg, log_path=log_path, keep_log=faulted))
    except Exception as exc:  # a crashed run is a failure with its reason, not a lost campaign
        return {"run": index, "crashed": True, "success": False,
                "explanation": f"crashed: {crash_explanation(exc)}",
                "traceback": "".join(traceback.format_exception(exc)),
                "fault": faults.inject[0].kind if faulted and faults else None,
                "sim": cfg.world.params if cfg.world else None}
    ev = out.evaluation
    return {"run": index, "crashed": False, "success": ev.success,
            "reached_grasp_ready": ev.reached_grasp_ready, "final_state": ev.final_state,
            "reason": ev.reason, "action": ev.action, "ended_safe": ev.ended_safe,
            "landed": ev.landed, "time_to_grasp_ready_s": ev.time_to_grasp_ready_s,
            "horizontal_error_m": ev.horizontal_error_m, "grasp_distance_m": ev.grasp_distance_m,
            "gripper_closed": ev.gripper_closed, "grasped": ev.grasped,
            "grasp_error_m": ev.grasp_error_m,
            "grasp_error_horizontal_m": ev.grasp_error_horizontal_m,
            "vehicle_error_m": ev.vehicle_error_m,
            "violations": [v.__dict__ for v in ev.violations], "explanation": ev.explanation,
            "speedup": out.speedup, "latency_p90_ms": out.result.latency_p90_ms,
            "sim": cfg.world.params if cfg.world else None,
            **(judge(out) if faulted else {})}


@dataclass
class CampaignSummary:
    runs: list[dict[str, Any]] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.runs)

    @property
    def success_rate(self) -> float:
        return sum(r["success"] for r in self.runs) / self.n if self.n else math.nan

    @property
    def grasped(self) -> int:
        """Runs whose gripper closed with the true tool within 2.5 cm of the grasp point."""
        return sum(bool(r.get("grasped")) for r in self.runs)

    @property
    def violations(self) -> int:
        return sum(len(r.get("violations", [])) for r in self.runs)

    def values(self, key: str) -> list[float]:
        return [float(r[key]) for r in self.runs if r.get(key) is not None]

    def as_dict(self) -> dict[str, Any]:
        return {"n": self.n, "success_rate": self.success_rate, "grasped": self.grasped,
                "violations": self.violations, "runs": self.runs}


def run_campaign(config: str | None, *, runs: int, seed: int, workers: int = 2,
                 out_dir: str | None = None, progress: bool = False,
                 executor: str | Executor = "local",
                 address: str | None = None,
                 faults: list[str] | None = None,
                 ground_images: list[Path] | None = None,
                 vehicle: str = "simulated",
                 only_faults: set[str] | None = None,
                 imaging_effects: bool = True,
                 manipulator: str | None = None) -> CampaignSummary:
    """Fly ``runs`` randomised runs on ``executor`` (``local``, ``ray`` or an
    :class:`~eaglemission.lab.campaign.executors.Executor`); with ``out_dir`` each finished
    run is stored there and a rerun flies only the missing ones
    (:mod:`eaglemission.lab.campaign.resume`). ``faults``: fault kinds, one drawn per run
    (:mod:`.campaign_faults`). ``ground_images``: each run's ground is one of these photos.
    ``vehicle``: ``simulated`` (virtual time) or ``emulator`` (real time through MAVSDK,
    :mod:`.campaign_emulator`). ``only_faults``: fly only the runs whose drawn fault is one of
    these (the same draws: the runs a change to those faults' path can alter).
    ``imaging_effects=False``: the worlds without the drawn imaging effects (:func:`randomise`).
    ``manipulator``: fly every run with this manipulator type (:func:`with_manipulator`)."""
    if vehicle not in VEHICLES:
        raise ValueError(f"vehicle: {vehicle!r} is not one of {', '.join(VEHICLES)}")
    base = load_config(config)
    if manipulator is not None:
        base = with_manipulator(base, manipulator)
    rng = np.random.RandomState(seed)
    jobs = []
    for i in range(runs):
        cfg = randomise(base, np.random.RandomState(int(rng.randint(0, 2**31 - 1))),
                        ground_images, imaging_effects=imaging_effects)
        if faults:
            cfg = with_drawn_fault(cfg, i, faults, seed)
        if only_faults is not None and not (
                (drawn := faults_of(cfg)) is not None
                and {f.kind for f in drawn.inject} & only_faults):
            continue
        jobs.append((i, cfg.model_dump(mode="json"), out_dir, vehicle))
    total = len(jobs)
    ex = make_executor(executor, workers=workers, address=address) \
        if isinstance(executor, str) else executor
    store = None if out_dir is None else \
        RunStore.open(out_dir, seed=seed, base_cfg={  # another vehicle: another campaign
            **base.model_dump(mode="json"),
            **({"campaign_vehicle": vehicle} if vehicle != "simulated" else {})})
    results: list[dict[str, Any]] = []
    if store is not None:
        stored = {j[0]: store.finished(j[0], j[1]) for j in jobs}
        results = [r for r in stored.values() if r is not None]
        jobs = [j for j in jobs if stored[j[0]] is None]
    cfg_of = {j[0]: j[1] for j in jobs}
    summary = CampaignSummary()
    bar = None
    if progress:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

        bar = Progress("[progress.description]{task.description}", BarColumn(),
                       MofNCompleteColumn(), TimeElapsedColumn())

    def flown() -> Iterator[dict[str, Any]]:
        for r in ex.map_unordered(_one_run, jobs):
            if store is not None:
                store.save(r["run"], cfg_of[r["run"]], r)
            yield r

    if bar is not None:
        with bar:
            task = bar.add_task(f"campaign ({ex.name})", total=total, completed=len(results))
            for r in flown():
                results.append(r)
                ok = sum(x["success"] for x in results)
                bar.update(task, advance=1, description=f"campaign ({ex.name}, {ok} ok)")
    else:
        results.extend(flown())
    summary.runs = sorted(results, key=lambda r: r["run"])
    if out_dir is not None:
        (Path(out_dir) / "summary.json").write_text(json.dumps(summary.as_dict(), indent=1,
                                                               default=str))
    return summary


def print_summary(summary: CampaignSummary) -> None:
    from rich.table import Table

    from eaglemission.commands import console

    c = console()
    c.print(f"[bold]runs[/bold]: {summary.n}   [bold]success[/bold]: "
            f"{summary.success_rate:.0%}   [bold]envelope violations[/bold]: {summary.violations}")
    closed = sum(bool(r.get("gripper_closed")) for r in summary.runs)
    c.print(f"[bold]grasped[/bold] (gripper closed, true tool within "
            f"{GRASPED_WITHIN_M * 100:g} cm of the grasp point): {summary.grasped}/{summary.n}"
            f"   gripper closed: {closed}/{summary.n}")
    t = Table(title="distribution over runs that reached GRASP_READY")
    for col in ("quantity", "min", "median", "p90", "max"):
        t.add_column(col)
    for key, label, k in (("time_to_grasp_ready_s", "time to GRASP_READY (s)", 1.0),
                          ("horizontal_error_m", "tool-point horizontal error (cm)", 100.0),
                          ("grasp_distance_m", "grasp distance (m)", 1.0),
                          ("grasp_error_m", "tool-to-target at the grasp (cm)", 100.0),
                          ("vehicle_error_m", "vehicle's own error at the grasp (cm)", 100.0),
                          ("speedup", "speed-up (x real time)", 1.0),
                          ("latency_p90_ms", "latency p90 (ms)", 1.0)):
        v = np.asarray(summary.values(key)) * k
        v = v[np.isfinite(v)]
        if len(v):
            t.add_row(label, *(f"{x:.3g}" for x in (v.min(), np.median(v),
                                                   np.percentile(v, 90), v.max())))
    c.print(t)
    fails = [r for r in summary.runs if not r["success"]]
    for r in fails:
        c.print(f"  run {r['run']}: {r.get('final_state', '?')} -- {r['explanation']} "
                f"(ended safe: {r.get('ended_safe')})", markup=False)
