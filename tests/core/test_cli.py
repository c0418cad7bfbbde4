"""The ``eaglemission`` CLI entry points."""

from __future__ import annotations

import re
import subprocess
import sys
from importlib.metadata import entry_points

from eaglemission.cli import build_parser, main


def test_help_lists_core_commands(capsys) -> None:
    assert main([]) == 1
    out = capsys.readouterr().out
    for cmd in ("plugins", "validate"):
        assert cmd in out


def test_plugins_table_lists_every_builtin() -> None:
    r = subprocess.run([sys.executable, "-m", "eaglemission.cli", "plugins"],
                       capture_output=True, text=True, timeout=120,
                       env={"COLUMNS": "250", "PATH": "/usr/bin:/bin"})
    for name in ("synthetic", "replay", "genicam", "simulated", "mavsdk", "dtdmi", "rpnp",
                 "pixel_offset", "bearing", "approach"):
        assert name in r.stdout
    assert "Traceback" not in r.stderr


def test_every_declared_command_builds() -> None:
    """Each command of the ``eaglemission.commands`` group loads and is offered by the CLI."""
    declared = {ep.name for ep in entry_points(group="eaglemission.commands")}
    assert {"plugins", "validate"} <= declared
    text = build_parser().format_help()
    offered = set(re.findall(r"^ {4}(\S+)", text, re.M))
    assert declared <= offered, text
    assert "unavailable" not in text
