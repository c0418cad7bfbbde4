"""The xdist grouping of tests/conftest.py holds on two workers: the modules marked ``machine``
(a PX4 SITL, fixed UDP ports, processes they start) run on one worker, one test at a time, and
every other module stays on one worker. Checked on a small suite of its own, run with the
suite's own conftest and ``-n 2 --dist loadgroup``."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

MODULE = """import time

import pytest
{mark}

@pytest.mark.parametrize("k", range(4))
def test_step(k):
    time.sleep(0.2)
"""


def test_machine_modules_share_one_worker_and_modules_stay_whole(tmp_path: Path) -> None:
    shutil.copy(REPO / "tests" / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "pytest.ini").write_text(
        "[pytest]\nmarkers =\n    machine: shares the machine\n    gc_unfrozen: whole heap\n")
    for name in ("test_px4_a.py", "test_px4_b.py", "test_ports.py"):
        (tmp_path / name).write_text(MODULE.format(mark="pytestmark = pytest.mark.machine"))
    for name in ("test_plain_a.py", "test_plain_b.py"):
        (tmp_path / name).write_text(MODULE.format(mark=""))
    r = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-v",
                        "-p", "no:cacheprovider", "-p", "no:randomly"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    ran = re.findall(r"\[(gw\d)\] \[\s*\d+%\] PASSED (test_\w+)\.py::", r.stdout)
    assert len(ran) == 20, r.stdout[-3000:]
    workers: dict[str, set[str]] = {}
    for worker, module in ran:
        workers.setdefault(module, set()).add(worker)
    assert all(len(w) == 1 for w in workers.values()), workers
    machine = workers["test_px4_a"] | workers["test_px4_b"] | workers["test_ports"]
    assert len(machine) == 1, workers
    assert {w for ws in workers.values() for w in ws} == {"gw0", "gw1"}  # both were used
