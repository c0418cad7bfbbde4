"""``eaglemission replay FILE.mcap [CONFIG]``: fly a recording's frames and vehicle answers
through the same detector -> estimator -> state machine in virtual time, and compare the
replay's setpoints, envelope verdicts and state changes with the recording's
(:mod:`eaglemission.recording.compare`; docs/recording.md, "Replaying a recording").

Without CONFIG the mission file embedded in the recording (its ``config`` record) is flown;
with CONFIG that file's detector, estimators and mission params. Either way both cameras and
the vehicle become ``replay`` plugins on the recording. Exit codes: 0 identical, 7 diverged
(the first divergence and a side-by-side summary are printed), 2 the file or config cannot be
used, 1 the replay failed.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eaglemission.commands import Command


@dataclass
class ReplayResult:
    comparison: Any
    """:class:`~eaglemission.recording.compare.Comparison`."""
    flight: Any
    """:class:`~eaglemission.flight.run.FlightResult` of the replay."""
    clock: str
    """How the recording was flown: ``virtual`` or ``wall``."""
    images: str
    """How its frames are stored: ``png`` (lossless) or ``jpeg``."""


def replay(path: str | Path, config: str | Path | None = None,
           say: Callable[[str], None] | None = None) -> ReplayResult:
    """Replay ``path`` (with the mission file ``config``, else the recorded one) and compare;
    ``say`` gets a line per state change as the replay flies. Raises ConfigError for a file or
    config that cannot be replayed."""
    from eaglemission.config import MissionFile, load_config
    from eaglemission.errors import ConfigError
    from eaglemission.flight.run import FlightOptions, fly_sync
    from eaglemission.interfaces import MissionHooks
    from eaglemission.recording.compare import compare, replay_config_data
    from eaglemission.recording.mcap_reader import log_records, metadata

    rec_path = Path(path)
    if not rec_path.is_file():
        raise ConfigError(f"{rec_path}: no such recording (eaglemission run --record FILE.mcap)")
    try:
        meta = metadata(rec_path)
        recorded = list(log_records(rec_path))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{rec_path}: not a readable MCAP recording: {exc}") from exc
    if config is not None:
        base = load_config(config).model_dump(mode="json")
    else:
        cfg_rec = next((r for r in recorded if r.get("kind") == "config"), None)
        if cfg_rec is None:
            raise ConfigError(f"{rec_path}: holds no config record (/log/config): give the "
                              "mission file as CONFIG")
        base = cfg_rec["config"]
    try:
        cfg = MissionFile.model_validate(replay_config_data(base, rec_path))
    except ValueError as exc:
        raise ConfigError(f"{config or rec_path}: cannot replay with this mission file: "
                          f"{exc}") from exc
    def on_state(t_s: float, state: str, reason: str, action: str) -> None:
        if say is not None:
            say(f"  {t_s:7.2f} s  {state}")

    flight = fly_sync(cfg, FlightOptions(hooks=MissionHooks(keep_log=True, on_state=on_state),
                                         record_config=False))
    log = getattr(flight.outcome, "log", None)
    replayed = list(log.records) if log is not None else []
    return ReplayResult(compare(recorded, replayed), flight, meta.get("clock", "?"),
                        meta.get("images", "jpeg"))


def _add(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE.mcap", help="a recording (run --record FILE.mcap)")
    p.add_argument("config", nargs="?", metavar="CONFIG",
                   help="fly this mission file's detector, estimators and mission instead of "
                        "the recorded one (cameras and vehicle still replay the file)")


def _run(args: argparse.Namespace) -> int:
    from eaglemission.errors import ConfigError
    from eaglemission.flight.run import EXIT_CONFIG, EXIT_DONE, EXIT_ERROR, EXIT_REPLAY_DIVERGED

    try:
        print(f"replaying {args.file} ...", flush=True)
        res = replay(args.file, args.config, say=lambda line: print(line, flush=True))
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    flight, cmp = res.flight, res.comparison
    if flight.outcome is None:
        print(f"error: the replay did not fly: {flight.error}", file=sys.stderr)
        return EXIT_CONFIG if flight.exit_code == EXIT_CONFIG else EXIT_ERROR
    print(f"replayed {args.file} ({res.clock}-time recording, {res.images} frames) with "
          f"{args.config or 'the recorded config'}: {flight.outcome.final_state} "
          f"in {flight.wall_s:.1f} s wall")
    print(cmp.headline())
    if cmp.identical:
        return EXIT_DONE
    if res.clock == "wall":
        print("  (a real-time recording: the replay asks at other instants, so it is not "
              "expected to be identical)")
    elif res.images != "png":
        print("  (JPEG frames: the detector sees compression artefacts the flight did not; "
              "record with --record-lossless to replay exactly)")
    assert cmp.divergence is not None
    print("\n".join(cmp.divergence.lines()))
    print("\n".join(cmp.side_by_side()))
    return EXIT_REPLAY_DIVERGED


COMMAND = Command("replay a flight recording (MCAP) through the mission and compare its "
                  "setpoints and state changes with the recording's", _add, _run)
