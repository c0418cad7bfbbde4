"""CLI subcommands, discovered through the ``eaglemission.commands`` entry-point group.

A command is a :class:`Command`: a help line, a function adding its arguments to an argparse
parser, and a function running it that returns the process exit code. Plugin folders
contribute their own commands (``run``, ``detect``, ``sitl-vehicle``, ...) the same way a third
party would, so the core CLI imports no plugin.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Command:
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def console(*, stderr: bool = False) -> Any:
    """A rich Console for a command's lines: at a terminal they fit its width (wrapped between
    words); into a pipe or a file they are never wrapped (one record, one line, for grep)."""
    from rich.console import Console

    out = Console(stderr=stderr, highlight=False)
    if not out.is_terminal:  # tables too: as wide as they need (up to PIPE_WIDTH)
        out = Console(stderr=stderr, highlight=False, width=PIPE_WIDTH, soft_wrap=True)
    return out


PIPE_WIDTH = 240
"""Columns a table may take when the output is not a terminal."""
