"""setuptools entry: the cffi extension, the version, the licence, and a fresh
build directory.

cffi cannot be declared in pyproject.toml yet; everything else lives there.
"""

from __future__ import annotations

import atexit
import re
import shutil
import tempfile
from pathlib import Path

import setuptools
from setuptools import setup

HERE = Path(__file__).resolve().parent


def version() -> str:
    """pymb's version from csrc/pymb.h, its one home (pyproject declares it dynamic)."""
    header = (HERE / "csrc" / "pymb.h").read_text()
    parts = []
    for part in ("MAJOR", "MINOR", "PATCH"):
        m = re.search(rf"^#define PYMB_VERSION_{part} (\d+)\s*$", header, re.M)
        if m is None:
            raise SystemExit(f"pymb: csrc/pymb.h defines no PYMB_VERSION_{part}")
        parts.append(m.group(1))
    return ".".join(parts)


# Build out of tree, in a directory of this run's own: setuptools would reuse
# objects left in ./build by an earlier build (it does not see header changes).
build_base = tempfile.mkdtemp(prefix="pymb-build-")
atexit.register(shutil.rmtree, build_base, True)

# The licence as an SPDX expression where setuptools knows one (77 and later:
# the TOML table form warns there); Debian 12's own setuptools (66), which a
# build without isolation uses, takes the plain text.
LICENCE = ({"license_expression": "MIT"}
           if int(setuptools.__version__.split(".")[0]) >= 77 else {"license": "MIT"})

setup(
    version=version(),
    **LICENCE,
    cffi_modules=["build_ffi.py:ffibuilder"],
    options={
        "build": {"build_base": build_base},
        # cffi compiles the extension for the limited API (_pymb_cffi.abi3.so):
        # one wheel serves CPython 3.11 and later.
        "bdist_wheel": {"py_limited_api": "cp311"},
    },
)
