"""The repository stands on its own: no file names a path outside it, and the
device notes' worked values are pymb's."""

from __future__ import annotations

import re
from array import array
from pathlib import Path

from docblocks import claim_one

import pymb
from pymb.devices.coolpro import decode_identity, decode_telemetry

ROOT = Path(__file__).resolve().parents[2]
NOTES = ROOT / "docs" / "device-notes.md"

#: Where a clone has nothing: the reference material beside the development
#: checkout, and the development machine's own paths (spelled apart, so this
#: file does not match itself).
OUTSIDE = re.compile("|".join(re.escape(s) for s in ("/" + "work/", "../" + "shared",
                                                       "shared" + "/specs")))
SKIP_DIRS = {".git", ".venv", "build", "dist", "__pycache__", ".pytest_cache", ".ruff_cache",
             ".mypy_cache", ".hypothesis"}


def _project_files() -> list[Path]:
    out = []
    for path in ROOT.rglob("*"):
        rel = path.relative_to(ROOT).parts
        if any(p in SKIP_DIRS or p.endswith(".egg-info") or p.startswith(".venv") for p in rel):
            continue
        if path.is_file() and path.suffix not in {".so", ".o", ".a", ".png", ".sqlite"}:
            out.append(path)
    return out


def test_no_file_names_a_path_outside_the_repository() -> None:
    files = _project_files()
    assert any(f.name == "pymb.h" for f in files)
    found = []
    for path in files:
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if OUTSIDE.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not found, "\n".join(found)


def _worked(kind: str) -> list[tuple[list[int], str]]:
    block = claim_one("docs/device-notes.md", "text", how="compare").text
    rows = []
    for line in block.splitlines():
        name, rest = line.split(" ", 1)
        if name == kind:
            left, right = rest.split(" = ")
            rows.append(([int(w, 16) if w.startswith("0x") or len(w) == 2 else int(w)
                          for w in left.split()], right))
    assert rows, kind
    return rows


def test_the_worked_crcs_are_pymbs() -> None:
    for frame, want in _worked("crc"):
        assert pymb.crc16(bytes(frame)) == int(want, 16)


def _regs(*words: int) -> array[int]:
    return array("H", [*words, *[0] * (8 - len(words))])


def test_the_worked_coolpro_values_are_pymbs() -> None:
    ((raw, text),) = _worked("telemetry")
    words = [raw[i] << 8 | raw[i + 1] for i in range(0, 8, 2)]
    t = decode_telemetry(_regs(*words))
    decoded = (t.input_voltage_v, t.input_current_a, t.output_voltage_v, t.output_current_a)
    assert [float(v) for v in re.findall(r"[\d.]+", text)] == [round(x, 3) for x in decoded]
    ((uptime, text),) = _worked("uptime")
    assert decode_telemetry(_regs(0, 0, 0, 0, 0, *uptime)).uptime_s == int(text.split()[0])
    ((serial, text),) = _worked("serial")
    assert decode_identity(_regs(*serial)).serial_number == int(text)
