"""``eaglemission plugins``: every plugin per role with a one-line description."""

from __future__ import annotations

import argparse

from rich.table import Table

from eaglemission import registry
from eaglemission.commands import Command
from eaglemission.names import ROLES


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("--role", choices=ROLES, help="only this role")


def _run(args: argparse.Namespace) -> int:
    from eaglemission.commands import console as make_console

    console = make_console()
    table = Table(title="eaglemission plugins")
    table.add_column("role")
    table.add_column("name (config `type`)")
    table.add_column("description")
    broken = 0
    for role in ROLES if args.role is None else (args.role,):
        for info in registry.describe(role):
            if info.error:
                broken += 1
                table.add_row(role, info.name, f"[red]unavailable[/red]: {info.error}")
            else:
                table.add_row(role, info.name, info.description)
    console.print(table)
    return 1 if broken else 0


COMMAND = Command("list every plugin per role", _add, _run)
