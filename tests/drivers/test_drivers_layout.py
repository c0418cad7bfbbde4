"""The drivers folder keeps to its layout: it imports only the core and itself (at module level,
inside functions, or by importlib), no module is over 600 lines and no class over 400."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

DRIVERS = Path(__file__).resolve().parents[2] / "drivers"
OTHER_PLUGIN_FOLDERS = ("missions", "detectors", "estimators")
MAX_MODULE_LINES = 600
MAX_CLASS_LINES = 400


def _modules() -> list[Path]:
    files = sorted(DRIVERS.rglob("*.py"))
    assert len(files) > 20  # the folder was found
    return files


def _imported_names(tree: ast.AST) -> list[str]:
    names: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.append(node.module)
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", ""))
              in ("import_module", "__import__") and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            names.append(node.args[0].value)
    return names


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(DRIVERS)))
def test_imports_only_the_core_and_drivers(path: Path) -> None:
    bad = []
    for name in _imported_names(ast.parse(path.read_text())):
        top = name.split(".")
        if top[0] in ("drivers", *OTHER_PLUGIN_FOLDERS):
            bad.append(name)  # a plugin folder by its folder name
        elif top[0] == "eaglemission" and len(top) > 1 and top[1] in OTHER_PLUGIN_FOLDERS:
            bad.append(name)
    assert not bad, f"{path.name} imports another plugin folder: {bad}"


def test_the_import_scan_sees_imports_inside_functions_and_importlib() -> None:
    src = ("def f():\n    from eaglemission.missions import sim\n"
           "    importlib.import_module('eaglemission.detectors.dtdmi')\n")
    assert _imported_names(ast.parse(src)) == ["eaglemission.missions",
                                                "eaglemission.detectors.dtdmi"]


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(DRIVERS)))
def test_no_module_over_600_lines_and_no_class_over_400(path: Path) -> None:
    src = path.read_text()
    assert src.count("\n") <= MAX_MODULE_LINES, f"{path.name}: {src.count(chr(10))} lines"
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.ClassDef):
            n = (node.end_lineno or node.lineno) - node.lineno + 1
            assert n <= MAX_CLASS_LINES, f"{path.name}: class {node.name} is {n} lines"
