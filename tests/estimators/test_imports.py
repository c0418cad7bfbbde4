"""estimators/ imports only the core and itself: no other plugin folder (drivers, detectors,
missions), neither at module level nor inside functions, nor named in a string (importlib,
``lazy_kernel``)."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
OTHER_PLUGIN_FOLDERS = ("drivers", "detectors", "missions")


def _imported(tree: ast.AST) -> list[tuple[int, str]]:
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level > 1:
                found.append((node.lineno, "." * node.level + (node.module or "")))
            elif node.level == 0 and node.module:
                found.append((node.lineno, node.module))
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
              and node.value.startswith("eaglemission.")):
            found.append((node.lineno, node.value))
    return found


def _foreign(module: str) -> bool:
    if module.startswith(".."):
        return True  # a relative import out of the estimators package
    parts = module.split(".")
    if parts[0] in OTHER_PLUGIN_FOLDERS:
        return True
    return parts[0] == "eaglemission" and len(parts) > 1 and parts[1] in OTHER_PLUGIN_FOLDERS


def test_estimators_import_only_the_core_and_themselves() -> None:
    offenders = []
    for py in sorted((REPO / "estimators").rglob("*.py")):
        tree = ast.parse(py.read_text(), filename=str(py))
        offenders += [f"{py.relative_to(REPO)}:{line} imports {mod}"
                      for line, mod in _imported(tree) if _foreign(mod)]
    assert not offenders, offenders


def test_the_check_sees_imports_inside_functions_and_strings() -> None:
    tree = ast.parse("def f():\n    from eaglemission.missions import x\n"
                     "k = lazy_kernel('eaglemission.detectors._k', 'f')\n")
    assert sorted(m for _, m in _imported(tree) if _foreign(m)) == [
        "eaglemission.detectors._k", "eaglemission.missions"]
