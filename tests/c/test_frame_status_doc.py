"""pymb_frame_strerror(3) says what every pymb_frame_status of pymb.h
means and where a failure record gets it: a status added to the public
header without its line there fails here."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _statuses() -> list[str]:
    header = (ROOT / "csrc" / "pymb.h").read_text()
    body = re.search(r"typedef enum \{([^}]*)\} pymb_frame_status;", header)
    assert body is not None
    text = re.sub(r"/\*.*?\*/", "", body.group(1), flags=re.S)
    return re.findall(r"\b(PYMB_FRAME_[A-Z_]+)\s*=", text)


def test_every_frame_status_is_described_in_its_man_page() -> None:
    page = (ROOT / "csrc" / "man" / "pymb_frame_strerror.3").read_text()
    named = set(re.findall(r"\\fB(PYMB_FRAME_[A-Z_]+)\\fR", page))
    statuses = _statuses()
    assert len(statuses) >= 13  # (the enum as pymb.h has it: OK .. BAD_TID)
    assert [s for s in statuses if s not in named] == []
