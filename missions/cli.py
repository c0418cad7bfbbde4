"""``eaglemission run`` and ``eaglemission campaign``.

``run [CONFIG]`` flies the approach mission in closed-loop simulation (simulated vehicle +
synthetic dual camera + the configured detector and estimators) on the virtual-time loop, faster
than real time, and prints the state changes, the time and the evaluator's final errors.
Without CONFIG it flies the embedded ``configs/sitl_synthetic.yaml``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from eaglemission.commands import Command


def _add_run(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="mission YAML (default: embedded sitl_synthetic.yaml)")
    p.add_argument("--vehicle", choices=("simulated", "emulator"), default="simulated",
                   help="simulated: in-process vehicle, virtual time (default); emulator: the "
                        "MAVSDK driver against the MAVLink emulator, real time")
    p.add_argument("--plot", metavar="PNG", help="draw trajectory, target and state changes")
    p.add_argument("--record", metavar="DIR", help="record both camera streams + telemetry "
                                                   "(replay format)")
    p.add_argument("--log", metavar="FILE", help="JSON-lines mission log (default: none)")
    p.add_argument("--realtime", action="store_true", help="run at wall-clock speed")
    p.add_argument("--detector", metavar="NAME",
                   help="fly with this detector plugin instead of the config's (e.g. mss)")


def _print_outcome(console: Any, out: Any) -> None:
    r, ev = out.result, out.evaluation
    console.print(f"[bold]final state[/bold]: {r.final_state} ({r.reason}; action {r.action})")
    console.print(f"simulated {out.sim_s:.1f} s in {out.wall_s:.1f} s wall "
                  f"([bold]{out.speedup:.1f}x[/bold] real time)")
    if r.t_grasp_ready_s is not None:
        console.print(f"GRASP_READY at t = {r.t_grasp_ready_s:.2f} s")
    if ev.horizontal_error_m is not None:
        console.print(f"true tool-point error: horizontal {ev.horizontal_error_m * 100:.1f} cm, "
                      f"grasp distance {ev.grasp_distance_m:.3f} m")
    if r.estimated_tool_errors_m is not None:
        h, d = r.estimated_tool_errors_m
        console.print(f"mission's own estimate: horizontal {h * 100:.1f} cm, grasp distance "
                      f"{d:.3f} m")
    if r.latencies_ms:
        console.print(f"frame-to-setpoint latency p50/p90: {out.result.latencies_ms and _pct(r.latencies_ms, 50):.1f}"
                      f" / {_pct(r.latencies_ms, 90):.1f} ms (wall clock, {len(r.latencies_ms)} samples)")
    if r.failsafe_params is not None:
        console.print("autopilot failsafe parameters: " + ", ".join(
            f"{k}={v:g}" for k, v in r.failsafe_params.items()))
    for w in r.failsafe_warnings:
        console.print(f"  [yellow]warning[/yellow]: {w}")
    console.print(f"frames processed: {r.frames_processed}, with a detection: {r.detections}")
    console.print(f"envelope violations: {len(ev.violations)}"
                  + "".join(f"\n  {v.kind} at {v.t_s:.1f} s: {v.value:.2f} > {v.limit:.2f} "
                            f"for {v.duration_s:.1f} s" for v in ev.violations))
    console.print(f"evaluator: {'[green]SUCCESS[/green]' if ev.success else '[red]FAILURE[/red]'}"
                  + (f" -- {ev.explanation}" if ev.explanation else ""))


def _pct(v: list[float], q: float) -> float:
    import numpy as np

    return float(np.percentile(v, q))


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from eaglemission.config import load_config

    console = Console()
    cfg = load_config(args.config)
    if args.detector:
        from eaglemission.config import MissionFile

        cfg = MissionFile.model_validate({**cfg.model_dump(),
                                          "detector": {"type": args.detector, "params": {}}})
    source = args.config or "<embedded sitl_synthetic.yaml>"
    console.print(f"[bold]eaglemission run[/bold] {source} (vehicle: {args.vehicle}, "
                  f"{'real time' if args.realtime or args.vehicle == 'emulator' else 'virtual time'})")

    def on_state(t_s: float, state: str, reason: str, action: str) -> None:
        extra = f" -> {action}" if action else ""
        console.print(f"  {t_s:7.2f} s  {state:<16} ({reason}{extra})")

    if args.vehicle == "emulator":
        from eaglemission.missions.emulated import run_emulated

        out = run_emulated(cfg, log_path=args.log, record_dir=args.record, on_state=on_state)
    else:
        from eaglemission.missions.sim import run_simulation

        out = run_simulation(cfg, realtime=args.realtime, log_path=args.log,
                             record_dir=args.record, on_state=on_state)
    _print_outcome(console, out)
    if args.plot:
        from eaglemission.missions.plot import plot_outcome

        plot_outcome(out, cfg, Path(args.plot))
        console.print(f"plot written to {args.plot}")
    if args.log:
        console.print(f"log written to {args.log}")
    return 0 if out.evaluation.success or out.result.final_state in ("DONE", "FAILSAFE") else 1


def _add_campaign(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="mission YAML (default: embedded sitl_synthetic.yaml)")
    p.add_argument("--runs", type=int, default=50, help="number of randomised runs")
    p.add_argument("--seed", type=int, default=0, help="campaign seed")
    p.add_argument("--workers", type=int, default=2, help="parallel processes")
    p.add_argument("--out", metavar="DIR", help="write one log per run and summary.json here")


def _campaign(args: argparse.Namespace) -> int:
    from eaglemission.missions.campaign import print_summary, run_campaign

    if args.runs < 1:
        print("error: --runs must be >= 1", file=sys.stderr)
        return 2
    summary = run_campaign(args.config, runs=args.runs, seed=args.seed, workers=args.workers,
                           out_dir=args.out, progress=True)
    print_summary(summary)
    return 0


RUN_COMMAND = Command("fly the approach-to-grasp mission in closed-loop simulation",
                      _add_run, _run)
CAMPAIGN_COMMAND = Command("randomised simulation campaign with the evaluator's statistics",
                           _add_campaign, _campaign)
