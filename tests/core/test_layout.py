"""The design card's layout: core imports no plugin, every package folder is installed,
plugin folders are imported only through ``eaglemission.``."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PLUGIN_FOLDERS = ("drivers", "detectors", "estimators", "missions")
PLUGIN_PACKAGES = tuple(f"eaglemission.{f}" for f in PLUGIN_FOLDERS)


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_core_imports_no_plugin() -> None:
    offenders = []
    for py in (REPO / "eaglemission").rglob("*.py"):
        for mod in imported_modules(py):
            if mod.startswith(PLUGIN_PACKAGES):
                offenders.append(f"{py.relative_to(REPO)} imports {mod}")
    assert not offenders, offenders


def test_plugin_folders_never_imported_as_top_level_names() -> None:
    offenders = []
    for folder in (*PLUGIN_FOLDERS, "eaglemission", "tests", "benchmarks"):
        for py in (REPO / folder).rglob("*.py"):
            for mod in imported_modules(py):
                if mod.split(".")[0] in PLUGIN_FOLDERS:
                    offenders.append(f"{py.relative_to(REPO)} imports {mod}")
    assert not offenders, offenders


def test_every_package_folder_is_listed_in_pyproject() -> None:
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())
    listed = set(cfg["tool"]["setuptools"]["packages"])
    package_dir = cfg["tool"]["setuptools"]["package-dir"]
    folder_of = {v: k for k, v in package_dir.items()}
    found = set()
    for top, pkg in folder_of.items():
        for init in (REPO / top).rglob("__init__.py"):
            rel = init.parent.relative_to(REPO / top)
            found.add(".".join([pkg, *rel.parts]) if rel.parts else pkg)
    assert found == listed, f"missing: {sorted(found - listed)}, stale: {sorted(listed - found)}"


def test_plugin_packages_import_from_installed_location() -> None:
    import eaglemission.detectors
    import eaglemission.drivers

    assert Path(eaglemission.drivers.__file__).parent == REPO / "drivers"
    assert Path(eaglemission.detectors.__file__).parent == REPO / "detectors"
