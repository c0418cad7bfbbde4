"""What recording a flight as MCAP costs (``run --record FILE.mcap``, docs/recording.md).

    python benchmarks/bench_record.py                 # the embedded mission, MSS detector
    python benchmarks/bench_record.py --quality 60 --short
    python benchmarks/bench_record.py --realtime      # wall clock: latency p90 with / without
    python benchmarks/bench_record.py --realtime --short --pairs 4   # 4 interleaved pairs

After an untimed warm-up flight (JIT compilation, caches), flies the same simulated mission
(same seed) twice, without and with recording, and prints:
the wall-time slowdown ratio (virtual time: how much longer the recorded flight took on this
machine; with ``--realtime`` the frame-to-setpoint latency p90 instead), the frames processed
by each (they must be equal), the frames the recorder dropped, the file's size per second of
flight, and the size per second the two 1280x960 cameras would take if both were processed at
the mission's ``perception.process_rate_hz`` all flight long (the mission grabs a camera only while its
state needs it, so the recorded figure is lower). ``--short``: the coarse approach times out
after 4 s (a ~27 s flight, FAILSAFE), for a quick look. ``--pairs N`` flies N pairs
(without, with, without, with...: a load that changes during the run hits both alike) and
prints each pair's figures and the ratio of the medians; the file figures are the last pair's.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from eaglemission.missions.approach_config import ApproachConfig
from eaglemission.missions.mission import ApproachOutcome
from mcap.records import Channel, Message

from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import FlightOptions, FlightResult, fly_sync
from eaglemission.interfaces import MissionHooks
from eaglemission.recording.mcap_reader import Scan, scan
from eaglemission.recording.options import RecordOptions


def _config(detector: str, short: bool) -> MissionFile:
    data = load_config(check_plugins=False).model_dump(mode="json")
    data["detector"] = {"type": detector, "params": {"downscale": 2} if detector == "mss" else {}}
    if short:
        data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 4.0
    return MissionFile.model_validate(data)


def _fly(cfg: MissionFile, record: RecordOptions | None, realtime: bool
         ) -> tuple[FlightResult, float]:
    t0 = time.perf_counter()
    res = fly_sync(cfg, FlightOptions(realtime=realtime, record=record,
                                      hooks=MissionHooks(keep_log=False)))
    wall = time.perf_counter() - t0
    if not isinstance(res.outcome, ApproachOutcome):
        sys.exit(f"the flight did not happen: exit {res.exit_code}: {res.error}")
    return res, wall


def _p90(res: FlightResult) -> float:
    assert isinstance(res.outcome, ApproachOutcome)
    lat = res.outcome.result.latencies_ms
    return float(np.percentile(lat, 90)) if lat else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quality", type=int, default=RecordOptions.jpeg_quality,
                    help=f"JPEG quality (default {RecordOptions.jpeg_quality}, the default of "
                         "run --record-quality)")
    ap.add_argument("--detector", default="mss", help="detector plugin (default: mss, fast)")
    ap.add_argument("--short", action="store_true", help="a ~27 s flight (FAILSAFE)")
    ap.add_argument("--realtime", action="store_true",
                    help="fly on the wall clock: latency p90 with and without recording")
    ap.add_argument("--pairs", type=int, default=1,
                    help="interleaved pairs of flights (without, with recording)")
    args = ap.parse_args(argv)
    cfg = _config(args.detector, args.short)
    rate = ApproachConfig.of(cfg).perception.process_rate_hz
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        _fly(_config(args.detector, True), None, False)  # warm-up: JIT, caches (untimed)
        p90s: list[tuple[float, float]] = []
        walls: list[tuple[float, float]] = []
        for k in range(max(1, args.pairs)):
            path.unlink(missing_ok=True)
            base, wall_base = _fly(cfg, None, args.realtime)
            rec, wall_rec = _fly(cfg, RecordOptions(path, jpeg_quality=args.quality),
                                 args.realtime)
            p90s.append((_p90(base), _p90(rec)))
            walls.append((wall_base, wall_rec))
            if args.pairs > 1:
                assert isinstance(base.outcome, ApproachOutcome)
                assert isinstance(rec.outcome, ApproachOutcome)
                print(f"pair {k + 1}: latency p90 {p90s[-1][0]:.1f} / {p90s[-1][1]:.1f} ms, "
                      f"wall {wall_base:.1f} / {wall_rec:.1f} s (without / with), frames "
                      f"{base.outcome.result.frames_processed} / "
                      f"{rec.outcome.result.frames_processed}", flush=True)
        st = Scan()
        frame_channels: set[int] = set()
        sizes = []
        for r in scan(path, st):
            if isinstance(r, Channel) and r.topic.endswith("/frame"):
                frame_channels.add(r.id)
            elif isinstance(r, Message) and r.channel_id in frame_channels:
                sizes.append(json.loads(r.data)["jpeg_bytes"])
        size_mb = path.stat().st_size / 1e6
    assert isinstance(base.outcome, ApproachOutcome) and isinstance(rec.outcome, ApproachOutcome)
    ob, orec = base.outcome, rec.outcome
    stats = rec.recording or {}
    flight_s = orec.sim_s
    print(f"mission: {cfg.detector.type} detector, perception.process_rate_hz {rate:g}, "
          f"{'wall clock' if args.realtime else 'virtual time'}, JPEG quality {args.quality}")
    print(f"flight: {flight_s:.1f} s, final state {orec.final_state} (unrecorded: "
          f"{ob.final_state})")
    print(f"frames processed: unrecorded {ob.result.frames_processed}, recorded "
          f"{orec.result.frames_processed}")
    print(f"frames recorded {stats.get('frames_written')}, dropped by the recorder "
          f"{stats.get('frames_dropped')}, write errors {stats.get('write_errors')}")
    if args.realtime:
        p90b, p90r = (float(np.median([p[i] for p in p90s])) for i in (0, 1))
        print(f"frame-to-setpoint latency p90 (median of {len(p90s)}): {p90b:.1f} ms without, "
              f"{p90r:.1f} ms with recording (x{p90r / p90b:.2f})")
    wall_base, wall_rec = (float(np.median([w[i] for w in walls])) for i in (0, 1))
    print(f"wall time (median of {len(walls)}): {wall_base:.1f} s without, {wall_rec:.1f} s "
          f"with recording: slowdown x{wall_rec / wall_base:.2f}")
    mean_kb = float(np.mean(sizes)) / 1e3 if sizes else float("nan")
    print(f"file: {size_mb:.1f} MB, {size_mb / flight_s:.2f} MB per second of flight "
          f"({st.chunks} chunks, mean JPEG {mean_kb:.0f} kB)")
    print(f"both 1280x960 cameras at {rate:g} Hz all flight long: "
          f"{2 * rate * mean_kb / 1e3:.2f} MB per second of flight")
    return 0


if __name__ == "__main__":
    sys.exit(main())
