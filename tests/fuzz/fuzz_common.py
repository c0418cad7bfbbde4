"""What every fuzz target shares: the crash type, random values of every kind, and a counter
(used by the hypothesis tests in this folder and by ``benchmarks/fuzz.py``)."""

from __future__ import annotations

import math
import random
import re
from collections import Counter
from dataclasses import dataclass, field
from typing import Any


class FuzzCrash(AssertionError):
    """A target broke its property: an exception escaped, or an output broke the invariant.
    ``case`` is a short repr of the input that did it."""

    def __init__(self, target: str, problem: str, case: Any) -> None:
        text = repr(case)
        self.target, self.problem = target, problem
        self.case = text if len(text) <= 400 else text[:397] + "..."
        super().__init__(f"{target}: {problem}; case: {self.case}")


@dataclass
class Tally:
    """Outcomes per target (``valid``, ``refused``, ... as the target names them) and crashes."""

    outcomes: Counter[str] = field(default_factory=Counter)
    crashes: list[FuzzCrash] = field(default_factory=list)

    def total(self) -> int:
        return sum(self.outcomes.values()) + len(self.crashes)


PROBLEM_LINE = re.compile(r"^[^\n]*?\S[^\n]*?: \S[^\n]*$")
"""``path: problem``: a non-empty place, a colon, a non-empty problem, one line."""


def check_problem_lines(target: str, lines: list[str], case: Any) -> None:
    """Every line must read ``path: problem`` and none may be a traceback."""
    if not lines:
        raise FuzzCrash(target, "refused without saying why", case)
    for line in lines:
        if not PROBLEM_LINE.match(line) or "Traceback" in line:
            raise FuzzCrash(target, f"problem line is not `path: problem`: {line!r}", case)


FLOATS = (0.0, -0.0, 1.0, -1.0, 1e-300, 1e300, -1e300, math.inf, -math.inf, math.nan, 0.5,
          2**63, 2**64 + 0.5, 1e20)
INTS = (0, 1, -1, 2, 255, 256, 2**31 - 1, -2**31, 2**63, 2**64, -2**63 - 1, 10**30)
STRINGS = ("", " ", "a", "type", "params", "null", "~", "yes", "no", "on", "1e3", "nan",
           "simulated", "dtdmi", "rpnp", "0x10", "-", ":", "{", "[", "\u00e9\u00e8", "\u2603",
           "a" * 300, "../../etc/passwd", "/dev/null", "C:\\x", "{utc}")


def random_scalar(rng: random.Random) -> Any:
    """A scalar of a random kind, edge values often."""
    k = rng.randrange(6)
    if k == 0:
        return rng.choice((None, True, False))
    if k == 1:
        return rng.choice(INTS) if rng.random() < 0.5 else rng.randint(-1000, 1000)
    if k == 2:
        return rng.choice(FLOATS) if rng.random() < 0.5 else rng.uniform(-1e4, 1e4)
    if k == 3:
        return rng.choice(STRINGS)
    if k == 4:
        n = rng.randrange(12)
        return "".join(chr(rng.randrange(32, 0x2FF)) for _ in range(n))
    return rng.uniform(-50, 50)


def random_value(rng: random.Random, depth: int = 0) -> Any:
    """A random YAML-able value: scalars, lists and mappings nested up to 4 deep."""
    if depth >= 4 or rng.random() < 0.6:
        return random_scalar(rng)
    if rng.random() < 0.5:
        return [random_value(rng, depth + 1) for _ in range(rng.randrange(5))]
    out: dict[Any, Any] = {}
    for _ in range(rng.randrange(5)):
        key: Any = random_scalar(rng) if rng.random() < 0.2 else rng.choice(STRINGS[:14])
        try:
            out[key] = random_value(rng, depth + 1)
        except TypeError:  # an unhashable key
            continue
    return out
