"""The ``eaglemission`` CLI entry points."""

from __future__ import annotations

import subprocess
import sys

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
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert {"plugins", "validate"} <= set(sub.choices)
