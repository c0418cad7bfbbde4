"""Coverage-guided fuzzing (atheris, libFuzzer) of the byte-level parsers, beside the seeded
generators of benchmarks/fuzz.py: atheris mutates the bytes towards code not yet covered.

    pip install -e ".[fuzz]"                                   # atheris 3.0.0 (Linux, macOS)
    python benchmarks/atheris_fuzz.py mavlink --runs 100000    # MAVLink bytes into the emulator
    python benchmarks/atheris_fuzz.py config --runs 20000      # YAML bytes into `validate`
    python benchmarks/atheris_fuzz.py mcap --runs 5000         # bytes as a recording: log, --recover

Targets (the properties of tests/fuzz, whose checks these reuse):

* ``mavlink``: the bytes, split at a position they choose, as two datagrams into the
  emulator's receive path (tests/fuzz/fuzz_mavlink.py ``check_stream``): nothing raises, no
  handler fails, the vehicle stays finite, every reply parses;
* ``config``: the bytes as a mission file through ``eaglemission validate`` (fuzz_config.py
  ``check_file``): exit 0, or exit 2 with ``path: problem`` lines, never a traceback;
* ``mcap``: the bytes as an MCAP file through ``log`` and ``log --recover`` (fuzz_files.py
  ``check_mcap``).

The corpus starts from valid inputs (packed MAVLink messages of the handled kinds; the shipped
mission files; a short recording), so mutations start where the parsers do real work. libFuzzer
prints its coverage as it goes; at the end this prints the runs, the outcomes and the crashes
(must be 0); a crash stops the run with the input saved by libFuzzer (``crash-<sha1>``) to keep
as a regression case in tests/fuzz. Exit status: libFuzzer's (0 when nothing crashed).
"""

from __future__ import annotations

import argparse
import collections
import logging
import random
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import atheris

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "fuzz"))

with atheris.instrument_imports():  # the targets and the project code they import
    import fuzz_config
    import fuzz_files
    import fuzz_mavlink
    from fuzz_common import FuzzCrash

OUTCOMES: collections.Counter[str] = collections.Counter()
CRASHES: list[str] = []


def _mavlink_target(work: Path) -> tuple[Callable[[bytes], None], list[bytes]]:
    fm = fuzz_mavlink
    rig = fm.EmulatorRig.new()

    def one(data: bytes) -> None:
        cut = data[0] % (len(data)) if data else 0
        OUTCOMES[fm.check_stream(rig, [data[:cut], data[cut:]])] += 1

    rng = random.Random(1)
    seeds = [b"".join(fm.random_stream(rng, 3)) for _ in range(32)]
    return one, seeds


def _config_target(work: Path) -> tuple[Callable[[bytes], None], list[bytes]]:
    fc = fuzz_config
    path = work / "mission.yaml"

    def one(data: bytes) -> None:
        path.write_bytes(data)
        OUTCOMES[fc.check_file(path)] += 1

    seeds = [p.read_bytes() for p in sorted((REPO / "configs").glob("*.yaml"))]
    return one, seeds


def _mcap_target(work: Path) -> tuple[Callable[[bytes], None], list[bytes]]:
    ff = fuzz_files
    path = work / "x.mcap"

    def one(data: bytes) -> None:
        for old in work.glob("x*.mcap"):
            old.unlink()
        OUTCOMES[ff.check_mcap(path, data)] += 1

    return one, [ff.sample_recording(work / "sample.mcap")]


TARGETS = {"mavlink": _mavlink_target, "config": _config_target, "mcap": _mcap_target}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("target", choices=sorted(TARGETS))
    ap.add_argument("--runs", type=int, default=10_000, help="inputs to try")
    ap.add_argument("--seed", type=int, default=1, help="libFuzzer's seed")
    ap.add_argument("--max-len", type=int, default=4096, help="longest input, bytes")
    args, libfuzzer_args = ap.parse_known_args()
    logging.disable(logging.WARNING)  # the parsers' own warnings on hostile input: expected
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        one, seeds = TARGETS[args.target](work)
        corpus = work / "corpus"
        corpus.mkdir()
        for i, s in enumerate(seeds):
            (corpus / f"seed{i:03d}").write_bytes(s[: args.max_len])
        def test_one_input(data: bytes) -> None:
            try:
                one(data)
            except FuzzCrash as exc:
                CRASHES.append(str(exc))
                print(f"CRASH: {exc}", flush=True)
                _report()
                raise
            if sum(OUTCOMES.values()) == args.runs:  # libFuzzer exits without Python's atexit
                _report()

        print(f"atheris {args.target}: {args.runs} runs, seed {args.seed}, "
              f"{len(seeds)} seed inputs", flush=True)
        atheris.Setup([sys.argv[0], f"-runs={args.runs}", f"-seed={args.seed}",
                       f"-max_len={args.max_len}", "-print_final_stats=1", str(corpus),
                       *libfuzzer_args], test_one_input)
        atheris.Fuzz()  # libFuzzer ends the process itself: the report is an atexit hook
    return 0


def _report() -> None:
    total = sum(OUTCOMES.values())
    print(f"inputs run: {total}; outcomes: {dict(OUTCOMES)}; crashes: {len(CRASHES)}",
          flush=True)


if __name__ == "__main__":
    sys.exit(main())
