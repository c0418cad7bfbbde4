"""Reading MCAP flight recordings: a linear pass that survives a file cut short (a crash, a
``kill -9``, a full disk), :func:`recover` (a valid copy of everything up to the last
complete chunk) and :func:`summarize` (``eaglemission log FILE.mcap``)."""

from __future__ import annotations

import json
import os
import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, BinaryIO, cast

from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import Writer

MAX_CHUNK_BYTES = 1 << 30
"""A chunk declaring more uncompressed bytes than this is corrupt (the recorder writes 4 MiB)."""


@dataclass
class Scan:
    """What a linear read of a recording found."""

    complete: bool = False
    """The file has its footer (it was closed properly)."""
    chunks: int = 0
    """Complete chunks read."""
    messages: int = 0
    stopped: str = ""
    """Why the read stopped before the footer (a truncated or corrupt record)."""
    topics: Counter[str] = field(default_factory=Counter)


class _Bounded:
    """A file whose ``read(n)`` never asks for more than what is left of it (a corrupt
    length field inside a record must not allocate gigabytes)."""

    def __init__(self, fh: BinaryIO, size: int) -> None:
        self._fh, self._size = fh, size

    def read(self, n: int = -1) -> bytes:
        left = max(0, self._size - self._fh.tell())
        return self._fh.read(left if n < 0 else min(n, left))


def scan(path: str | Path, st: Scan) -> Iterator[Any]:
    """Every Schema, Channel, Message and Metadata record of the file, in file order, up to
    its footer or its last complete chunk (``st`` counts them and says where it stopped); a
    chunk is read only whole (its CRC checked), so a truncated one is left out entirely."""
    channels: dict[int, str] = {}
    with open(path, "rb") as fh:
        # no record is longer than the file: a corrupt length must not allocate gigabytes
        size = max(1, os.fstat(fh.fileno()).st_size)
        it = iter(StreamReader(cast(IO[bytes], _Bounded(fh, size)), emit_chunks=True,
                               record_size_limit=size).records)
        while True:
            try:
                rec = next(it)
            except StopIteration:
                break
            except EndOfFile:
                st.stopped = "the file ends inside a record: cut short"
                break
            except (McapError, EOFError, ValueError, OSError, struct.error,
                    OverflowError) as exc:  # corrupt (struct.error: a field cut short)
                st.stopped = f"{type(exc).__name__}: {exc}".strip()
                break
            if isinstance(rec, Chunk):
                if rec.uncompressed_size > MAX_CHUNK_BYTES:
                    st.stopped = (f"corrupt chunk: declares {rec.uncompressed_size} bytes "
                                  "uncompressed")
                    break
                try:
                    inner = breakup_chunk(rec, validate_crc=True)
                except Exception as exc:  # noqa: BLE001 - a corrupt chunk ends the readable part
                    st.stopped = f"corrupt chunk: {type(exc).__name__}: {exc}"
                    break
                st.chunks += 1
                for r in inner:
                    yield from _count(r, st, channels)
            elif isinstance(rec, Footer):
                st.complete = True
            else:
                yield from _count(rec, st, channels)


def _count(rec: Any, st: Scan, channels: dict[int, str]) -> Iterator[Any]:
    if isinstance(rec, Channel):
        channels[rec.id] = rec.topic
    elif isinstance(rec, Message):
        st.messages += 1
        st.topics[channels.get(rec.channel_id, "?")] += 1
    elif not isinstance(rec, Schema | Metadata):
        return
    yield rec


@dataclass(frozen=True)
class Recovered:
    source: Path
    output: Path
    messages: int
    chunks: int
    complete: bool
    stopped: str
    orphans: int = 0
    """Messages of a channel never defined before them (a corrupt chunk whose CRC was not
    set): left out."""

    def line(self) -> str:
        how = ("the file was complete" if self.complete
               else f"read up to its last complete chunk ({self.stopped or 'end of file'})")
        left = (f"; {self.orphans} messages of undefined channels left out" if self.orphans
                else "")
        return (f"recovered {self.messages - self.orphans} messages from {self.chunks} chunks "
                f"of {self.source} into {self.output}: {how}{left}")


def recover(source: str | Path, output: str | Path | None = None) -> Recovered:
    """Rewrite ``source`` (a recording without a footer: cut short) into a valid MCAP file,
    ``output`` (default ``<stem>.recovered.mcap`` beside it), keeping every message of every
    complete chunk."""
    src = Path(source)
    out = Path(output) if output is not None else src.with_name(src.stem + ".recovered.mcap")
    if out.resolve() == src.resolve():
        raise ValueError("--recover: the output must be another file than the source")
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    st = Scan()
    orphans = 0
    with open(out, "wb") as fh:
        w: Any = Writer(fh)  # mcap's Writer: finish() is untyped
        w.start(profile="", library="eaglemission (recovered)")
        for rec in scan(src, st):
            if isinstance(rec, Schema):
                if rec.id not in schemas:
                    schemas[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                if rec.id not in channels:
                    channels[rec.id] = w.register_channel(
                        rec.topic, rec.message_encoding, schemas.get(rec.schema_id, 0),
                        dict(rec.metadata))
            elif isinstance(rec, Message):
                if rec.channel_id not in channels:
                    orphans += 1
                    continue
                w.add_message(channels[rec.channel_id], log_time=rec.log_time, data=rec.data,
                              publish_time=rec.publish_time, sequence=rec.sequence)
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
        w.finish()
    return Recovered(src, out, st.messages, st.chunks, st.complete, st.stopped, orphans)


def recover_all(source: str | Path, output: str | Path | None = None) -> list[Recovered]:
    """:func:`recover` every part of a recording, split or not: part ``k`` of ``NAME.mcap``
    goes to part ``k`` of ``output`` (default ``NAME.recovered.mcap``, then
    ``NAME.recovered.001.mcap``...), complete parts too, so the recovered parts read together
    as the original did (:func:`messages`)."""
    src = Path(source)
    first = Path(output) if output is not None else src.with_name(src.stem + ".recovered.mcap")
    return [recover(part, first if k == 0 else
                    first.with_name(f"{first.stem}.{k:03d}{first.suffix}"))
            for k, part in enumerate(parts_of(src))]


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The first 8 bytes of every MCAP file (the MCAP specification's magic)."""


def check_mcap(path: str | Path) -> None:
    """Raise ValueError (one line) unless ``path`` starts as an MCAP file (its magic, whole or
    cut short): a JSON-lines mission log, an image or an empty file is not a recording, and
    has nothing to recover."""
    with open(path, "rb") as fh:
        head = fh.read(len(MCAP_MAGIC))
    if head and MCAP_MAGIC.startswith(head):
        return  # the magic, or a recording cut inside it: read as cut short
    if not head:
        raise ValueError("empty file: not an MCAP recording, nothing to read or recover")
    hint = (": a JSON-lines mission log (run --log) is read as text"
            if head.lstrip().startswith(b"{") else "")
    raise ValueError(f"not an MCAP recording (no MCAP magic at its start){hint}; give a file "
                     "written by run --record FILE.mcap")


def parts_of(path: str | Path) -> list[Path]:
    """The files of a recording: ``NAME.mcap`` and, when it was split (``recording.split_mb``),
    ``NAME.001.mcap``, ``NAME.002.mcap``... as long as they follow each other."""
    first = Path(path)
    out = [first]
    while True:
        nxt = first.with_name(f"{first.stem}.{len(out):03d}{first.suffix}")
        if not nxt.exists():
            return out
        out.append(nxt)


def messages(path: str | Path, st: Scan | None = None) -> Iterator[tuple[str, Message]]:
    """(topic, message) of every message of a recording, split or not, in file order, each
    once: the copies a part starts with (``eaglemission.part`` metadata, ``carried``) are left
    out."""
    for part in parts_of(path):
        topics: dict[int, str] = {}
        carried = 0
        for rec in scan(part, st if st is not None else Scan()):
            if isinstance(rec, Metadata) and rec.name == "eaglemission.part":
                carried = int(rec.metadata.get("carried", "0"))
            elif isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                if carried:
                    carried -= 1
                    continue
                yield topics.get(rec.channel_id, ""), rec


def summarize(path: str | Path) -> list[str]:
    """Lines a person reads: completeness (of each part of a split recording), topics and
    counts, state changes, the recorder's stats and the frame counts per camera."""
    out: list[str] = []
    files = parts_of(path)
    all_complete = True
    if len(files) > 1:
        out.append(f"{path}: split recording, {len(files)} parts:")
        for f in files:
            st = Scan()
            for _ in scan(f, st):
                pass
            all_complete = all_complete and st.complete
            out.append(f"  {f.name}: {'complete' if st.complete else 'NO FOOTER (--recover)'}, "
                       f"{st.messages} messages in {st.chunks} chunks, "
                       f"{f.stat().st_size / 1e6:.1f} MB")
    states: list[str] = []
    stats: dict[str, Any] = {}
    counts: Counter[str] = Counter()
    st = Scan()
    t0_ns: int | None = None  # the mission's start: state times as `run` and `replay` print them
    for topic, rec in messages(path, st):
        counts[topic] += 1
        if topic == "/log/start" and t0_ns is None:
            r = json.loads(rec.data)
            t0_ns = int(r.get("t0_ns", r["t_ns"]))
        elif topic == "/log/state":
            r = json.loads(rec.data)
            t_s = r["t_s"] if t0_ns is None else (int(r["t_ns"]) - t0_ns) * 1e-9
            states.append(f"  {t_s:8.2f} s  {r['old']} -> {r['new']} ({r['reason']})")
        elif topic == "/recorder/stats":
            stats = json.loads(rec.data)
    head = "complete" if st.complete else "NO FOOTER (cut short: log --recover)"
    if len(files) > 1:
        head = "all parts complete" if all_complete else "a part is cut short (log --recover it)"
    out.insert(0 if len(files) == 1 else 1 + len(files),
               f"{path}: {head}, {sum(counts.values())} messages in {st.chunks} chunks")
    out += [f"  {n:7d}  {t}" for t, n in sorted(counts.items())]
    if states:
        out.append("state changes (s since the mission's start):" if t0_ns is not None
                   else "state changes (mission clock, s):")
        out += states
    cams = stats.pop("cameras", None) or {}
    if stats:
        out.append("recorder: " + ", ".join(f"{k} {v}" for k, v in stats.items() if v != ""))
    for cam, n in cams.items():
        out.append(f"camera {cam}: {n['grabbed']} frames grabbed = {n['processed']} processed + "
                   f"{n['skipped']} skipped + {n['dropped']} dropped")
    return out


def metadata(path: str | Path) -> dict[str, str]:
    """The recording's ``eaglemission`` metadata (config hash, clock, ``t0_ns``...), read
    from the head of its first file only."""
    for rec in scan(path, Scan()):
        if isinstance(rec, Metadata) and rec.name == "eaglemission":
            return dict(rec.metadata)
        if isinstance(rec, Message):
            break
    return {}


def start_ns(path: str | Path) -> int | None:
    """Where the recorded mission's clock stood when recording began (metadata ``t0_ns``,
    else the ``start`` record); None: no recorded mission in the file."""
    t0 = metadata(path).get("t0_ns")
    if t0 is not None:
        return int(t0)
    for topic, rec in messages(path):
        if topic == "/log/start":
            return int(rec.log_time)
    return None


def log_records(path: str | Path, kinds: tuple[str, ...] | None = None
                ) -> Iterator[dict[str, Any]]:
    """The mission-log records of a recording (``/log/<kind>``), in file order."""
    for topic, rec in messages(path):
        if topic.startswith("/log/") and (kinds is None or topic[5:] in kinds):
            yield json.loads(rec.data)
