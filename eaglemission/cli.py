"""``eaglemission`` command line. Subcommands come from the ``eaglemission.commands`` group."""

from __future__ import annotations

import argparse
import logging
import sys
from importlib.metadata import entry_points

from eaglemission import __version__
from eaglemission.errors import EagleMissionError


class _LogFormat(logging.Formatter):
    """``warning: message``, as the commands' own lines; with ``-v`` timestamped, with the
    logger's name."""

    def __init__(self, *, timestamps: bool) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s" if timestamps
                         else "%(message)s")
        self.timestamps = timestamps

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        return text if self.timestamps else f"{record.levelname.lower()}: {text}"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="eaglemission",
        description="Eagle-eye dual-camera target detection and approach-to-grasp missions.",
    )
    parser.add_argument("--version", action="version", version=f"eaglemission {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for ep in sorted(entry_points(group="eaglemission.commands"), key=lambda e: e.name):
        try:
            cmd = ep.load()
        except Exception as exc:  # keep the CLI usable when one command cannot import
            p = sub.add_parser(ep.name, help=f"(unavailable: {type(exc).__name__}: {exc})")
            p.set_defaults(_unavailable=f"{ep.name}: unavailable: {exc}")
            continue
        p = sub.add_parser(ep.name, help=cmd.help, description=cmd.help)
        cmd.add_arguments(p)
        p.set_defaults(_run=cmd.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = logging.StreamHandler()
    handler.setFormatter(_LogFormat(timestamps=args.verbose > 0))
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2), handlers=[handler])
    if getattr(args, "_unavailable", None):
        print(args._unavailable, file=sys.stderr)
        return 3
    if not getattr(args, "_run", None):
        parser.print_help()
        return 1
    try:
        return int(args._run(args))
    except EagleMissionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
