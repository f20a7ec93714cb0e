"""Rules of the source tree that keep it a house a maintainer can live in:
every module of the product stays small enough to read in one sitting, and
the SQLite file has one owner (only pymb.store speaks SQL to it), and so has
the collector's database (pymb.collect.sqlstore; pymb.collect.postgres makes
the test server's empty database), and a class name names one class."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PRODUCT = sorted((ROOT / "pymb").rglob("*.py"))
MAX_LINES = 500

#: speaking SQL: a statement run, or a connection opened
SQL = re.compile(r"\.execute(?:many|script)?\(|sqlite3\.connect\(")


def _rel(p: Path) -> str:
    return str(p.relative_to(ROOT))


def test_every_module_is_under_500_lines() -> None:
    long = {_rel(p): n for p in PRODUCT
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert long == {}, f"split these along their seams: {long}"


def test_only_the_store_speaks_sql() -> None:
    # The bench measures storage layouts of its own, in files of its own.
    owners = ("pymb/store/", "pymb/bench/", "pymb/collect/sqlstore.py",
              "pymb/collect/postgres.py")
    outside = [_rel(p) for p in PRODUCT if not _rel(p).startswith(owners)
               and SQL.search(p.read_text(encoding="utf-8"))]
    assert outside == [], f"SQL outside pymb/store: {outside}"


def test_a_class_name_names_one_class() -> None:
    where: dict[str, list[str]] = {}
    for p in PRODUCT:  # a class made inside a function or a class counts too
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(_rel(p))
    assert where["MapDevice"] == ["pymb/devices/mapdevice.py"]  # the scan sees the classes
    shared = {name: sorted(files) for name, files in where.items() if len(files) > 1}
    assert shared == {}, f"one name, one class: rename one of these (or merge them): {shared}"


def test_a_template_hook_is_abstract() -> None:
    # A hook a subclass must supply is an abc.abstractmethod (or a Protocol
    # member): a class that lacks it fails when it is made, and under mypy,
    # not when the hook is first called.
    raising = [f"{_rel(p)}:{node.lineno}" for p in PRODUCT
               for node in ast.walk(ast.parse(p.read_text(encoding="utf-8")))
               if isinstance(node, ast.Raise) and node.exc is not None
               and "NotImplementedError" in ast.unparse(node.exc)]
    assert raising == [], f"make these hooks abstract: {raising}"


def test_the_template_bases_name_their_hooks() -> None:
    from pymb.aio._mirror import Mirrored
    from pymb.bench.worker import PurePythonClient
    from pymb.collect.sqlstore import Store
    from pymb.fleet.profiles import Profile
    from pymb.sim.base import Device
    from pymb.sim.server import SimServer

    hooks = {cls.__name__: set(cls.__abstractmethods__)
             for cls in (Mirrored, PurePythonClient, Store, Profile, Device, SimServer)}
    assert hooks == {
        "Mirrored": {"_submit"},
        "PurePythonClient": {"read"},
        "Store": {"batch", "write"},
        "Profile": {"will", "births", "data", "goodbye"},
        "Device": {"handle"},
        "SimServer": {"_open", "_close", "_serve_once"},
    }
