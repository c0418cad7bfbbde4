"""The design card's layout: core imports no plugin, the product never imports the lab, every
package folder is installed, plugin folders are imported only through ``eaglemission.``."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PLUGIN_FOLDERS = ("drivers", "detectors", "estimators", "missions")
PLUGIN_PACKAGES = tuple(f"eaglemission.{f}" for f in PLUGIN_FOLDERS)
LAB_PACKAGE = "eaglemission.lab"


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
            if mod.startswith((*PLUGIN_PACKAGES, LAB_PACKAGE)):
                offenders.append(f"{py.relative_to(REPO)} imports {mod}")
    assert not offenders, offenders


def test_the_product_never_refers_to_the_lab() -> None:
    """What a field computer runs reads on its own: no product module imports the lab, not
    even inside a function or by a module name in a string (the lab reaches the product only
    through entry points: the simulated drivers, the faults section, the judge)."""
    offenders = []
    for mod, path in _module_names().items():
        if _folder(mod) == "lab":
            continue
        offenders += [f"{path.relative_to(REPO)} -> {ref}" for ref in _references(path)
                      if ref == LAB_PACKAGE or ref.startswith(LAB_PACKAGE + ".")]
    assert offenders == []


def test_plugin_folders_never_imported_as_top_level_names() -> None:
    offenders = []
    for folder in (*PLUGIN_FOLDERS, "lab", "eaglemission", "tests", "benchmarks"):
        for py in (REPO / folder).rglob("*.py"):
            for mod in imported_modules(py):
                if mod.split(".")[0] in (*PLUGIN_FOLDERS, "lab"):
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


# -- plugin folders stay apart, and nothing imports in a circle ---------------------------------
FOLDER_OF_PACKAGE = {"eaglemission": "eaglemission", "eaglemission.drivers": "drivers",
                     "eaglemission.detectors": "detectors",
                     "eaglemission.estimators": "estimators", "eaglemission.missions": "missions",
                     "eaglemission.configs": "configs", "eaglemission.lab": "lab"}


def _module_names() -> dict[str, Path]:
    mods = {}
    for pkg, folder in FOLDER_OF_PACKAGE.items():
        for p in (REPO / folder).rglob("*.py"):
            parts = list(p.relative_to(REPO / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join([pkg, *parts])] = p
    return mods


def _references(path: Path) -> set[str]:
    """Every eaglemission module a file imports at run time: module-level and inside
    functions, and module names given as strings (importlib, lazy kernels); imports under
    ``if TYPE_CHECKING:`` do not run and are left out."""
    tree = ast.parse(path.read_text(), filename=str(path))
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip |= {id(n) for n in ast.walk(node)}
    names: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
              and node.value.startswith("eaglemission.") and " " not in node.value):
            names.add(node.value.split(":")[0])
    return {n for n in names if n.startswith("eaglemission")}


def _folder(module: str) -> str:
    best = max((p for p in FOLDER_OF_PACKAGE if module == p or module.startswith(p + ".")),
               key=len)
    return FOLDER_OF_PACKAGE[best]


def test_no_plugin_folder_imports_another() -> None:
    offenders = []
    for mod, path in _module_names().items():
        here = _folder(mod)
        if here in ("eaglemission", "configs", "lab"):  # the lab may use every product part
            continue
        for ref in _references(path):
            there = _folder(ref)
            if there not in ("eaglemission", here):
                offenders.append(f"{path.relative_to(REPO)} -> {ref}")
    assert offenders == []


def test_no_import_cycle() -> None:
    mods = _module_names()

    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {m: {r for ref in _references(p) if (r := resolve(ref)) and r != m}
             for m, p in mods.items()}
    # Tarjan's strongly connected components: any component of two or more is a cycle
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    assert cycles == []


def test_modules_and_classes_stay_small() -> None:
    """No module over 600 lines (numba kernels aside) and no class over 400."""
    big = []
    for path in _module_names().values():
        text = path.read_text()
        kernel = path.name == "kernels.py" or (path.name.startswith("_")
                                               and path.name.endswith("_kernel.py"))
        if not kernel and len(text.splitlines()) > 600:
            big.append(f"{path.relative_to(REPO)}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > 400:
                big.append(f"{path.relative_to(REPO)}:{node.name}: "
                           f"{node.end_lineno - node.lineno + 1} lines")
    assert big == []
