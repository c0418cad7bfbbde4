"""Two simulated flights of the same mission file and seed write the same log, record for
record, apart from wall-clock fields: in the same process and through ``eaglemission run``
in another (whose hash seed differs), over several randomised worlds."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from deployment_helpers import cli, log_records, run_env
from eaglemission.lab.campaign.campaign import randomise
from eaglemission.lab.campaign.sim import run_simulation
from eaglemission.missions.log import read_log

WALL_FIELDS = {"wall_time", "perception_ms", "latency_ms", "latency_p90_ms", "wall_s"}
"""Fields that measure host time (how long the computer took), not the flight."""


def _flight_records(path: Path) -> list[dict]:
    """The records apart from wall-clock fields and records judged on wall time (a slow frame
    on the host: ``wall_clock: true``)."""
    return [{k: v for k, v in r.items() if k not in WALL_FIELDS} for r in read_log(path)
            if not r.get("wall_clock")]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 11, 29])
def test_same_seed_same_log(fast_config, tmp_path: Path, seed: int) -> None:
    cfg = randomise(fast_config, np.random.RandomState(seed))
    a = run_simulation(cfg, log_path=tmp_path / "a.jsonl")
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
    p = subprocess.run(cli("run", str(path), "--log", str(tmp_path / "b.jsonl")),
                       capture_output=True, text=True, timeout=600, env=run_env())
    assert p.returncode in (0, 3, 6), p.stdout[-2000:] + p.stderr[-2000:]
    ra, rb = _flight_records(tmp_path / "a.jsonl"), _flight_records(tmp_path / "b.jsonl")
    assert len(ra) > 500
    assert sum(r["kind"] == "detection" for r in ra) == sum(a.result.frames_processed.values())
    for i, (x, y) in enumerate(zip(ra, rb)):
        assert x == y, f"record {i} differs:\n{x}\n{y}"
    assert len(ra) == len(rb)
    assert [r for r in log_records(tmp_path / "b.jsonl") if r["kind"] == "end"]
