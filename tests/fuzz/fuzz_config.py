"""Fuzz target: the mission-file loader and ``eaglemission validate``.

Property: whatever the file holds, validation either accepts it or raises
:class:`~eaglemission.errors.ConfigError` whose every line reads ``path: problem``; the CLI
exits 0 or 2 and never prints a traceback.

Two entries: :func:`check_document` validates a parsed document the way ``validate`` does
(schema, plugin params, cross-section checks) without the YAML text (fast, for mutated
valid files), and :func:`check_file` runs the ``validate`` command itself on a file.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import random
from pathlib import Path
from typing import Any

import yaml
from fuzz_common import FuzzCrash, check_problem_lines, random_scalar, random_value

from eaglemission.commands import checks
from eaglemission.commands.validate import COMMAND as VALIDATE
from eaglemission.config import (
    parse_yaml,
    plugin_problems,
    resolve_relative_paths,
    validate_mapping,
)
from eaglemission.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
CONFIG_DIR = REPO / "configs"
CONFIG_FILES = sorted(CONFIG_DIR.glob("*.yaml"))
TARGET = "config"


def base_documents() -> list[Any]:
    """The shipped mission files, parsed (the seeds every mutation starts from)."""
    return [parse_yaml(p.read_text("utf-8"), source=str(p)) for p in CONFIG_FILES]


# -- mutations of a valid document ---------------------------------------------------------
def _slots(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path inside ``doc`` (mapping keys and list indices)."""
    out: list[tuple[Any, ...]] = []
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        out.append((*path, k))
        out.extend(_slots(v, (*path, k)))
    return out


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    for k in path[:-1]:
        doc = doc[k]
    return doc


def _misspell(rng: random.Random, key: Any) -> Any:
    s = str(key)
    if not s:
        return "x"
    i = rng.randrange(len(s))
    return rng.choice((s[:i] + s[i + 1:], s[:i] + s[i] * 2 + s[i + 1:], s.upper(), s + "_m",
                       s.replace("_", "-")))


def mutate(doc: Any, rng: random.Random, n: int | None = None) -> Any:
    """A deep copy of ``doc`` with 1-4 (or ``n``) random edits: a key dropped, misspelt or
    added; a value replaced by one of another type, an edge number, a list or a mapping;
    a value nested one level deeper or moved to another place."""
    doc = copy.deepcopy(doc)
    for _ in range(n if n is not None else rng.randint(1, 4)):
        slots = _slots(doc)
        if not slots:
            return random_value(rng)
        path = rng.choice(slots)
        parent = _parent(doc, path)
        key = path[-1]
        op = rng.randrange(9)
        if op == 0 and isinstance(parent, dict):
            del parent[key]
        elif op == 0 and isinstance(parent, list):
            del parent[key]
        elif op == 1 and isinstance(parent, dict):
            new = _misspell(rng, key)
            parent[new] = parent.pop(key)
        elif op == 2 and isinstance(parent, dict):
            parent[rng.choice(("extra", "type", "params", str(key) + "2", 7, None))] = \
                random_value(rng)
        elif op == 3:
            parent[key] = random_scalar(rng)
        elif op == 4:
            parent[key] = random_value(rng)
        elif op == 5:
            parent[key] = [parent[key]]
        elif op == 6:
            parent[key] = {str(key): parent[key]}
        elif op == 7:
            other = rng.choice(slots)
            with contextlib.suppress(KeyError, IndexError, TypeError):
                parent[key] = copy.deepcopy(_parent(doc, other)[other[-1]])
        else:
            v = parent[key]
            if isinstance(v, bool) or not isinstance(v, int | float):
                parent[key] = random_scalar(rng)
            else:
                parent[key] = rng.choice((-v, v * 1e6, v + 0.5, str(v), float("nan"), 0))
    return doc


# -- random text ---------------------------------------------------------------------------
def random_text(rng: random.Random, base_texts: list[str]) -> str:
    """A YAML text: a random document, a shipped file cut short, with lines shuffled or
    bytes flipped, or characters YAML treats specially."""
    k = rng.randrange(5)
    if k == 0:
        return yaml.safe_dump(random_value(rng), allow_unicode=True)
    base = rng.choice(base_texts)
    if k == 1:
        return base[: rng.randrange(len(base) + 1)]
    if k == 2:
        lines = base.splitlines()
        i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
        return "\n".join(lines)
    if k == 3:
        chars = list(base)
        for _ in range(rng.randint(1, 8)):
            chars[rng.randrange(len(chars))] = rng.choice("\t :-{}[]&*!|>'\"%@`#,?\\\x00\x7f\u00e9")
        return "".join(chars)
    return "".join(rng.choice(" \n\t:-{}[]&*!|>'\"%@`#,?ab1.\\") for _ in range(rng.randrange(60)))


# -- the property --------------------------------------------------------------------------
def check_document(data: Any) -> str:
    """Validate a parsed document as ``eaglemission validate`` does; ``valid`` or ``refused``,
    or :class:`FuzzCrash`."""
    try:
        cfg = validate_mapping(data, source="<fuzz>", check_plugins=False)
        cfg = resolve_relative_paths(cfg, CONFIG_DIR)
        problems = plugin_problems(cfg) + checks.run_checks(cfg)
    except ConfigError as exc:
        check_problem_lines(TARGET, exc.problems, data)
        return "refused"
    except Exception as exc:
        raise FuzzCrash(TARGET, f"{type(exc).__name__}: {exc}", data) from exc
    if problems:
        check_problem_lines(TARGET, problems, data)
        return "refused"
    return "valid"


def check_file(path: Path) -> str:
    """``eaglemission validate PATH``: exit 0, or 2 with ``invalid: ...`` and ``path: problem``
    lines on stderr; anything else is a :class:`FuzzCrash`."""
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = VALIDATE.run(argparse.Namespace(config=str(path)))
    except Exception as exc:
        raise FuzzCrash(TARGET, f"validate raised {type(exc).__name__}: {exc}",
                        path.read_bytes()[:300]) from exc
    text = err.getvalue()
    if code == 0:
        return "valid"
    if code != 2 or not text.startswith("invalid: "):
        raise FuzzCrash(TARGET, f"validate exited {code} with {text[:200]!r}", path.read_bytes())
    lines = [ln.strip().removeprefix("- ") for ln in text.splitlines()]
    body = [ln for ln in lines[1:] if ln] if "problems:" in lines[0] else [
        lines[0].removeprefix("invalid: ").split(": ", 1)[-1]]
    check_problem_lines(TARGET, body, path.read_bytes()[:300])
    return "refused"
