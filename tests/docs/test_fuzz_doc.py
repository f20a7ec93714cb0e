"""docs/reliability.md names every libFuzzer target in csrc/fuzz, each with a
seed corpus, and the Makefile's fuzz-run (which CI runs) fuzzes each one."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _targets() -> set[str]:
    return {p.stem for p in (ROOT / "csrc" / "fuzz").glob("fuzz_*.c")}


def test_every_fuzz_target_is_documented_with_what_it_feeds() -> None:
    doc = (ROOT / "docs" / "reliability.md").read_text()
    section = doc[doc.index("- **libFuzzer targets**"):doc.index("- **Device lengths")]
    listed = set(re.findall(r"^  - `(fuzz_\w+)`: \S", section, re.M))
    targets = _targets()
    assert len(targets) >= 6
    assert listed == targets
    rows = set(re.findall(r"^  \| `(fuzz_\w+)` \|", section, re.M))
    assert rows == targets  # a recorded run of each


def test_fuzz_run_covers_every_target_from_its_seeds() -> None:
    make = (ROOT / "csrc" / "Makefile").read_text()
    m = re.search(r"^FUZZ_TARGETS\s*=\s*(.+)$", make, re.M)
    assert m is not None
    assert {f"fuzz_{t}" for t in m.group(1).split()} == _targets()
    for t in _targets():
        seeds = ROOT / "csrc" / "fuzz" / "corpus" / t.removeprefix("fuzz_")
        assert any(seeds.iterdir()), t
