"""``eaglemission log FILE.mcap``: what a flight recording holds; ``--recover`` rewrites a
recording cut short (crash, ``kill -9``, full disk) into a valid file; ``--plot OUT.png``
draws the flight from it (the mission plugin's ``plot_recording``, the figure of
``run --plot``)."""

from __future__ import annotations

import argparse
import sys

from eaglemission.commands import Command


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE.mcap", help="a recording (run --record FILE.mcap)")
    p.add_argument("--recover", action="store_true",
                   help="rewrite the file (every part of a split one), read linearly up to its last "
                        "complete chunk, into a valid MCAP file (-o, default FILE.recovered.mcap)")
    p.add_argument("-o", "--output", metavar="OUT", help="where --recover writes")
    p.add_argument("--plot", metavar="PNG", help="draw the recorded flight: reported path, "
                   "target estimates, route, geofence, state changes, altitude over time")


def plot(path: str, out: str) -> None:
    """``--plot``: the recording's figure, drawn by its mission plugin."""
    from pathlib import Path

    from eaglemission import registry
    from eaglemission.config import MissionFile
    from eaglemission.recording.mcap_reader import log_records

    records = list(log_records(path))
    cfg_rec = next((r for r in records if r.get("kind") == "config"), None)
    if cfg_rec is None:
        raise ValueError("no config record (/log/config): nothing to draw the flight on")
    cfg = MissionFile.model_validate(cfg_rec["config"])
    draw = getattr(registry.get("missions", cfg.mission.type), "plot_recording", None)
    if draw is None:
        raise ValueError(f"the mission plugin {cfg.mission.type!r} draws no recordings")
    draw(records, cfg, Path(out))


def _run(args: argparse.Namespace) -> int:
    from eaglemission.recording.mcap_reader import check_mcap, recover_all, summarize

    try:
        check_mcap(args.file)
        if args.recover:
            for rec in recover_all(args.file, args.output):
                print(rec.line())
        else:
            if args.output:
                print("-o needs --recover", file=sys.stderr)
                return 2
            print("\n".join(summarize(args.file)))
            if args.plot:
                plot(args.file, args.plot)
                print(f"plot written to {args.plot}")
    except (OSError, ValueError) as exc:
        print(f"error: {args.file}: {exc}", file=sys.stderr)
        return 2
    return 0


COMMAND = Command("summarise a flight recording (MCAP); --recover one cut short", _add, _run)
