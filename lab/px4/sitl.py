"""Start and stop a fresh PX4 SITL instance (SIH or jMAVSim), headless.

Nothing of PX4 lives in this repository: the build comes from ``--build`` or
``EAGLEMISSION_PX4_BUILD`` (``PX4-Autopilot/build/px4_sitl_default``, made with
``make px4_sitl_default``) and jMAVSim's jar from ``--jmavsim-jar`` or
``EAGLEMISSION_JMAVSIM_JAR`` (``ant create_run_jar copy_res`` in PX4's jMAVSim folder).

Each start uses a new empty working directory, so PX4's parameters and mission storage start
from the airframe's defaults. PX4 runs as instance 0: its offboard link sends to UDP 14540
(``udpin://0.0.0.0:14540``), its GCS link to 14550, jMAVSim meets it on TCP 4560; so one
instance per machine. With jMAVSim, PX4 starts first and waits for the simulator; jMAVSim is
started then (PX4's own jMAVSim start script would rebuild jMAVSim and kill any jMAVSim Java
process of the user). Processes are stopped by their own pid (SIGTERM, then SIGKILL after a
timeout), after checking that the pid is still the process that was started.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from eaglemission.errors import EagleMissionError

ENV_PX4_BUILD = "EAGLEMISSION_PX4_BUILD"
ENV_PX4_SIM = "EAGLEMISSION_PX4_SIM"
ENV_JMAVSIM_JAR = "EAGLEMISSION_JMAVSIM_JAR"

SIMS = ("sih", "jmavsim")
MODELS = {"sih": "sihsim_quadx", "jmavsim": "jmavsim_iris"}
"""PX4_SIM_MODEL of each simulator (airframes 10040 and 10017)."""
AIRFRAMES = {10040: "sih", 10017: "jmavsim"}
"""SYS_AUTOSTART -> simulator."""
READY_TIMEOUT_S = {"sih": 60.0, "jmavsim": 120.0}
"""Default wait for "Ready for takeoff" (measured 4-5 s and 13-14 s on a quiet 2-core machine;
the JVM start and PX4's estimator convergence stretch under load)."""

READY_LINE = "Ready for takeoff"
SIM_WAIT_LINE = "Waiting for simulator to accept connection on TCP port"
OFFBOARD_URL = "udpin://0.0.0.0:14540"
INSTANCE_PORT = 14580
"""UDP port PX4 instance 0 binds for its offboard link: taken while such an instance runs."""
JMAVSIM_PORT = 4560
JMAVSIM_TCP = f"127.0.0.1:{JMAVSIM_PORT}"
JAR_IN_PX4_TREE = "Tools/simulation/jmavsim/jMAVSim/out/production/jmavsim_run.jar"
JVM_OPTIONS = ("--add-exports", "java.base/java.lang=ALL-UNNAMED",
               "--add-exports", "java.desktop/sun.awt=ALL-UNNAMED",
               "--add-exports", "java.desktop/sun.java2d=ALL-UNNAMED",
               "-XX:GCTimeRatio=20", "-Djava.ext.dirs=")
JMAVSIM_ARGS = ("-tcp", JMAVSIM_TCP, "-r", "250", "-lockstep", "-no-gui")
"""jMAVSim headless, lockstep with PX4, 250 Hz sensor rate."""


class SitlError(EagleMissionError):
    """PX4 SITL could not be started or stopped; the message names the cause and the fix."""


@dataclass(frozen=True)
class SitlOptions:
    """Where PX4 is and which simulator to run."""

    build_dir: Path
    sim: str = "sih"
    jmavsim_jar: Path | None = None
    ready_timeout_s: float | None = None
    """None: :data:`READY_TIMEOUT_S` of the simulator."""
    workdir_parent: Path | None = None
    """Where the fresh working directory is made (None: the system's temporary folder)."""

    @property
    def px4_bin(self) -> Path:
        return self.build_dir / "bin" / "px4"

    @property
    def timeout_s(self) -> float:
        return self.ready_timeout_s or READY_TIMEOUT_S[self.sim]


def resolve_options(*, build: str | Path | None = None, sim: str | None = None,
                    jmavsim_jar: str | Path | None = None, ready_timeout_s: float | None = None,
                    workdir_parent: Path | None = None) -> SitlOptions:
    """Options from the arguments, else the environment; raises :class:`SitlError` naming
    what is missing and how to provide it."""
    raw_build = build or os.environ.get(ENV_PX4_BUILD)
    if not raw_build:
        raise SitlError(f"no PX4 build given: pass --build DIR or set {ENV_PX4_BUILD} to "
                        "PX4-Autopilot/build/px4_sitl_default (make px4_sitl_default)")
    build_dir = Path(raw_build).expanduser().resolve()
    if not (build_dir / "bin" / "px4").is_file() or not (build_dir / "etc").is_dir():
        raise SitlError(f"PX4 build {build_dir}: no bin/px4 and etc/ there: point it at "
                        "PX4-Autopilot/build/px4_sitl_default (make px4_sitl_default)")
    sim = (sim or os.environ.get(ENV_PX4_SIM) or "sih").lower()
    if sim not in SIMS:
        raise SitlError(f"simulator {sim!r}: use one of {', '.join(SIMS)}")
    jar: Path | None = None
    if sim == "jmavsim":
        raw_jar = jmavsim_jar or os.environ.get(ENV_JMAVSIM_JAR)
        if raw_jar:
            jar = Path(raw_jar).expanduser().resolve()
        else:  # the jar where PX4's tree builds it, next to the build folder
            jar = build_dir.parents[1] / JAR_IN_PX4_TREE if len(build_dir.parents) > 1 else None
        if jar is None or not jar.is_file():
            raise SitlError(f"jMAVSim jar {jar or '(none)'} not found: pass --jmavsim-jar or set "
                            f"{ENV_JMAVSIM_JAR} (ant create_run_jar copy_res in PX4's "
                            "Tools/simulation/jmavsim/jMAVSim)")
        if shutil.which("java") is None:
            raise SitlError("jMAVSim needs Java 17 (java not on PATH): install a JDK, "
                            "e.g. openjdk-17-jdk-headless")
    if ready_timeout_s is not None and not ready_timeout_s > 0:
        raise SitlError(f"ready timeout {ready_timeout_s}: must be > 0 s")
    return SitlOptions(build_dir, sim, jar, ready_timeout_s, workdir_parent)


# ---------------------------------------------------------------------------------------------
# Processes
# ---------------------------------------------------------------------------------------------
def _start_ticks(pid: int) -> int | None:
    """The process's start time (clock ticks since boot), None when it is gone or a zombie;
    tells a pid from a later process that reused it."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()
    if fields[0] in ("Z", "X"):
        return None
    return int(fields[19])


@dataclass
class Proc:
    """One started process: name, pid and start time (identity), log file."""

    name: str
    pid: int
    start_ticks: int
    log: str
    popen: subprocess.Popen[bytes] | None = field(default=None, repr=False, compare=False)

    def alive(self) -> bool:
        if self.popen is not None and self.popen.poll() is not None:
            return False
        return _start_ticks(self.pid) == self.start_ticks


@dataclass
class Px4Instance:
    """A started PX4 (and jMAVSim): what stop() needs, and where the logs are."""

    sim: str
    workdir: str
    procs: list[Proc]
    url: str = OFFBOARD_URL
    ready_s: float = 0.0

    @property
    def pids(self) -> dict[str, int]:
        return {p.name: p.pid for p in self.procs}

    def to_json(self) -> str:
        return json.dumps({"sim": self.sim, "workdir": self.workdir, "url": self.url,
                           "ready_s": self.ready_s,
                           "procs": [{"name": p.name, "pid": p.pid, "start_ticks": p.start_ticks,
                                      "log": p.log} for p in self.procs]}, indent=1)

    @classmethod
    def from_json(cls, text: str) -> Px4Instance:
        d = json.loads(text)
        return cls(str(d["sim"]), str(d["workdir"]),
                   [Proc(str(p["name"]), int(p["pid"]), int(p["start_ticks"]), str(p["log"]))
                    for p in d["procs"]], str(d["url"]), float(d["ready_s"]))


def port_in_use(port: int, kind: socket.SocketKind = socket.SOCK_DGRAM) -> bool:
    """True when ``port`` (UDP, or TCP with ``SOCK_STREAM``) cannot be bound on all interfaces
    (PX4 instance 0 holds UDP 14580 while it runs, jMAVSim listens on TCP 4560)."""
    with socket.socket(socket.AF_INET, kind) as sock:
        if kind == socket.SOCK_STREAM:  # a closed connection's TIME_WAIT is no listener
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(("0.0.0.0", port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return True
            raise
    return False


def wait_until_free(timeout_s: float) -> None:
    """Wait (bounded) until no PX4 SITL instance 0 runs on the machine (UDP 14580 free): one
    started by hand or by another run; raises :class:`SitlError` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while port_in_use(INSTANCE_PORT):
        if time.monotonic() > deadline:
            raise SitlError(f"UDP {INSTANCE_PORT} still in use after {timeout_s:g} s: a PX4 SITL "
                            "instance 0 runs on this machine; stop it first "
                            "(python -m eaglemission.lab.px4 stop)")
        time.sleep(0.5)


def _spawn(name: str, argv: list[str], *, cwd: Path, env: dict[str, str], log: Path) -> Proc:
    with open(log, "wb") as out:
        popen = subprocess.Popen(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=out,
                                 stderr=subprocess.STDOUT, start_new_session=True)
    ticks = _start_ticks(popen.pid)
    return Proc(name, popen.pid, ticks if ticks is not None else -1, str(log), popen)


class _LogWatch:
    """Reads a growing log file for lines, bounded by a deadline."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.text = ""
        self._f: IO[str] | None = None

    def seen(self, needle: str) -> bool:
        if self._f is None:
            try:
                self._f = open(self.path, encoding="utf-8", errors="replace")  # noqa: SIM115
            except OSError:
                return False
        self.text += self._f.read()
        return needle in self.text

    def tail(self, lines: int = 15) -> str:
        return "\n".join(self.text.splitlines()[-lines:])

    def close(self) -> None:
        if self._f is not None:
            self._f.close()


def _wait_for(watch: _LogWatch, needle: str, procs: list[Proc], deadline: float,
              what: str) -> None:
    while not watch.seen(needle):
        dead = [p for p in procs if not p.alive()]
        if dead:
            raise SitlError(f"{dead[0].name} exited before {what}; see {dead[0].log}:\n"
                            f"{watch.tail()}")
        if time.monotonic() > deadline:
            raise SitlError(f"{what}: not within the timeout; see {watch.path}:\n{watch.tail()}")
        time.sleep(0.1)


def start(opts: SitlOptions) -> Px4Instance:
    """Start PX4 (and jMAVSim) in a fresh working directory and wait for "Ready for takeoff"
    (bounded by ``opts.timeout_s``). On any failure what was started is stopped again."""
    if port_in_use(INSTANCE_PORT):
        raise SitlError(f"UDP {INSTANCE_PORT} is in use: a PX4 SITL instance 0 already runs on "
                        "this machine; stop it first (python -m eaglemission.lab.px4 stop)")
    if opts.sim == "jmavsim" and port_in_use(JMAVSIM_PORT, socket.SOCK_STREAM):
        raise SitlError(f"TCP {JMAVSIM_PORT} is in use: another simulator listens there and PX4 "
                        "would connect to it; stop it first")
    workdir = Path(tempfile.mkdtemp(prefix=f"px4_{opts.sim}.", dir=opts.workdir_parent))
    env = dict(os.environ, PX4_SIM_MODEL=MODELS[opts.sim], HEADLESS="1")
    t0 = time.monotonic()
    deadline = t0 + opts.timeout_s
    inst = Px4Instance(opts.sim, str(workdir), [])
    watch = _LogWatch(workdir / "px4.log")
    try:
        inst.procs.append(_spawn("px4", [str(opts.px4_bin), "-d", str(opts.build_dir / "etc")],
                                 cwd=workdir, env=env, log=workdir / "px4.log"))
        if opts.sim == "jmavsim":
            assert opts.jmavsim_jar is not None
            _wait_for(watch, SIM_WAIT_LINE, inst.procs, deadline, "PX4 waiting for jMAVSim")
            inst.procs.insert(0, _spawn(
                "jmavsim", ["java", *JVM_OPTIONS, "-jar", str(opts.jmavsim_jar), *JMAVSIM_ARGS],
                cwd=opts.jmavsim_jar.parent, env=dict(os.environ), log=workdir / "jmavsim.log"))
        _wait_for(watch, READY_LINE, inst.procs, deadline, f"PX4 ({opts.sim}) ready for takeoff")
    except BaseException:
        stop(inst)
        raise
    finally:
        watch.close()
    inst.ready_s = time.monotonic() - t0
    return inst


def _end(proc: Proc, timeout_s: float) -> str:
    if not proc.alive():
        if proc.popen is not None:
            proc.popen.wait(timeout=timeout_s)
        return f"{proc.name} (pid {proc.pid}): not running"
    os.kill(proc.pid, signal.SIGTERM)
    how = "stopped by SIGTERM"
    deadline = time.monotonic() + timeout_s
    while proc.alive() and time.monotonic() < deadline:
        time.sleep(0.05)
    if proc.alive():
        os.kill(proc.pid, signal.SIGKILL)
        how = f"killed (SIGKILL after {timeout_s:g} s)"
        deadline = time.monotonic() + 5.0
        while proc.alive() and time.monotonic() < deadline:
            time.sleep(0.05)
    if proc.popen is not None:
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.popen.wait(timeout=5.0)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)  # what it started in its own session, if any is left
    if proc.alive():
        raise SitlError(f"{proc.name} (pid {proc.pid}) is still alive after SIGKILL")
    return f"{proc.name} (pid {proc.pid}): {how}"


def stop(inst: Px4Instance, timeout_s: float = 10.0) -> list[str]:
    """Stop the instance's processes (jMAVSim first, then PX4), each by its pid: SIGTERM, then
    SIGKILL after ``timeout_s``. Returns one line per process."""
    return [_end(p, timeout_s) for p in inst.procs]


# ---------------------------------------------------------------------------------------------
# One user of the autopilot at a time
# ---------------------------------------------------------------------------------------------
LOCK_FILE = Path(tempfile.gettempdir()) / "eaglemission-px4-sitl.lock"


@contextlib.contextmanager
def machine_lock(timeout_s: float, path: Path = LOCK_FILE) -> Iterator[None]:
    """Hold the machine's PX4 lock (an exclusive ``flock``) for the block, waiting at most
    ``timeout_s`` for another holder (a test on another xdist worker, another test run)."""
    with open(path, "a+") as f:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise SitlError(f"the PX4 SITL lock {path} was held for more than "
                                    f"{timeout_s:g} s (another test run using PX4?)") from None
                time.sleep(0.2)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def describe(inst: Px4Instance) -> list[str]:
    """Lines for a user: readiness, pids, working directory, the URL to connect to."""
    lines = [f"PX4 ({inst.sim}) ready for takeoff in {inst.ready_s:.1f} s"]
    lines += [f"{p.name.upper()}_PID={p.pid}" for p in inst.procs]
    lines += [f"WORKDIR={inst.workdir}", f"URL={inst.url}"]
    return lines


def state_path(raw: str | None) -> Path:
    return Path(raw) if raw else Path(tempfile.gettempdir()) / "eaglemission-px4-sitl.json"


def read_state(path: Path) -> Px4Instance | None:
    try:
        return Px4Instance.from_json(path.read_text())
    except FileNotFoundError:
        return None
    except (ValueError, KeyError, TypeError) as exc:
        raise SitlError(f"{path}: not a PX4 SITL state file ({exc}): remove it") from exc
