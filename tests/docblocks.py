"""The code blocks of README.md and docs/: where each is, its language, and
which test handles it.

Every code block is fenced (an indented code block is refused by
``tests/docs/test_every_block.py``). A test that runs, compiles, loads or
compares blocks gets them from :func:`claim` (or :func:`claim_one`) with
literal arguments; ``test_every_block.py`` reads those calls in the test
files (the same selection, so the check cannot drift from what is run) and
fails, naming the file and line, on a block that no call selects and that
carries no marker.

A marker is a word after the block's language in its info string, with the
reason (docs/development.md, "Examples in the docs"):

    ```sh not-run: needs root and systemd
    ```text illustrative: a run's figures, which vary

``not-run``: a command no test can run (root, systemd, apt, real hardware,
another machine). ``illustrative``: output shown as an example and not
compared with real output. A marked block is never selected by a claim.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "HOW",
    "MARKERS",
    "ROOT",
    "Block",
    "claim",
    "claim_one",
    "indented_blocks",
    "page_blocks",
    "pages",
]

ROOT = Path(__file__).resolve().parents[1]
MARKERS = ("not-run", "illustrative")
#: what a claiming test does with its blocks
HOW = ("run", "compile", "load", "compare", "parse", "check")

_FENCE = re.compile(r"^( *)(`{3,}|~{3,})(.*)$")  # indented: in a list item
_LIST_ITEM = re.compile(r"^(\s*)([-*+]|\d+[.)])\s+")


@dataclass(frozen=True)
class Block:
    """One fenced code block of a page."""

    page: str  #: relative to the repository: "README.md", "docs/cli.md"
    line: int  #: 1-based line of its opening fence
    lang: str  #: the first word of the info string ("" for none)
    marker: str  #: "not-run", "illustrative" or ""
    reason: str  #: the marker's reason
    text: str  #: the lines between the fences, each with its newline

    @property
    def where(self) -> str:
        """``page:line``, as an editor opens it."""
        return f"{self.page}:{self.line}"

    def lines(self) -> list[str]:
        """The block's lines without their newlines."""
        return self.text.splitlines()


def pages() -> list[str]:
    """README.md and every page under docs/, relative to the repository."""
    docs = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").rglob("*.md"))
    return ["README.md", *docs]


def page_blocks(page: str, text: str | None = None) -> list[Block]:
    """The fenced code blocks of a page (its file, or ``text``), in order."""
    if text is None:
        text = (ROOT / page).read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    out = []
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, info = len(m.group(1)), m.group(2), m.group(3).strip()
        j = i + 1
        while j < len(lines) and lines[j].strip() != fence:
            j += 1
        lang, _, rest = info.partition(" ")
        marker, reason = "", ""
        word, colon, why = rest.strip().partition(":")
        if word in MARKERS:
            marker, reason = word, why.strip() if colon else ""
        body = [line[indent:] if line[:indent].strip() == "" else line.lstrip(" ")
                for line in lines[i + 1:j]]
        out.append(Block(page, i + 1, lang, marker, reason, "".join(body)))
        i = j + 1
    return out


def indented_blocks(page: str) -> list[int]:
    """1-based lines where an indented code block starts (outside fences
    and lists): a line indented by 4 or more after a blank line, under a
    paragraph, heading or nothing."""
    lines = (ROOT / page).read_text(encoding="utf-8").splitlines()
    found = []
    fence = ""
    blank = True
    content = 0  # the content column of the list item we are in (0: none)
    in_code = False
    for n, line in enumerate(lines, 1):
        if fence:
            if line.strip() == fence:
                fence = ""
            continue
        m = _FENCE.match(line)
        if m:
            fence, blank, in_code = m.group(2), False, False
            continue
        if not line.strip():
            blank = True
            continue
        indent = len(line) - len(line.lstrip(" "))
        item = _LIST_ITEM.match(line)
        if indent >= content + 4 and (blank or in_code) and not (item and indent < content + 4):
            if not in_code:
                found.append(n)
            in_code = True
        else:
            in_code = False
            if item:
                content = len(item.group(0))
            elif indent == 0:
                content = 0
        blank = False
    return found


def claim(page: str, lang: str, *, how: str, index: int | None = None,
          contains: str | None = None) -> list[Block]:
    """The unmarked blocks of ``page`` in ``lang`` (only the ``index``-th of
    them, or only those containing ``contains``), which the calling test
    handles as ``how`` says (one of :data:`HOW`). Arguments must be literals:
    ``test_every_block.py`` reads them from the calling file. Never empty."""
    if how not in HOW:
        raise ValueError(f"how must be one of {HOW}, got {how!r}")
    got = [b for b in page_blocks(page) if b.lang == lang and not b.marker]
    if index is not None:
        got = got[index:index + 1]
    if contains is not None:
        got = [b for b in got if contains in b.text]
    if not got:
        raise LookupError(f"{page} has no unmarked {lang!r} block"
                          + (f" #{index}" if index is not None else "")
                          + (f" containing {contains!r}" if contains else ""))
    return got


def claim_one(page: str, lang: str, *, how: str, index: int | None = None,
              contains: str | None = None) -> Block:
    """The one block :func:`claim` selects with these arguments."""
    got = claim(page, lang, how=how, index=index, contains=contains)
    if len(got) != 1:
        raise LookupError(f"{len(got)} blocks of {page} match, not one: "
                          + ", ".join(b.where for b in got))
    return got[0]


# -- output shown in the docs, against real output -----------------------------

NUMBER = r"-?\d[\d,]*(?:\.\d+)?"  #: a number as pymb prints one
SIZE = rf"{NUMBER} (?:B|kB|MB|GB)"  #: a size as pymb prints one


def shape(line: str) -> str:
    """A regular expression that output matches where the doc's ``line``
    shows it: numbers stand for any number, ``…``/``...`` for any text, runs
    of spaces for any run of spaces (columns are fitted to the values), a
    size (``180.2 kB``) for any size."""
    out = []
    for part in re.split(rf"(…|\.\.\.|{SIZE}|{NUMBER}|\s+)", line):
        if part in ("…", "..."):
            out.append(".*")
        elif part and re.fullmatch(SIZE, part):
            out.append(SIZE)
        elif part and part.isspace():
            out.append(r"\s+")
        elif part and re.fullmatch(NUMBER, part):
            out.append(NUMBER)
        else:
            out.append(re.escape(part))
    return "".join(out)


def assert_shaped(block: Block, real: list[str]) -> None:
    """Every line of ``block`` matches the real line at its place."""
    shown = [line for line in block.lines() if line.strip()]
    assert len(real) >= len(shown), (block.where, real)
    for doc, got in zip(shown, real, strict=False):
        assert re.fullmatch(shape(doc.strip()), got.strip()), \
            f"{block.where}: the doc shows\n  {doc.strip()}\npymb prints\n  {got.strip()}"
