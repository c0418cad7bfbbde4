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
