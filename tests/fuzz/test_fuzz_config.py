"""Fuzzing the mission-file loader and ``eaglemission validate`` (tests/fuzz/fuzz_config.py):
never a traceback, always ``path: problem``. Derandomized: the same examples on every run."""

from __future__ import annotations

import copy
import random
import tempfile
from pathlib import Path

import pytest
from fuzz_config import (
    CONFIG_FILES,
    base_documents,
    check_document,
    check_file,
    mutate,
    random_text,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eaglemission.commands import checks
from eaglemission.config import plugin_problems, resolve_relative_paths, validate_mapping

FUZZ = settings(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
DOCS = base_documents()
TEXTS = [p.read_text("utf-8") for p in CONFIG_FILES]
yaml_scalars = (st.none() | st.booleans() | st.integers() | st.floats()
                | st.text(max_size=20))
yaml_values = st.recursive(yaml_scalars, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=12), inner, max_size=4),
                           max_leaves=20)


def test_the_shipped_files_pass_except_the_replay_without_its_recording() -> None:
    got = {p.name: check_document(copy.deepcopy(d)) for p, d in zip(CONFIG_FILES, DOCS)}
    assert got == {"field_basler_px4.yaml": "valid", "px4_jmavsim.yaml": "valid",
                   "px4_sitl.yaml": "valid",
                   "replay.yaml": "refused", "sim_gusts.yaml": "valid",
                   "sitl_synthetic.yaml": "valid"}


@settings(FUZZ, max_examples=25)
@given(st.randoms(use_true_random=False))
def test_mutated_valid_files_are_accepted_or_refused_with_path_problem(rand: random.Random) -> None:
    doc = mutate(rand.choice(DOCS), rand)
    assert check_document(doc) in ("valid", "refused")


@settings(FUZZ, max_examples=40)
@given(st.dictionaries(st.sampled_from(sorted(DOCS[0])) | st.text(max_size=8), yaml_values,
                       max_size=6))
def test_random_documents_are_refused_with_path_problem(doc: dict[str, object]) -> None:
    assert check_document(doc) == "refused"


@settings(FUZZ, max_examples=20)
@given(st.randoms(use_true_random=False))
def test_random_yaml_through_the_validate_command_exits_0_or_2(rand: random.Random) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mission.yaml"
        path.write_text(random_text(rand, TEXTS), encoding="utf-8", errors="surrogatepass")
        assert check_file(path) in ("valid", "refused")


@pytest.mark.parametrize("text", ["", "~", "- a\n- b\n", "a: [", "\x00", "{1: 2}", "a: &x\n  b: *x",
                                  "mission: {params: " + "[" * 300 + "]}"])
def test_degenerate_files_exit_2_with_path_problem(tmp_path: Path, text: str) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(text, encoding="utf-8")
    assert check_file(path) == "refused"


def test_invalid_world_params_are_reported_once_by_the_world_not_by_the_camera() -> None:
    """A fuzzing case: ``world.params.seed: {seed: 1}`` is one path problem from the world, not
    the synthetic camera's check failing with pydantic's multi-line dump."""
    doc = copy.deepcopy(DOCS[CONFIG_FILES.index(CONFIG_FILES[0].with_name("sitl_synthetic.yaml"))])
    doc["world"]["params"]["seed"] = {"seed": 1}
    cfg = resolve_relative_paths(validate_mapping(doc, check_plugins=False), None)
    problems = plugin_problems(cfg) + checks.run_checks(cfg)
    assert problems == ["world.params.seed: must be an integer, got {'seed': 1}"]


@pytest.mark.parametrize("key", ["\n", "", " a", "a\tb"])
def test_a_key_that_cannot_print_as_a_word_is_quoted_in_its_path(key: str) -> None:
    """A hypothesis case: an unknown key ``"\\n"`` must not make the problem line
    ``"\\n: unknown key"``, two lines with an empty path."""
    assert check_document({key: None}) == "refused"
