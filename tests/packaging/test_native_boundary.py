"""One package touches cffi's ``ffi`` and ``lib``: ``pymb._native``. Everything
above it (``pymb.errors``, ``pymb.maps``, the clients) goes through its
functions and constants, and the boundary has no import cycle: the package's
``__init__`` imports nothing of pymb but the extension, ``pymb.errors`` only
that ``__init__``, and the submodules that raise pymb's errors sit above both."""

from __future__ import annotations

import ast
from pathlib import Path

import pymb

PYMB = Path(pymb.__file__).parent


def _imports(path: Path) -> set[str]:
    """The pymb modules a file imports (``from pymb import x`` counts as
    ``pymb.x``), type-only imports included."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("pymb")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pymb"):
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names
                      if (PYMB.parent / node.module.replace(".", "/") / a.name).exists()
                      or (PYMB.parent / f"{node.module.replace('.', '/')}/{a.name}.py").exists()}
    return found


def test_only_pymb_native_imports_the_extension() -> None:
    users = sorted(str(p.relative_to(PYMB.parent)) for p in PYMB.rglob("*.py")
                   if "pymb._pymb_cffi" in _imports(p))
    assert users, "no module imports the extension: the test looks in the wrong place"
    assert [u for u in users if not u.startswith("pymb/_native/")] == []
    assert "pymb/_native/__init__.py" in users
    assert "pymb/_native/mapdecode.py" in users


def test_the_boundary_has_no_import_cycle() -> None:
    init = _imports(PYMB / "_native" / "__init__.py")
    assert init == {"pymb._pymb_cffi"}  # no submodule, no pymb.errors
    errors = _imports(PYMB / "errors.py")
    assert errors == {"pymb._native"}  # the constants and the C library's words
    maps_decode = _imports(PYMB / "maps" / "_decode.py")
    assert "pymb._native.mapdecode" in maps_decode
    assert "pymb.errors" not in _imports(PYMB / "_native" / "mapdecode.py")
