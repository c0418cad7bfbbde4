"""Fuzzing the recording readers (tests/fuzz/fuzz_files.py): MCAP into ``eaglemission log``
and ``log --recover``, JSON lines into the mission-log and telemetry readers."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest
from fuzz_files import check_jsonl, check_mcap, mutate_bytes, sample_jsonl, sample_recording
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def samples(tmp_path_factory: pytest.TempPathFactory) -> list[bytes]:
    d = tmp_path_factory.mktemp("rec")
    return [sample_recording(d / "z.mcap"), sample_recording(d / "n.mcap", compression="none")]


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def test_the_samples_read_cleanly(samples: list[bytes], work: Path) -> None:
    assert [check_mcap(work / "s.mcap", s) for s in samples] == ["read/read"] * 2


@settings(FUZZ, max_examples=40)
@given(rand=st.randoms(use_true_random=False))
def test_mutated_recordings_never_crash_log(rand: random.Random, samples: list[bytes],
                                            work: Path) -> None:
    data = mutate_bytes(rand.choice(samples), rand)
    assert check_mcap(work / "m.mcap", data) in ("read/read", "read/refused", "refused/refused",
                                                 "refused/read")


def _huge_length(data: bytes) -> bytes:
    b = bytearray(data)
    b[9:17] = struct.pack("<Q", 2**62)  # the header record's length
    return bytes(b)


@pytest.mark.parametrize("cut", [_huge_length, lambda d: d[:5], lambda d: d[:12],
                                 lambda d: d[:len(d) // 2]],
                         ids=["huge_record_length", "inside_magic", "inside_header", "half"])
def test_recordings_cut_or_lying_about_lengths_read_cleanly(samples: list[bytes], work: Path,
                                                             cut: object) -> None:
    """Fuzzing cases: a cut inside a field (struct.error) or a corrupt length (MemoryError /
    OverflowError) is a clean refusal of ``eaglemission log``, not an exception out of it."""
    for s in samples:
        assert check_mcap(work / "c.mcap", cut(s)) == "read/read"  # type: ignore[operator]


@settings(FUZZ, max_examples=60)
@given(rand=st.randoms(use_true_random=False))
def test_mutated_jsonl_is_read_or_refused(rand: random.Random, work: Path) -> None:
    log, tel = sample_jsonl()
    assert check_jsonl(work, mutate_bytes(log, rand), mutate_bytes(tel, rand))


CASES = Path(__file__).parent / "cases"


def test_atheris_case_a_message_of_an_undefined_channel(work: Path) -> None:
    """A case of benchmarks/atheris_fuzz.py mcap: a chunk (no CRC) with a message whose channel
    was never defined is left out and counted by ``log --recover`` (not a KeyError)."""
    data = (CASES / "atheris_recover_unknown_channel.mcap").read_bytes()
    assert check_mcap(work / "x.mcap", data) in ("read/read", "refused/read", "read/refused",
                                                 "refused/refused")
