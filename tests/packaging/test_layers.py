"""The package's floors: every import of a pymb module, at the top of a file,
inside a function or under ``if TYPE_CHECKING:``, runs down to a lower floor
or stays inside its own package, and no module imports itself back through
others (no import circle). Read from the source, so a type-only import
counts as much as one that runs."""

from __future__ import annotations

import ast
import functools
from fnmatch import fnmatchcase
from pathlib import Path

import pymb

PYMB = Path(pymb.__file__).parent


def _package(name: str) -> tuple[str, str]:
    return name, f"{name}.*"


#: The floors, from the ground up (docs/development.md, "Layout"); each entry
#: matches module names (fnmatch). ``pymb._native`` alone, the C library's
#: constants and words, stands below ``pymb.errors``; the submodules of
#: ``pymb._native``, which raise pymb's errors, stand above it.
FLOORS: list[tuple[str, ...]] = [
    ("pymb._native", "pymb.wire", "pymb.extras", "pymb.child", "pymb.jsonvalue"),
    ("pymb.errors",),
    ("pymb._native.*",),
    (*_package("pymb.client"), *_package("pymb.maps"), *_package("pymb.serve")),
    ("pymb", *_package("pymb.devices")),
    (*_package("pymb.aio"), *_package("pymb.sim"), *_package("pymb.store")),
    (*_package("pymb.fleet"), *_package("pymb.service"), "pymb.testing"),
    (*_package("pymb.logger"), *_package("pymb.collect")),
    (*_package("pymb.commands"), *_package("pymb.bench")),
    ("pymb.cli",),  # it loads each command's module by name
    ("pymb.__main__",),
]


def modules(root: Path = PYMB) -> dict[str, Path]:
    """Each module of the package under ``root`` by its dotted name."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports(found: dict[str, Path]) -> dict[str, set[str]]:
    """Each module's imports of the package's modules (``from pymb.x import
    y`` is ``pymb.x.y`` where that is a module, else ``pymb.x``), wherever
    in the file they stand. A name of no source file (the compiled
    extension, ``pymb._pymb_cffi``) is no module here."""
    def resolve(name: str) -> str | None:
        return name if name in found else None

    out: dict[str, set[str]] = {}
    for module, path in found.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        targets: set[str | None] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets |= {resolve(a.name) for a in node.names if a.name.split(".")[0] == "pymb"}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
                if base.split(".")[0] != "pymb":
                    continue
                for a in node.names:
                    full = f"{base}.{a.name}"
                    targets.add(full if full in found else resolve(base))
        out[module] = {t for t in targets if t is not None and t != module}
    return out


def floor_of(module: str) -> list[int]:
    """The floors whose entries match ``module`` (one, in a well-kept house)."""
    return [i for i, names in enumerate(FLOORS) if any(fnmatchcase(module, n) for n in names)]


def _top(module: str) -> str:
    return ".".join(module.split(".")[:2])


def upward(graph: dict[str, set[str]]) -> list[str]:
    """``a -> b`` of each import that does not run to a lower floor: up, or
    sideways into another package on its own floor."""
    bad = []
    for a, targets in sorted(graph.items()):
        fa = floor_of(a)[0]
        for b in sorted(targets):
            fb = floor_of(b)[0]
            if fb > fa or (fb == fa and _top(a) != _top(b)):
                bad.append(f"{a} (floor {fa}) -> {b} (floor {fb})")
    return bad


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles: each group of modules that import each other."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


@functools.cache
def _graph() -> dict[str, set[str]]:
    return imports(modules())


def rooms(graph: dict[str, set[str]], package: str) -> dict[str, set[str]]:
    """The imports between the rooms of ``package``: each module directly in
    it, its ``__init__`` and each subpackage (taken whole, everything under it)."""
    depth = package.count(".") + 1

    def room(module: str) -> str | None:
        if module == package:
            return module
        if not module.startswith(package + "."):
            return None
        return ".".join(module.split(".")[:depth + 1])

    out: dict[str, set[str]] = {}
    for a, targets in graph.items():
        ra = room(a)
        if ra is not None:
            out.setdefault(ra, set()).update(
                rb for rb in map(room, targets) if rb is not None and rb != ra)
    return out


def packages() -> list[str]:
    """The package and each subpackage, by dotted name."""
    return sorted(m for m, path in modules().items() if path.name == "__init__.py")


def test_every_module_stands_on_one_floor() -> None:
    placed = {m: floor_of(m) for m in modules()}
    assert {m: f for m, f in placed.items() if len(f) != 1} == {}, \
        "add the module's package to FLOORS (and to docs/development.md's layout)"


def test_no_import_runs_up_or_sideways() -> None:
    graph = _graph()
    assert sum(len(t) for t in graph.values()) > 500  # the scan sees the imports
    assert upward(graph) == []


def test_no_import_circle() -> None:
    assert circles(_graph()) == []


def test_no_circle_between_the_rooms_of_a_folder() -> None:
    # A folder read as rooms (its modules, each subpackage whole) has no
    # circle either; the one pair is the floor split of FLOORS: the
    # package pymb._native holds the C library's constants, below
    # pymb.errors, and the line that raises pymb's errors, above it.
    found = [group for package in packages() for group in circles(rooms(_graph(), package))]
    assert found == [["pymb._native", "pymb.errors"]]


def test_the_scan_sees_type_only_function_level_and_relative_imports(tmp_path: Path) -> None:
    root = tmp_path / "pymb"
    (root / "store").mkdir(parents=True)
    (root / "__init__.py").write_text("", encoding="utf-8")
    (root / "errors.py").write_text("", encoding="utf-8")
    (root / "store" / "__init__.py").write_text("from .rows import x\n", encoding="utf-8")
    (root / "store" / "rows.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pymb.logger import y\n"
        "def f():\n    import pymb.commands.log\n    from pymb import errors\n",
        encoding="utf-8")
    (root / "logger.py").write_text("from pymb.store.rows import f\nimport paho\n"
                                    "from pymb._pymb_cffi import ffi\n",
                                    encoding="utf-8")
    (root / "commands").mkdir()
    (root / "commands" / "__init__.py").write_text("", encoding="utf-8")
    (root / "commands" / "log.py").write_text("from ..store import rows\n", encoding="utf-8")
    graph = imports(modules(root))
    assert graph == {
        "pymb": set(), "pymb.errors": set(), "pymb.commands": set(),
        "pymb.store": {"pymb.store.rows"},
        "pymb.store.rows": {"pymb.logger", "pymb.commands.log", "pymb.errors"},
        "pymb.logger": {"pymb.store.rows"},
        "pymb.commands.log": {"pymb.store.rows"},
    }
    assert circles(graph) == [["pymb.commands.log", "pymb.logger", "pymb.store.rows"]]
    assert rooms(graph, "pymb") == {
        "pymb": set(), "pymb.errors": set(), "pymb.commands": {"pymb.store"},
        "pymb.store": {"pymb.logger", "pymb.commands", "pymb.errors"},
        "pymb.logger": {"pymb.store"},
    }
    assert rooms(graph, "pymb.store") == {"pymb.store": {"pymb.store.rows"},
                                          "pymb.store.rows": set()}
    assert upward(graph) == [
        "pymb.store.rows (floor 5) -> pymb.commands.log (floor 8)",
        "pymb.store.rows (floor 5) -> pymb.logger (floor 7)",
    ]
