"""``eaglemission campaign``: randomised simulated flights of the approach mission, each through
the assembly (``eaglemission run`` is the core command :mod:`eaglemission.commands.run`)."""

from __future__ import annotations

import argparse
import sys

from eaglemission.commands import Command


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


CAMPAIGN_COMMAND = Command("randomised simulation campaign with the evaluator's statistics",
                           _add_campaign, _campaign)
