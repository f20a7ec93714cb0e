"""What a C shop and a packager rely on: one version everywhere, every public C
function exported and documented, and one clear line when a build need is missing.

The install into a DESTDIR, pkg-config, ``man -l``, the ARM builds and the sdist
round trip take minutes and run from ``.ci/run`` (``.ci/check-*``).
"""

from __future__ import annotations

import errno
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from pymb._pymb_cffi import ffi, lib

import pymb

ROOT = Path(__file__).resolve().parents[2]
CSRC = ROOT / "csrc"

needs_make = pytest.mark.skipif(shutil.which("make") is None or shutil.which("cc") is None,
                                reason="needs make and a C compiler")


def _header_version() -> str:
    text = (CSRC / "pymb.h").read_text()
    parts = [re.search(rf"^#define PYMB_VERSION_{p} (\d+)$", text, re.M) for p in
             ("MAJOR", "MINOR", "PATCH")]
    assert all(parts), "pymb.h must define PYMB_VERSION_MAJOR, _MINOR and _PATCH"
    return ".".join(m.group(1) for m in parts if m)


def test_one_version_everywhere() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "version" not in project
    assert "version" in project["dynamic"]  # from pymb.h
    version = _header_version()
    assert pymb.__version__ == version
    assert ffi.string(lib.pymb_version()).decode() == version
    assert importlib.metadata.version("pymb-modbus") == version


def test_strerror_knows_libmodbus_codes_and_the_os_ones() -> None:
    def text(errnum: int) -> str:
        text: str = ffi.string(lib.pymb_strerror(errnum)).decode()
        return text

    codes = ("EMBXILFUN", "EMBXILADD", "EMBXILVAL", "EMBXSFAIL", "EMBXACK", "EMBXSBUSY",
             "EMBXNACK", "EMBXMEMPAR", "EMBXGPATH", "EMBXGTAR", "EMBBADCRC", "EMBBADDATA",
             "EMBBADEXC", "EMBUNKEXC", "EMBMDATA", "EMBBADSLAVE")
    texts = [text(getattr(lib, c)) for c in codes]
    assert len(set(texts)) == len(codes)
    assert not any(t.startswith("Unknown error") for t in texts)
    # [MB-AP] 7's names for the exceptions
    assert text(lib.EMBXSFAIL) == "Server device failure"
    assert text(lib.EMBXSBUSY) == "Server device busy"
    assert text(errno.EINVAL) == os.strerror(errno.EINVAL)
    assert text(errno.ETIMEDOUT) == os.strerror(errno.ETIMEDOUT)


def test_bad_arguments_set_einval_and_say_so() -> None:
    frame = ffi.new("uint8_t[8]")
    ffi.errno = 0
    assert lib.pymb_rtu_append_crc(frame, 7, 8) == -1
    assert ffi.errno == errno.EINVAL
    ffi.errno = 0
    assert lib.pymb_rtu_crc_ok(ffi.NULL, 8) == -1
    assert ffi.errno == errno.EINVAL
    perm = ffi.new("uint8_t[8]", [9] * 8)
    ffi.errno = 0
    assert lib.pymb_map_order(b"ABC", 3, perm) == -1  # widths are 2, 4 or 8
    assert ffi.errno == errno.EINVAL
    assert list(perm) == [9] * 8  # nothing written on failure


@needs_make
def test_every_public_function_is_exported_and_has_a_man_page(tmp_path: Path) -> None:
    """A function added to pymb.h or pymb_modbus.h without a man page fails here."""
    done = subprocess.run(["make", "-s", "-C", str(CSRC), f"B={tmp_path}", "check-exports"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "exported, declared and documented alike" in done.stdout


@needs_make
def test_the_check_catches_a_function_without_a_page(tmp_path: Path) -> None:
    header = tmp_path / "extra.h"
    header.write_text("int pymb_not_documented(int x);\n")
    subprocess.run(["make", "-s", "-C", str(CSRC), f"B={tmp_path}", "lib"], check=True,
                   capture_output=True, timeout=300)
    lib_so = next(tmp_path.glob("libpymb.so.*.*.*"))
    done = subprocess.run(["sh", str(CSRC / "tests" / "check_exports.sh"), str(lib_so),
                           str(CSRC / "man"), str(CSRC / "pymb.h"), str(header)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert "pymb_not_documented" in done.stderr


@needs_make
def test_core_builds_and_passes_without_libmodbus(tmp_path: Path) -> None:
    env = dict(os.environ, PKG_CONFIG="false")
    core = subprocess.run(["make", "-s", "-C", str(CSRC), f"B={tmp_path}", "check-core"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert core.returncode == 0, core.stderr
    assert " 0 failed" in core.stdout
    full = subprocess.run(["make", "-s", "-C", str(CSRC), f"B={tmp_path}", "lib"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert full.returncode != 0
    assert "apt install libmodbus-dev pkg-config" in full.stderr


def _build_ffi(env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(ROOT / "build_ffi.py")], capture_output=True,
                          text=True, env=env, timeout=120, cwd=ROOT)


def test_python_build_without_pkg_config_is_one_clear_line() -> None:
    done = _build_ffi(dict(os.environ, PKG_CONFIG="no-such-pkg-config-for-pymb"))
    assert done.returncode != 0
    assert done.stderr.strip().splitlines() == [
        "pymb: cannot build its C extension: install pkg-config first "
        "(Debian/Ubuntu: sudo apt install pkg-config)"]


def test_python_build_without_libmodbus_is_one_clear_line(tmp_path: Path) -> None:
    if shutil.which("pkg-config") is None:
        pytest.skip("needs pkg-config")
    # A real pkg-config that looks only in an empty directory finds no libmodbus.
    done = _build_ffi(dict(os.environ, PKG_CONFIG_LIBDIR=str(tmp_path), PKG_CONFIG_PATH=""))
    assert done.returncode != 0
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert "sudo apt install libmodbus-dev" in lines[0], done.stderr


@needs_make
def test_makefile_honours_the_usual_variables(tmp_path: Path) -> None:
    """CC, AR, CPPFLAGS, CFLAGS, LDFLAGS, PKG_CONFIG, EMULATOR and WERROR=0 reach the commands."""
    fake_pc = tmp_path / "my-pkg-config"
    fake_pc.write_text("#!/bin/sh\ncase \"$*\" in *--cflags*) echo -I/opt/mb;; "
                       "*--libs*) echo -lmodbus;; esac\n")
    fake_pc.chmod(0o755)
    args = [f"B={tmp_path}/b", "CC=my-cc", "AR=my-ar", "CPPFLAGS=-DMY_CPP",
            "CFLAGS=-O0 -DMY_CFLAGS", "LDFLAGS=-L/my/ldflags", f"PKG_CONFIG={fake_pc}",
            "EMULATOR=my-emulator"]
    dry = subprocess.run(["make", "-n", "-C", str(CSRC), *args, "WERROR=0", "all", "check-core"],
                         capture_output=True, text=True, timeout=60)
    assert dry.returncode == 0, dry.stderr
    out = dry.stdout
    for want in ("my-cc ", "my-ar rcs", "-DMY_CPP", "-DMY_CFLAGS", "-L/my/ldflags", "-I/opt/mb",
                 "my-emulator "):
        assert want in out, want
    assert "-Werror" not in out
    strict = subprocess.run(["make", "-n", "-C", str(CSRC), *args, "all"],
                            capture_output=True, text=True, timeout=60)
    assert "-Werror" in strict.stdout
