"""The PX4 SITL launcher (``eaglemission.lab.px4``) on stand-in programs: a ``bin/px4`` shell
script that prints what PX4 prints (or does not), and a ``java`` on PATH standing in for
jMAVSim. What is checked: the fresh working directory, the environment PX4 gets, the order
PX4 -> "waiting for the simulator" -> jMAVSim -> "Ready for takeoff", bounded waits, stopping by
pid (SIGTERM, SIGKILL for a process that ignores it), refusals with their fix."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from eaglemission.lab.px4 import sitl
from eaglemission.lab.px4.sitl import SitlError

READY_PX4 = """#!/bin/sh
echo "args $*"
echo "model $PX4_SIM_MODEL headless $HEADLESS cwd $(pwd)"
sleep 0.3
echo "INFO  [commander] Ready for takeoff!"
exec sleep 60
"""
SILENT_PX4 = "#!/bin/sh\necho $$ > px4.pid\necho 'px4 starting.'\nexec sleep 60\n"
EXITING_PX4 = "#!/bin/sh\necho 'ERROR [px4] PX4 server already running for instance 0'\nexit 1\n"
STUBBORN_PX4 = """#!/bin/sh
trap '' TERM
echo "INFO  [commander] Ready for takeoff!"
while :; do sleep 0.1; done
"""
JMAVSIM_PX4 = """#!/bin/sh
echo "model $PX4_SIM_MODEL"
sleep 0.3
date +%s.%N > "$SIM_MARK.waiting"
echo "INFO  [simulator_mavlink] Waiting for simulator to accept connection on TCP port 4560"
while [ ! -e "$SIM_MARK" ]; do sleep 0.05; done
echo "INFO  [commander] Ready for takeoff!"
exec sleep 60
"""
FAKE_JAVA = """#!/bin/sh
echo "$(date +%s.%N) java $* cwd $(pwd)" > "$SIM_MARK.tmp" && mv "$SIM_MARK.tmp" "$SIM_MARK"
exec sleep 60
"""


def _build(tmp_path: Path, script: str) -> Path:
    build = tmp_path / "build" / "px4_sitl_default"
    (build / "bin").mkdir(parents=True)
    (build / "etc").mkdir()
    px4 = build / "bin" / "px4"
    px4.write_text(script)
    px4.chmod(0o755)
    return build


@pytest.fixture(autouse=True)
def own_ports(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Free ports of our own in place of PX4's 14580 and jMAVSim's 4560, so that a real PX4
    running on the machine does not change the outcome."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u, \
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as t:
        u.bind(("0.0.0.0", 0))
        t.bind(("0.0.0.0", 0))
        ports = u.getsockname()[1], t.getsockname()[1]
    monkeypatch.setattr(sitl, "INSTANCE_PORT", ports[0])
    monkeypatch.setattr(sitl, "JMAVSIM_PORT", ports[1])
    yield


def _gone(pid: int, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sitl._start_ticks(pid) is None:
            return True
        time.sleep(0.05)
    return False


def test_sih_starts_in_a_fresh_directory_and_stops_by_sigterm(tmp_path: Path) -> None:
    build = _build(tmp_path, READY_PX4)
    opts = sitl.resolve_options(build=build, sim="sih", workdir_parent=tmp_path)
    inst = sitl.start(opts)
    try:
        workdir = Path(inst.workdir)
        assert workdir.parent == tmp_path and workdir.name.startswith("px4_sih.")
        log = (workdir / "px4.log").read_text()
        assert f"args -d {build / 'etc'}" in log
        assert f"model sihsim_quadx headless 1 cwd {workdir}" in log
        assert 0.3 <= inst.ready_s < 10.0
        assert list(inst.pids) == ["px4"] and inst.procs[0].alive()
        assert inst.url == "udpin://0.0.0.0:14540"
    finally:
        lines = sitl.stop(inst)
    assert lines == [f"px4 (pid {inst.pids['px4']}): stopped by SIGTERM"]
    assert not inst.procs[0].alive()
    assert sitl.stop(inst) == [f"px4 (pid {inst.pids['px4']}): not running"]  # idempotent


def test_jmavsim_starts_after_px4_waits_for_it_and_stops_first(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    build = _build(tmp_path, JMAVSIM_PX4)
    jar_dir = tmp_path / "jmavsim"
    jar_dir.mkdir()
    jar = jar_dir / "jmavsim_run.jar"
    jar.write_bytes(b"")
    bindir = tmp_path / "javabin"
    bindir.mkdir()
    (bindir / "java").write_text(FAKE_JAVA)
    (bindir / "java").chmod(0o755)
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    mark = tmp_path / "sim_started"
    monkeypatch.setenv("SIM_MARK", str(mark))
    inst = sitl.start(sitl.resolve_options(build=build, sim="jmavsim", jmavsim_jar=jar,
                                           workdir_parent=tmp_path))
    try:
        assert [p.name for p in inst.procs] == ["jmavsim", "px4"]
        java = mark.read_text()
        waiting = (tmp_path / "sim_started.waiting").read_text()
        assert float(java.split()[0]) > float(waiting)  # started once PX4 waited for it
        assert f"-jar {jar} -tcp 127.0.0.1:4560 -r 250 -lockstep -no-gui cwd {jar_dir}" in java
        assert "model jmavsim_iris" in (Path(inst.workdir) / "px4.log").read_text()
    finally:
        lines = sitl.stop(inst)
    assert [line.split(" (")[0] for line in lines] == ["jmavsim", "px4"]
    assert all(_gone(pid) for pid in inst.pids.values())


def test_not_ready_within_the_timeout_is_an_error_and_nothing_is_left_running(
        tmp_path: Path) -> None:
    build = _build(tmp_path, SILENT_PX4)
    opts = sitl.resolve_options(build=build, sim="sih", ready_timeout_s=0.8,
                                workdir_parent=tmp_path)
    t0 = time.monotonic()
    with pytest.raises(SitlError, match="ready for takeoff: not within the timeout") as info:
        sitl.start(opts)
    assert time.monotonic() - t0 < 8.0
    assert "px4 starting." in str(info.value)  # the log's tail
    (workdir,) = tmp_path.glob("px4_sih.*")
    assert _gone(int((workdir / "px4.pid").read_text()))  # stopped on the way out


def test_px4_exiting_early_is_reported_with_its_log(tmp_path: Path) -> None:
    build = _build(tmp_path, EXITING_PX4)
    with pytest.raises(SitlError, match="px4 exited before") as info:
        sitl.start(sitl.resolve_options(build=build, sim="sih", workdir_parent=tmp_path))
    assert "already running for instance 0" in str(info.value)


def test_a_process_ignoring_sigterm_is_killed_after_the_timeout(tmp_path: Path) -> None:
    inst = sitl.start(sitl.resolve_options(build=_build(tmp_path, STUBBORN_PX4), sim="sih",
                                           workdir_parent=tmp_path))
    t0 = time.monotonic()
    lines = sitl.stop(inst, timeout_s=0.5)
    assert lines[0].endswith("killed (SIGKILL after 0.5 s)")
    assert 0.5 <= time.monotonic() - t0 < 6.0 and _gone(inst.pids["px4"])


def test_a_running_instance_or_simulator_is_not_shared(tmp_path: Path) -> None:
    build = _build(tmp_path, READY_PX4)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("0.0.0.0", sitl.INSTANCE_PORT))
        with pytest.raises(SitlError, match=f"UDP {sitl.INSTANCE_PORT} is in use.*stop it"):
            sitl.start(sitl.resolve_options(build=build, sim="sih", workdir_parent=tmp_path))
    jar = tmp_path / "x.jar"
    jar.write_bytes(b"")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as listener:
        listener.bind(("0.0.0.0", sitl.JMAVSIM_PORT))
        listener.listen()
        with pytest.raises(SitlError, match=f"TCP {sitl.JMAVSIM_PORT} is in use"):
            sitl.start(sitl.resolve_options(build=build, sim="jmavsim", jmavsim_jar=jar,
                                            workdir_parent=tmp_path))
    assert list(tmp_path.glob("px4_*")) == []  # refused before anything was made


def test_options_name_what_is_missing_and_how_to_provide_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for env in (sitl.ENV_PX4_BUILD, sitl.ENV_PX4_SIM, sitl.ENV_JMAVSIM_JAR):
        monkeypatch.delenv(env, raising=False)
    with pytest.raises(SitlError, match="pass --build DIR or set EAGLEMISSION_PX4_BUILD"):
        sitl.resolve_options()
    with pytest.raises(SitlError, match="no bin/px4 and etc/ there"):
        sitl.resolve_options(build=tmp_path)
    build = _build(tmp_path, READY_PX4)
    monkeypatch.setenv(sitl.ENV_PX4_BUILD, str(build))
    assert sitl.resolve_options().build_dir == build and sitl.resolve_options().sim == "sih"
    with pytest.raises(SitlError, match="simulator 'gazebo': use one of sih, jmavsim"):
        sitl.resolve_options(sim="gazebo")
    with pytest.raises(SitlError, match="jMAVSim jar .* not found: pass --jmavsim-jar or set "
                                        "EAGLEMISSION_JMAVSIM_JAR"):
        sitl.resolve_options(sim="jmavsim")
    jar = tmp_path / "jmavsim_run.jar"
    jar.write_bytes(b"")
    monkeypatch.setenv(sitl.ENV_JMAVSIM_JAR, str(jar))
    monkeypatch.setenv(sitl.ENV_PX4_SIM, "jmavsim")
    opts = sitl.resolve_options()
    assert (opts.sim, opts.jmavsim_jar, opts.timeout_s) == ("jmavsim", jar, 120.0)


def test_the_lock_keeps_a_second_user_waiting_then_refuses(tmp_path: Path) -> None:
    lock = tmp_path / "px4.lock"
    with sitl.machine_lock(1.0, lock):
        t0 = time.monotonic()
        with pytest.raises(SitlError, match="held for more than 0.3 s"):
            with sitl.machine_lock(0.3, lock):
                pass
        assert time.monotonic() - t0 >= 0.3
    with sitl.machine_lock(0.3, lock):  # released: taken at once
        pass


def test_cli_start_refuses_a_second_instance_and_stop_ends_it(tmp_path: Path) -> None:
    if sitl.port_in_use(14580):
        pytest.skip("a PX4 SITL runs on this machine (UDP 14580 taken): the CLI would refuse")
    build = _build(tmp_path, READY_PX4)
    state = tmp_path / "state.json"

    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "eaglemission.lab.px4", *args,
                               "--state", str(state)], capture_output=True, text=True,
                              timeout=60)

    r = cli("start", "--sim", "sih", "--build", str(build), "--workdir-parent", str(tmp_path))
    assert r.returncode == 0, r.stderr
    pid = int(next(x for x in r.stdout.splitlines() if x.startswith("PX4_PID=")).split("=")[1])
    try:
        assert "PX4 (sih) ready for takeoff in" in r.stdout and "WORKDIR=" in r.stdout
        again = cli("start", "--sim", "sih", "--build", str(build))
        assert again.returncode == 2 and "Traceback" not in again.stderr
        assert f"an instance started earlier still runs ({{'px4': {pid}}}" in again.stderr
        stopped = cli("stop")
        assert stopped.stdout.strip() == f"px4 (pid {pid}): stopped by SIGTERM"
        assert not state.exists() and _gone(pid)
        assert cli("stop").stdout.startswith("nothing to stop")
    finally:
        if not _gone(pid, 0.1):
            os.kill(pid, signal.SIGKILL)


def test_waiting_for_a_running_instance_is_bounded() -> None:
    sitl.wait_until_free(0.1)  # free: returns at once
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("0.0.0.0", sitl.INSTANCE_PORT))
        t0 = time.monotonic()
        with pytest.raises(SitlError, match="still in use after 0.6 s.*stop it first"):
            sitl.wait_until_free(0.6)
        assert 0.6 <= time.monotonic() - t0 < 5.0
