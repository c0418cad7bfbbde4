"""``python -m eaglemission.lab.px4 start|stop``: a fresh PX4 SITL instance for one flight.

    python -m eaglemission.lab.px4 start --sim sih --build PX4-Autopilot/build/px4_sitl_default
    python -m eaglemission.lab.px4 start --sim jmavsim --build DIR --jmavsim-jar JAR
    eaglemission run configs/px4_sitl.yaml --yes        # or configs/px4_jmavsim.yaml
    python -m eaglemission.lab.px4 stop

``start`` prints the pids and the working directory (logs: px4.log, jmavsim.log) and keeps them
in a state file (``--state``, default in the temporary folder) that ``stop`` reads. The build
and the jar may come from EAGLEMISSION_PX4_BUILD and EAGLEMISSION_JMAVSIM_JAR instead.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from eaglemission.lab.px4.sitl import (
    ENV_JMAVSIM_JAR,
    ENV_PX4_BUILD,
    SIMS,
    SitlError,
    describe,
    read_state,
    resolve_options,
    start,
    state_path,
    stop,
)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m eaglemission.lab.px4",
                                description="Start / stop a fresh PX4 SITL instance (SIH or "
                                            "jMAVSim), headless.")
    sub = p.add_subparsers(dest="action", required=True)
    s = sub.add_parser("start", help="start PX4 in an empty working directory and wait until "
                                     "it is ready for takeoff")
    s.add_argument("--sim", choices=SIMS, default=None,
                   help="simulator (default: EAGLEMISSION_PX4_SIM, else sih)")
    s.add_argument("--build", help=f"PX4's build/px4_sitl_default (default: {ENV_PX4_BUILD})")
    s.add_argument("--jmavsim-jar", help="jMAVSim's jmavsim_run.jar (default: "
                                         f"{ENV_JMAVSIM_JAR}, else its place in PX4's tree)")
    s.add_argument("--timeout-s", type=float, default=None,
                   help="wait for 'Ready for takeoff' (default 60 s SIH, 120 s jMAVSim)")
    s.add_argument("--workdir-parent", help="where the fresh working directory is made")
    t = sub.add_parser("stop", help="stop the instance the state file names (SIGTERM by pid, "
                                    "SIGKILL after --timeout-s)")
    t.add_argument("--timeout-s", type=float, default=10.0)
    for q in (s, t):
        q.add_argument("--state", help="state file (default: eaglemission-px4-sitl.json in the "
                                       "temporary folder)")
    return p


def _start(args: argparse.Namespace) -> int:
    path = state_path(args.state)
    old = read_state(path)
    if old is not None and any(p.alive() for p in old.procs):
        raise SitlError(f"an instance started earlier still runs ({old.pids}, state {path}): "
                        "stop it first (python -m eaglemission.lab.px4 stop)")
    opts = resolve_options(build=args.build, sim=args.sim, jmavsim_jar=args.jmavsim_jar,
                           ready_timeout_s=args.timeout_s,
                           workdir_parent=Path(args.workdir_parent) if args.workdir_parent
                           else None)
    inst = start(opts)
    path.write_text(inst.to_json())
    print("\n".join(describe(inst)), flush=True)
    return 0


def _stop(args: argparse.Namespace) -> int:
    path = state_path(args.state)
    inst = read_state(path)
    if inst is None:
        print(f"nothing to stop (no state file {path})")
        return 0
    for line in stop(inst, args.timeout_s):
        print(line)
    path.unlink(missing_ok=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return _start(args) if args.action == "start" else _stop(args)
    except SitlError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
