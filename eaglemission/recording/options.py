"""How a flight records (``FlightOptions.record``): the options, the mission file's
``recording`` section turned into them, split-part names and the disk-space check before
take-off (docs/recording.md)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal


@dataclass(frozen=True)
class RecordOptions:
    """How ``run --record FILE.mcap`` records (``FlightOptions.record``)."""

    path: Path
    jpeg_quality: int = 75
    queue_frames: int = 32
    """Frames waiting for the encoder; in real time a frame beyond them is dropped (counted),
    in virtual time the mission waits for room (nothing is dropped)."""
    chunk_s: float = 1.0
    """A chunk is closed (and the file flushed) at least this often, in mission time."""
    chunk_bytes: int = 4 << 20
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    split_mb: float | None = None
    """Go on in ``NAME.001.mcap``... once a file holds this many MB (None: one file)."""
    min_free_mb: float = 0.0
    """Refuse to take off with less free space on the recording's disk."""
    lossless: bool = False
    """PNG frames instead of JPEG: the replay's detector sees exactly the processed pixels
    (``eaglemission replay`` equals the flight only then)."""


def part_path(path: Path, part: int) -> Path:
    """``NAME.mcap`` (part 0), ``NAME.001.mcap``, ``NAME.002.mcap``..."""
    return path if part == 0 else path.with_name(f"{path.stem}.{part:03d}{path.suffix}")


def options_from_config(rec: Any, *, now: datetime | None = None) -> RecordOptions:
    """The :class:`RecordOptions` of a mission file's ``recording`` section, ``{utc}`` in its
    path replaced (``-1``, ``-2``... appended to it for a second flight within the same second);
    raises ValueError when the file exists (recordings are never overwritten)."""
    stamp = (now or datetime.now(UTC)).strftime("%Y%m%dT%H%M%SZ")
    path = Path(str(rec.path).replace("{utc}", stamp))
    k = 0
    while "{utc}" in str(rec.path) and path.exists():  # two flights within a second
        k += 1
        path = Path(str(rec.path).replace("{utc}", f"{stamp}-{k}"))
    if path.suffix.lower() != ".mcap":
        raise ValueError(f"recording.path: must end in .mcap, got {str(rec.path)!r}")
    if path.exists():
        raise ValueError(f"recording.path: {path} exists (recordings are never overwritten): "
                         "choose a new name or put {utc} in it")
    return RecordOptions(path, jpeg_quality=int(rec.quality), split_mb=rec.split_mb,
                         min_free_mb=float(rec.min_free_mb))


def planned(cfg: Any, record: RecordOptions | None, *, use_config: bool) -> RecordOptions | None:
    """How a flight records: ``record`` (``run --record``), else the mission file's
    ``recording`` section when ``use_config``; raises ConfigError for a bad or existing path."""
    if record is not None or not use_config or cfg.recording is None:
        return record
    from eaglemission.errors import ConfigError

    try:
        return options_from_config(cfg.recording)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def disk_check(options: RecordOptions, say: Callable[[str], None] | None = None
               ) -> tuple[str, bool, str]:
    """``(name, passed, detail)``: the free space where the recording goes vs. ``min_free_mb``
    (also said as a dry-run check line)."""
    name, ok, detail = _disk_check(options)
    if say is not None:
        say(f"  [{'ok' if ok else 'FAIL'}] {name}: {detail}")
    return name, ok, detail


def _disk_check(options: RecordOptions) -> tuple[str, bool, str]:
    where = options.path.resolve().parent
    while not where.exists() and where != where.parent:
        where = where.parent  # the recorder creates the missing folders
    try:
        free_mb = shutil.disk_usage(where).free / 1e6
    except OSError as exc:
        return ("recording: disk space", False, f"cannot read the free space at {where}: {exc}")
    ok = free_mb >= options.min_free_mb
    detail = (f"{free_mb:.0f} MB free at {where} (recording {options.path}, needs "
              f"recording.min_free_mb {options.min_free_mb:g})")
    if not ok:
        detail = (f"only {free_mb:.0f} MB free at {where}, below recording.min_free_mb "
                  f"{options.min_free_mb:g}: free space there or record elsewhere")
    return ("recording: disk space", ok, detail)


JPEG_BYTES_PER_PX_Q75 = 0.21
"""Recorded bytes per pixel of a JPEG frame at quality 75 (the simulated scenes at 1280x960:
262 kB a frame, log records included)."""
PNG_BYTES_PER_PX = 2.0
"""Recorded bytes per pixel of a lossless (PNG) frame of the same scenes: about 10x JPEG."""
_JPEG_SCALE = ((1, 0.3), (50, 0.65), (75, 1.0), (85, 1.35), (90, 1.7), (95, 2.5), (100, 5.5))
"""JPEG size relative to quality 75 (libjpeg's usual curve), interpolated."""


def bytes_per_px(options: RecordOptions) -> float:
    if options.lossless:
        return PNG_BYTES_PER_PX
    q = min(100, max(1, options.jpeg_quality))
    for (q0, s0), (q1, s1) in zip(_JPEG_SCALE, _JPEG_SCALE[1:], strict=False):
        if q <= q1:
            return JPEG_BYTES_PER_PX_Q75 * (s0 + (s1 - s0) * (q - q0) / (q1 - q0))
    return JPEG_BYTES_PER_PX_Q75 * _JPEG_SCALE[-1][1]


def expected_size(options: RecordOptions, frame_px: list[int], frames_per_s: float,
                  flight_bound_s: float | None) -> tuple[float, float | None]:
    """``(MB per second of flight, MB for the longest flight)``: every camera recorded at up to
    ``frames_per_s``, ``frame_px`` pixels a frame (pure; an upper estimate)."""
    per_s = sum(frame_px) * frames_per_s * bytes_per_px(options) / 1e6
    return per_s, None if flight_bound_s is None else per_s * flight_bound_s


def _mb(mb: float) -> str:
    return f"{mb / 1000:.1f} GB" if mb >= 1000 else f"{mb:.0f} MB"


def size_line(cfg: Any, options: RecordOptions, asm: Any) -> str:
    """The line said before take-off: the recording's expected size, from the cameras'
    resolution, the mission's frame rate (its plugin's ``recorded_rate_hz(config)``), JPEG or
    PNG, and the longest flight the mission allows (its plugin's ``max_flight_s(config)``)."""
    from eaglemission import registry

    px = [int(c.model.width_px) * int(c.model.height_px) for c in asm.cameras.values()]
    cls = registry.get("missions", cfg.mission.type)
    params = registry.validate_params("missions", cfg.mission.type, cfg.mission.params,
                                      path="mission.params")
    rate_fn, bound_fn = getattr(cls, "recorded_rate_hz", None), getattr(cls, "max_flight_s", None)
    rate = float(rate_fn(params)) if callable(rate_fn) else 10.0
    bound = float(bound_fn(params)) if callable(bound_fn) else None
    per_s, total = expected_size(options, px, rate, bound)
    sizes = ", ".join(f"{c.model.width_px}x{c.model.height_px}" for c in asm.cameras.values())
    kind = "PNG (lossless, about 10x JPEG)" if options.lossless else f"JPEG q{options.jpeg_quality}"
    text = (f"recording {options.path}: {kind}, {len(px)} cameras ({sizes} px) at up to "
            f"{rate:g} frames/s: up to {_mb(per_s)} per second of flight, "
            f"{_mb(per_s * 60)} a minute")
    if total is not None and bound is not None:
        text += f", {_mb(total)} if the mission runs to its timeouts ({bound / 60:.0f} min)"
    return text
