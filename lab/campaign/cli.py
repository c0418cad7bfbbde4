"""``eaglemission campaign``: randomised simulated flights of the approach mission, each through
the assembly (``eaglemission run`` is the core command :mod:`eaglemission.commands.run`)."""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType

from eaglemission.commands import Command

INTERRUPTED_EXIT = 130


def _add_campaign(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="mission YAML (default: embedded sitl_synthetic.yaml)")
    p.add_argument("--runs", type=int, default=50, help="number of randomised runs")
    p.add_argument("--seed", type=int, default=0, help="campaign seed")
    p.add_argument("--workers", type=int, default=2, help="parallel processes")
    p.add_argument("--out", metavar="DIR", help="write one log and result per run and "
                   "summary.json here; run again with the same DIR to resume")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local process pool, or Ray tasks (pip install 'eaglemission[ray]')")
    p.add_argument("--address", metavar="ADDR", help="Ray cluster to run on (--executor ray; "
                   "default: a local Ray with --workers CPUs)")
    p.add_argument("--faults", metavar="KINDS", help="inject one fault per run: 'all' or "
                   "kind1,kind2 (docs/faults.md)")
    p.add_argument("--require", metavar="FRACTION", type=float, default=None,
                   help="exit 0 when at least this fraction of the runs reach their expected "
                   "outcome (default: every run must; exit 1 otherwise)")
    p.add_argument("--ground-images", metavar="DIR", help="draw each run's ground from the "
                   "NAME.jpg|png photos of DIR, each with NAME.yaml holding m_per_px")
    p.add_argument("--vehicle", choices=("simulated", "emulator"), default="simulated",
                   help="simulated: virtual time; emulator: each run in real time through "
                   "MAVSDK against its own `sitl-vehicle` process, link faults on its UDP path")
    p.add_argument("--manipulator", metavar="TYPE", default=None,
                   help="fly every run with this manipulator instead of the file's (e.g. fixed "
                   "or simulated_arm: the same draws, another tool)")
    p.add_argument("--no-imaging-effects", action="store_true",
                   help="keep the mission file's white balance, motion blur, Bayer and JPEG "
                   "settings instead of drawing them (the worlds of campaigns flown before "
                   "they were drawn)")


@contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM stops a campaign as Ctrl-C does (a scheduler, ``kill``, a CI timeout): the
    executor's cleanup stops the runs still flying instead of leaving its workers behind."""
    def interrupt(signum: int, _frame: FrameType | None) -> None:
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupted(out: str | None) -> int:
    if out is None:
        print("interrupted: the runs still flying were stopped; nothing was kept (no --out)",
              file=sys.stderr)
    else:
        kept = len(list(Path(out).glob("run_*.result.json")))
        print(f"interrupted: the runs still flying were stopped; {kept} finished run(s) kept in "
              f"{out}: run the same command again to resume", file=sys.stderr)
    return INTERRUPTED_EXIT


def _campaign(args: argparse.Namespace) -> int:
    from eaglemission.lab.campaign.campaign import print_summary, run_campaign
    from eaglemission.lab.campaign.emulator import EMULATOR_KINDS, emulator_kinds
    from eaglemission.lab.campaign.executors import CampaignExecutorError
    from eaglemission.lab.campaign.faults import parse_kinds, print_fault_table
    from eaglemission.lab.campaign.resume import CampaignResumeError

    from eaglemission import extras
    from eaglemission.errors import ConfigError, PluginError

    if args.runs < 1:
        print("error: --runs must be >= 1", file=sys.stderr)
        return 2
    if args.require is not None and not 0.0 <= args.require <= 1.0:
        print(f"error: --require {args.require:g}: a fraction of the runs, 0..1", file=sys.stderr)
        return 2
    try:
        if args.executor == "ray":
            extras.require("ray", "campaign --executor ray")
        if args.vehicle == "emulator":
            extras.require("mavsdk", "campaign --vehicle emulator")
    except extras.MissingExtra as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    kinds = None
    if args.faults is not None:
        try:
            kinds = parse_kinds(args.faults)
            if args.vehicle == "emulator":
                kinds = (list(EMULATOR_KINDS) if args.faults.strip() == "all"
                         else emulator_kinds(kinds))
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    ground_images = None
    if args.ground_images is not None:
        from eaglemission.lab.world.ground_images import GroundImageError, ground_image_files

        try:
            ground_images = ground_image_files(Path(args.ground_images))
        except GroundImageError as exc:
            print(f"error: --ground-images: {exc}", file=sys.stderr)
            return 2
    try:
        with _sigterm_interrupts():
            summary = run_campaign(args.config, runs=args.runs, seed=args.seed,
                                   workers=args.workers, out_dir=args.out, progress=True,
                                   executor=args.executor, address=args.address, faults=kinds,
                                   ground_images=ground_images, vehicle=args.vehicle,
                                   imaging_effects=not args.no_imaging_effects,
                                   manipulator=args.manipulator)
    except KeyboardInterrupt:
        return _interrupted(args.out)
    except (CampaignExecutorError, CampaignResumeError, ConfigError, PluginError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print_summary(summary)
    if kinds is not None:
        missed = print_fault_table(summary.runs)
    else:  # no fault injected: every run is expected to succeed
        missed = sum(not r["success"] for r in summary.runs)
    return verdict(len(summary.runs), missed, args.require)


def verdict(runs: int, missed: int, require: float | None) -> int:
    """The campaign's exit code: 0 when every run reached its expected outcome, or when
    ``require`` is given and at least that fraction did; 1 otherwise (the line says which)."""
    met = runs - missed
    if require is None:
        ok = missed == 0
        rule = "every run must"
    else:
        ok = runs > 0 and met / runs >= require - 1e-12
        rule = f"--require {require:g}"
    print(f"{'passed' if ok else 'FAILED'}: {met}/{runs} runs reached their expected outcome "
          f"({rule})", file=sys.stdout if ok else sys.stderr)
    return 0 if ok else 1


CAMPAIGN_COMMAND = Command("randomised simulation campaign with the evaluator's statistics",
                           _add_campaign, _campaign)
