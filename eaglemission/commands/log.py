"""``eaglemission log FILE.mcap``: what a flight recording holds; ``--recover`` rewrites a
recording cut short (crash, ``kill -9``, full disk) into a valid file."""

from __future__ import annotations

import argparse
import sys

from eaglemission.commands import Command


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE.mcap", help="a recording (run --record FILE.mcap)")
    p.add_argument("--recover", action="store_true",
                   help="rewrite the file, read linearly up to its last complete chunk, into "
                        "a valid MCAP file (-o, default FILE.recovered.mcap)")
    p.add_argument("-o", "--output", metavar="OUT", help="where --recover writes")


def _run(args: argparse.Namespace) -> int:
    from eaglemission.mcap_tools import recover, summarize

    try:
        if args.recover:
            print(recover(args.file, args.output).line())
        else:
            if args.output:
                print("-o needs --recover", file=sys.stderr)
                return 2
            print("\n".join(summarize(args.file)))
    except (OSError, ValueError) as exc:
        print(f"error: {args.file}: {exc}", file=sys.stderr)
        return 2
    return 0


COMMAND = Command("summarise a flight recording (MCAP); --recover one cut short", _add, _run)
