"""Campaign executors and resume: the Ray executor's summary equals the local pool's apart from
wall-time fields, and a campaign resumes from its output folder flying only the missing runs.

The campaign flies the fast config (``fast_config``: MSS at 1/2 resolution) shrunk so that a run
takes a few CPU seconds: 320x240 cameras at 10 Hz, an 8 m route at 3 m."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest
import yaml
from eaglemission.lab.campaign.campaign import CampaignSummary, run_campaign
from eaglemission.lab.campaign.executors import (
    WALL_TIME_FIELDS,
    CampaignExecutorError,
    LocalExecutor,
    RunFn,
    flight_fields,
    make_executor,
    stage_project,
)
from eaglemission.lab.campaign.resume import MANIFEST, CampaignResumeError, result_path
from mission_helpers import variant

from eaglemission.config import MissionFile, load_config

pytestmark = pytest.mark.machine  # its emulators are found in /proc (tests/conftest.py)

SEED = 4
RUNS = 3


def _small_config() -> MissionFile:
    """The ``fast_config`` fixture's mission, shrunk (module-scoped fixtures cannot use it)."""
    cfg = variant(load_config(check_plugins=False),
                  detector={"type": "mss", "params": {"downscale": 2}})
    d = cfg.model_dump(mode="json")
    for cam in d["cameras"].values():
        cam["resolution_px"], cam["pixel_size_um"] = [320, 240], 15.0
    d["mission"]["route"][1]["north_m"] = 8.0
    d["mission"]["cruise_altitude_m"] = 3.0
    d["world"]["params"]["frame_rate_hz"] = 10.0
    return MissionFile.model_validate(d)


def _json(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """As stored in summary.json (tuples become lists)."""
    out: list[dict[str, Any]] = json.loads(json.dumps(runs, default=str))
    return out


@pytest.fixture(scope="module")
def small_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "small.yaml"
    path.write_text(yaml.safe_dump(_small_config().model_dump(mode="json"), sort_keys=False))
    return path


@pytest.fixture(scope="module")
def local_run(small_yaml: Path, tmp_path_factory: pytest.TempPathFactory
              ) -> tuple[CampaignSummary, Path]:
    """The campaign on the local pool (2 workers), uninterrupted, with its output folder."""
    out = tmp_path_factory.mktemp("local")
    return run_campaign(str(small_yaml), runs=RUNS, seed=SEED, workers=2, out_dir=str(out)), out


@pytest.mark.slow
def test_ray_summary_equals_the_local_pools(small_yaml: Path, local_run: tuple[CampaignSummary,
                                            Path], tmp_path: Path) -> None:
    pytest.importorskip("ray")
    local, _ = local_run
    ray = run_campaign(str(small_yaml), runs=RUNS, seed=SEED, workers=2, executor="ray",
                       out_dir=str(tmp_path))
    assert local.n == ray.n == RUNS
    assert any(r["reached_grasp_ready"] for r in local.runs)  # they flew the mission
    for r in local.runs + ray.runs:  # the wall-time fields exist: only they are left out
        assert all(r[k] is not None for k in WALL_TIME_FIELDS), r
    assert _json(flight_fields(ray.runs)) == _json(flight_fields(local.runs))
    assert (ray.success_rate, ray.violations) == (local.success_rate, local.violations)
    stored = json.loads((tmp_path / "summary.json").read_text())
    assert flight_fields(stored["runs"]) == _json(flight_fields(local.runs))


class _Recording:
    """The local pool, noting which runs it was given."""

    def __init__(self) -> None:
        self.inner, self.flown, self.name = LocalExecutor(workers=2), [], "local"

    def map_unordered(self, fn: RunFn, jobs: Sequence[Any]) -> Iterator[dict[str, Any]]:
        self.flown.extend(j[0] for j in jobs)
        return self.inner.map_unordered(fn, jobs)


@pytest.mark.slow
def test_an_interrupted_campaign_resumes_from_its_folder(
        small_yaml: Path, local_run: tuple[CampaignSummary, Path], tmp_path: Path) -> None:
    full, full_dir = local_run
    # what an interrupted campaign leaves: its manifest, runs 0 and 2, a torn write of run 1
    shutil.copy(full_dir / MANIFEST, tmp_path / MANIFEST)
    for i in (0, 2):
        shutil.copy(result_path(full_dir, i), result_path(tmp_path, i))
    torn = result_path(tmp_path, 1)
    torn.write_text(result_path(full_dir, 1).read_text()[:100])
    ex = _Recording()
    resumed = run_campaign(str(small_yaml), runs=RUNS, seed=SEED, out_dir=str(tmp_path),
                           executor=ex)
    assert ex.flown == [1]
    assert sorted(p.name for p in tmp_path.glob("run_*.jsonl")) == ["run_001.jsonl"]
    assert _json(flight_fields(resumed.runs)) == _json(flight_fields(full.runs))
    assert _json([resumed.runs[0], resumed.runs[2]]) == _json([full.runs[0], full.runs[2]])
    # resuming a finished campaign flies nothing
    again = _Recording()
    run_campaign(str(small_yaml), runs=RUNS, seed=SEED, out_dir=str(tmp_path), executor=again)
    assert again.flown == []


def test_a_folder_of_another_campaign_is_refused(
        small_yaml: Path, local_run: tuple[CampaignSummary, Path], tmp_path: Path) -> None:
    _, full_dir = local_run
    with pytest.raises(CampaignResumeError, match=r"holds another campaign \(seed 4 there, 5 now"):
        run_campaign(str(small_yaml), runs=RUNS, seed=SEED + 1, out_dir=str(full_dir),
                     executor=_Recording())
    # same manifest, but run 1 stored for another config
    shutil.copy(full_dir / MANIFEST, tmp_path / MANIFEST)
    rec = json.loads(result_path(full_dir, 1).read_text())
    rec["config_sha256"] = "0" * 64
    result_path(tmp_path, 1).write_text(json.dumps(rec))
    ex = _Recording()
    with pytest.raises(CampaignResumeError, match=r"run_001\.result\.json: stored for run 1.*"
                                                  r"use another --out"):
        run_campaign(str(small_yaml), runs=RUNS, seed=SEED, out_dir=str(tmp_path), executor=ex)
    assert ex.flown == []


def test_the_ray_executor_without_ray_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` sees without the extra
    with pytest.raises(CampaignExecutorError, match=r"pip install 'eaglemission\[ray\]'"):
        make_executor("ray")
    with pytest.raises(CampaignExecutorError, match="--address: only for --executor ray"):
        make_executor("local", address="10.0.0.1:6379")


def test_the_staged_project_imports_with_its_plugins(tmp_path: Path) -> None:
    """What a cluster's worker gets as its working_dir: the package with its plugin folders and
    entry points, imported from there (not from this checkout)."""
    staged = stage_project(tmp_path / "project")
    probe = ("import importlib.metadata as m, eaglemission.lab.campaign.campaign as c, "
             "eaglemission.registry as r; d = next(iter(m.distributions(name='eaglemission')));"
             "print(c.__file__, d.locate_file(''), r.get('detectors', 'mss').__module__)")
    p = subprocess.run([sys.executable, "-c", probe], cwd=staged, capture_output=True,
                       text=True, timeout=120, env={"PYTHONPATH": str(staged), "PATH": ""})
    assert p.returncode == 0, p.stderr[-2000:]
    module_file, dist_dir, plugin = p.stdout.split()
    assert Path(module_file).is_relative_to(staged) and (staged / dist_dir).resolve() == staged
    assert plugin == "eaglemission.detectors.mss"


@pytest.mark.slow
@pytest.mark.parametrize("how", ["sigterm to the campaign", "ctrl-c to the process group"])
def test_a_stopped_campaign_keeps_its_runs_and_leaves_no_worker(
        small_yaml: Path, tmp_path: Path, how: str) -> None:
    """``kill`` (a scheduler, a CI timeout) stops a campaign as Ctrl-C in its terminal does:
    the pool's workers are stopped with it, the finished runs stay in --out to resume from,
    exit 130, no traceback."""
    import os
    import signal
    import time

    def as_in_a_terminal() -> None:
        # a terminal's foreground job takes Ctrl-C; a job started in the background of a
        # script (and all it starts) ignores SIGINT, so Python would not turn it into
        # KeyboardInterrupt and the campaign would run to its end
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "eaglemission.cli", "campaign", str(small_yaml),
                             "--runs", "12", "--workers", "2", "--seed", str(SEED),
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, preexec_fn=as_in_a_terminal)
    try:
        deadline = time.monotonic() + 240
        while not list(out.glob("run_*.result.json")):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        if how.startswith("sigterm"):
            proc.send_signal(signal.SIGTERM)  # to the campaign only, not to its workers
        else:
            os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    kept = len(list(out.glob("run_*.result.json")))
    assert 1 <= kept < 12 and f"{kept} finished run(s) kept in {out}" in err, err
    assert "Traceback" not in err
    deadline = time.monotonic() + 20  # the workers (its process group) are gone
    while True:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        assert time.monotonic() < deadline, "a campaign worker outlived the campaign"
        time.sleep(0.2)


def _sitl_vehicles() -> set[int]:
    """Pids of the emulator campaigns' ``sitl-vehicle`` processes on this machine."""
    found = set()
    for proc in Path("/proc").iterdir():
        try:
            cmd = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        # a campaign's emulator takes its mission on stdin (`--mission -`)
        if b"sitl-vehicle" in cmd and b"--mission" in cmd \
                and cmd[cmd.index(b"--mission") + 1:][:1] == [b"-"]:
            found.add(int(proc.name))
    return found


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to list processes")
def test_a_stopped_emulator_campaign_stops_its_emulators(small_yaml: Path,
                                                         tmp_path: Path) -> None:
    """Each emulator run's ``sitl-vehicle`` lives in its own session: stopping the campaign
    must stop them through the runs that started them, not leave them streaming."""
    import os
    import signal
    import time

    before = _sitl_vehicles()
    proc = subprocess.Popen([sys.executable, "-m", "eaglemission.cli", "campaign", str(small_yaml),
                             "--runs", "4", "--workers", "2", "--seed", str(SEED), "--vehicle",
                             "emulator", "--out", str(tmp_path / "out")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(_sitl_vehicles() - before) < 2:  # both workers flying
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        started = _sitl_vehicles() - before
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    deadline = time.monotonic() + 20
    while _sitl_vehicles() & started:
        assert time.monotonic() < deadline, f"emulators left running: {_sitl_vehicles() & started}"
        time.sleep(0.2)


def test_only_faults_flies_the_runs_of_those_kinds_from_the_same_draws(small_yaml: Path) -> None:
    """``fault_campaign.py --only-faults``: after a change to one fault's path, the runs it can
    alter are flown again, drawn as in the whole campaign."""
    from eaglemission.lab.campaign.faults import with_drawn_fault

    kinds = ["camera_drop", "slow_frame"]
    base = load_config(str(small_yaml), check_plugins=False)
    drawn = {i: with_drawn_fault(base, i, kinds, SEED).faults for i in range(4)}
    expected = sorted(i for i, f in drawn.items() if f is not None
                      and f["inject"][0]["kind"] == "slow_frame")
    summary = run_campaign(str(small_yaml), runs=4, seed=SEED, workers=1, faults=kinds,
                           only_faults={"slow_frame"})
    assert [r["run"] for r in summary.runs] == expected and len(expected) == 2
    assert {r["fault"] for r in summary.runs} == {"slow_frame"}
