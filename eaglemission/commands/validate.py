"""``eaglemission validate CONFIG``: exit 0 for a valid mission file, 2 with reasons otherwise."""

from __future__ import annotations

import argparse
import sys

from eaglemission.config import load_config, plugin_problems
from eaglemission.errors import ConfigError


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="mission YAML (default: the embedded sitl_synthetic.yaml)")


def _run(args: argparse.Namespace) -> int:
    from eaglemission.commands import checks

    try:
        cfg = load_config(args.config, check_plugins=False)
        problems = plugin_problems(cfg) + checks.run_checks(cfg)
        if problems:
            raise ConfigError(problems, source=args.config or "<embedded>")
        for w in checks.hardware_warnings(cfg):
            print(f"warning: {w}", file=sys.stderr)
    except ConfigError as exc:
        print(f"invalid: {exc}", file=sys.stderr)
        return 2
    print(f"valid: {args.config or '<embedded sitl_synthetic.yaml>'}")
    return 0


from eaglemission.commands import Command  # noqa: E402

COMMAND = Command("validate a mission file", _add, _run)
