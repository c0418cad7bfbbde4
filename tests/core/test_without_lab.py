"""The product flies without the lab. In a process where every ``eaglemission.lab`` import
fails, as on a field computer with the product alone, ``validate`` passes the field config,
``plugins`` lists the lab's plugins as unavailable with the reason, and ``run --dry-run`` of the
field config passes every check against the genicam wheel's GenTL test producer and the
PX4-like emulator. The emulator runs in its own, ordinary process: it stands for the real
autopilot, not for a part of the product."""

from __future__ import annotations

import re
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pytest
import yaml
from deployment_helpers import REPO, free_udp_port, run_env, sitl_vehicle, viky_field_config

from eaglemission.names import ROLES

pytestmark = [pytest.mark.slow, pytest.mark.machine]  # a port, an emulator process

LAB = "eaglemission.lab"
WITHOUT_LAB = f'''
import importlib.abc
import sys


class NoLab(importlib.abc.MetaPathFinder):
    """Every import of the lab fails as it does where the lab is not installed; an import
    that does not come through an entry point (importlib.metadata) is remembered."""

    direct = []

    def find_spec(self, name, path=None, target=None):
        if name != "{LAB}" and not name.startswith("{LAB}."):
            return None
        f = sys._getframe(1)
        while f is not None and (f.f_code.co_filename.startswith("<frozen importlib")
                                 or f.f_globals.get("__name__") == "importlib"):
            f = f.f_back
        if f is None or f.f_globals.get("__name__") != "importlib.metadata":
            where = "?" if f is None else f"{{f.f_code.co_filename}}:{{f.f_lineno}}"
            self.direct.append(f"{{name}} ({{where}})")
        raise ModuleNotFoundError(f"No module named {{name!r}} (no lab here)", name=name)


sys.meta_path.insert(0, NoLab())
from eaglemission.cli import main

code = main(sys.argv[1:])
lab = sorted(m for m in sys.modules if m == "{LAB}" or m.startswith("{LAB}."))
print("lab modules imported:", ", ".join(lab) or "none", file=sys.stderr)
print("lab imports not through an entry point:", ", ".join(NoLab.direct) or "none",
      file=sys.stderr)
sys.exit(code)
'''
"""``python -c WITHOUT_LAB <eaglemission arguments>``: the CLI with the lab unimportable."""


def without_lab(cwd: Path, *args: str, timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", WITHOUT_LAB, *args], capture_output=True,
                          text=True, timeout=timeout_s, cwd=cwd, env=run_env())


def _clean(p: subprocess.CompletedProcess[str]) -> None:
    """No traceback; the lab was reached through entry points only, and none loaded."""
    assert "Traceback" not in p.stderr, p.stderr
    assert p.stderr.rstrip().endswith("lab modules imported: none\n"
                                      "lab imports not through an entry point: none"), p.stderr


def test_validate_passes_the_field_config(tmp_path: Path) -> None:
    p = without_lab(tmp_path, "validate", str(REPO / "configs" / "field_basler_px4.yaml"))
    assert p.returncode == 0, p.stdout + p.stderr
    assert "valid:" in p.stdout
    _clean(p)


def test_plugins_lists_the_lab_plugins_as_unavailable(tmp_path: Path) -> None:
    p = without_lab(tmp_path, "plugins")
    assert p.returncode == 1, p.stdout + p.stderr  # 1: some plugin is unavailable
    _clean(p)
    rows = {}
    for line in p.stdout.splitlines():  # | role | name | description | (COLUMNS=1000: one line)
        cells = [c.strip() for c in line.split("│")[1:-1]]
        if len(cells) == 3 and cells[0] in ROLES:
            rows[(cells[0], cells[1])] = cells[2]
    lab = []
    for role in ROLES:
        for ep in entry_points(group=f"eaglemission.{role}"):
            text = rows[(role, ep.name)]
            if ep.value.startswith(LAB + "."):
                lab.append(ep.name)
                assert re.fullmatch(rf"unavailable: \w+ plugin '{ep.name}' \({re.escape(ep.value)}\)"
                                    rf" cannot be imported: No module named '{LAB}.*", text), text
            else:
                assert "unavailable" not in text, (role, ep.name, text)
    assert {"synthetic", "simulated", "faults", "approach"} <= set(lab)


def test_dry_run_passes_on_the_gentl_producer_and_the_emulator(tmp_path: Path) -> None:
    port = free_udp_port()
    data = viky_field_config(tmp_path, port)
    # the free disk space of the test machine is not what is tested: the check still runs
    data["recording"]["min_free_mb"] = 1
    mission = tmp_path / "field.yaml"
    mission.write_text(yaml.safe_dump(data, sort_keys=False))
    with sitl_vehicle(mission, port, tmp_path / "emulator.json"):
        p = without_lab(tmp_path, "run", str(mission), "--dry-run")
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    _clean(p)
    assert "camera wide: genicam" in p.stdout and "camera narrow: genicam" in p.stdout
    assert "[FAIL]" not in p.stdout, p.stdout
    for check in ("recording: disk space", "camera wide: frame", "camera narrow: frame",
                  "vehicle: link", "vehicle: home", "vehicle: position", "vehicle: armable",
                  "vehicle: on the ground", "vehicle: battery", "autopilot parameters",
                  "autopilot version"):
        assert f"  [ok] {check}: " in p.stdout, (check, p.stdout)
    # on the ground a rangefinder below its minimum range has no reading: a warning
    assert ("  [ok] vehicle: downward rangefinder: " in p.stdout
            or "  [warn] vehicle: downward rangefinder: " in p.stdout), p.stdout
