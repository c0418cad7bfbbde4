"""The README opens with the two commands, and CI runs the README's test command verbatim."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def readme_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```(?:bash|sh)\n(.*?)```", text, flags=re.S)
    return [b.strip() for b in blocks[:2]]


def test_readme_starts_with_run_and_test_commands() -> None:
    run_cmd, test_cmd = readme_commands()
    assert "eaglemission run" in run_cmd
    assert "pytest" in test_cmd
    for cmd in (run_cmd, test_cmd):
        assert cmd.startswith("python3 -m venv .venv")


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    _, test_cmd = readme_commands()
    ci = (REPO / ".ci" / "run").read_text()
    assert test_cmd in ci.splitlines()
