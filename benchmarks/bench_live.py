"""What serving a flight live costs (``run --live``, docs/recording.md, "Live view in Foxglove").

    python benchmarks/bench_live.py                  # the embedded mission, MSS detector
    python benchmarks/bench_live.py --short          # a ~27 s flight (FAILSAFE)
    python benchmarks/bench_live.py --image-hz 1 --width 160 --quality 50
    python benchmarks/bench_live.py --realtime       # wall clock: latency p90 with / without

After an untimed warm-up flight, flies the same simulated mission (same seed) twice, without
and with ``--live`` at the given throttle, one Foxglove WebSocket client (the protocol client
of the tests, ``tests/core/foxglove_ws.py``) subscribed to every channel, and prints: the
bytes that client received (WebSocket frames included) per second of flight and per second of
wall time, by channel group; the thumbnails and records it got; the frames processed by both
flights (they must be equal); the frame-to-setpoint latency p90 of both (the runner times
perception on the wall clock even in virtual time); and the wall-time slowdown.
"""

from __future__ import annotations

import argparse
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from eaglemission.missions.mission import ApproachOutcome

from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import FlightOptions, FlightResult, fly_sync
from eaglemission.interfaces import MissionHooks
from eaglemission.recording.live import LiveOptions

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "core"))
from foxglove_ws import FoxgloveClient, Received  # noqa: E402


def _config(detector: str, short: bool) -> MissionFile:
    data = load_config(check_plugins=False).model_dump(mode="json")
    data["detector"] = {"type": detector, "params": {"downscale": 2} if detector == "mss" else {}}
    if short:
        data["mission"]["params"]["timeouts"]["coarse_approach_s"] = 4.0
    return MissionFile.model_validate(data)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _fly(cfg: MissionFile, live: LiveOptions | None, realtime: bool
         ) -> tuple[FlightResult, float, Received | None]:
    out: dict[str, Any] = {}
    thread = None
    if live is not None:
        def read() -> None:
            out["rx"] = FoxgloveClient(live.host, live.port, timeout_s=30.0).read_all(
                until_closed_s=3600.0)
        thread = threading.Thread(target=read, daemon=True)
        thread.start()
    t0 = time.perf_counter()
    res = fly_sync(cfg, FlightOptions(realtime=realtime, live=live,
                                      hooks=MissionHooks(keep_log=False)))
    wall = time.perf_counter() - t0
    if thread is not None:
        thread.join(timeout=30.0)
    if not isinstance(res.outcome, ApproachOutcome):
        sys.exit(f"the flight did not happen: exit {res.exit_code}: {res.error}")
    return res, wall, out.get("rx")


def _group(topic: str) -> str:
    if topic.endswith("/image"):
        return "thumbnails"
    if topic.startswith("/camera/"):
        return "frame info, calibration, model"
    return "log " + topic.removeprefix("/log/")


def _p90(values: list[float]) -> float:
    return float(np.percentile(values, 90)) if values else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    d = LiveOptions()
    ap.add_argument("--image-hz", type=float, default=d.image_hz)
    ap.add_argument("--width", type=int, default=d.image_width_px)
    ap.add_argument("--quality", type=int, default=d.jpeg_quality)
    ap.add_argument("--telemetry-hz", type=float, default=d.telemetry_hz)
    ap.add_argument("--detector", default="mss", help="detector plugin (default: mss, fast)")
    ap.add_argument("--short", action="store_true", help="a ~27 s flight (FAILSAFE)")
    ap.add_argument("--realtime", action="store_true", help="fly on the wall clock")
    args = ap.parse_args(argv)
    cfg = _config(args.detector, args.short)
    live = LiveOptions(port=_free_port(), image_hz=args.image_hz, image_width_px=args.width,
                       jpeg_quality=args.quality, telemetry_hz=args.telemetry_hz)
    _fly(_config(args.detector, True), None, False)  # warm-up: JIT, caches (untimed)
    base, wall_base, _ = _fly(cfg, None, args.realtime)
    res, wall_live, rx = _fly(cfg, live, args.realtime)
    assert isinstance(base.outcome, ApproachOutcome) and isinstance(res.outcome, ApproachOutcome)
    if rx is None:
        sys.exit("the client received nothing")
    ob, ol = base.outcome, res.outcome
    flight_s = ol.sim_s
    stats = res.live or {}
    print(f"mission: {cfg.detector.type} detector, "
          f"{'wall clock' if args.realtime else 'virtual time'}; live: thumbnails "
          f"{args.image_hz:g} Hz x {args.width} px, JPEG {args.quality}, telemetry and "
          f"setpoints {args.telemetry_hz:g} Hz")
    print(f"flight: {flight_s:.1f} s, final state {ol.final_state} (without live: "
          f"{ob.final_state}); frames processed: {ob.result.frames_processed} without, "
          f"{ol.result.frames_processed} with live")
    print(f"sink: {stats.get('messages')} messages published ({stats.get('images')} "
          f"thumbnails, {stats.get('records')} log records), {stats.get('throttled')} "
          f"throttled, {stats.get('dropped')} dropped, {stats.get('errors')} errors")
    groups: dict[str, list[int]] = {}
    for topic, msgs in rx.messages.items():
        g = groups.setdefault(_group(topic), [0, 0])
        g[0] += len(msgs)
        g[1] += sum(len(p) + 13 for _, p in msgs)  # + the messageData header
    total = rx.wire_bytes
    print(f"one client received {total / 1e6:.2f} MB: {total / flight_s / 1e3:.1f} kB per "
          f"second of flight ({total * 8 / flight_s / 1e3:.0f} kbit/s), "
          f"{total / wall_live / 1e3:.1f} kB per wall second")
    for name, (n, b) in sorted(groups.items(), key=lambda kv: -kv[1][1]):
        print(f"  {name:32} {n:5} messages {b / flight_s / 1e3:8.2f} kB/s of flight")
    print(f"frame-to-setpoint latency p90: {_p90(ob.result.latencies_ms):.1f} ms without, "
          f"{_p90(ol.result.latencies_ms):.1f} ms with live"
          + ("" if args.realtime else " (perception timed on the wall clock, plus the "
                                      "frame's age on the virtual clock)"))
    print(f"wall time: {wall_base:.1f} s without, {wall_live:.1f} s with live: slowdown "
          f"x{wall_live / wall_base:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
