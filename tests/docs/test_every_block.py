"""Every code block of README.md and docs/ is handled by a test, or says why
not: a block that no test's ``claim()`` selects and that carries no
``not-run`` / ``illustrative`` marker with its reason fails here, named by
file and line. The claims are read from the test files themselves (the
literal arguments of each ``claim``/``claim_one`` call), so this check
selects exactly what the runners run. Indented code blocks are refused (they
can carry no marker), and every file in docs/examples is read by a test."""

from __future__ import annotations

import ast

from docblocks import (
    HOW,
    MARKERS,
    ROOT,
    Block,
    claim,
    claim_one,
    indented_blocks,
    page_blocks,
    pages,
)

TESTS = ROOT / "tests"


def _claims() -> tuple[list[tuple[str, Block, str]], list[str]]:
    """(test file:line, block, how) of every block a test claims, and the
    calls whose arguments are not literals."""
    got: list[tuple[str, Block, str]] = []
    bad: list[str] = []
    for path in sorted(TESTS.rglob("*.py")):
        if path.name == "docblocks.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in ("claim", "claim_one")):
                continue
            if any(isinstance(a, ast.Starred) for a in node.args):
                continue  # this file's own call, below
            where = f"{path.relative_to(ROOT)}:{node.lineno}"
            try:
                args = [ast.literal_eval(a) for a in node.args]
                kwargs = {k.arg: ast.literal_eval(k.value) for k in node.keywords if k.arg}
            except ValueError:
                bad.append(where)
                continue
            for block in claim(*args, **kwargs):
                got.append((where, block, kwargs["how"]))
    return got, bad


def test_every_block_is_run_by_a_test_or_marked() -> None:
    claims, bad = _claims()
    assert not bad, "claim() with arguments that are not literals: " + ", ".join(bad)
    assert len(claims) >= 40
    claimed = {(b.page, b.line) for _, b, _ in claims}
    unhandled, unexplained = [], []
    for page in pages():
        for b in page_blocks(page):
            if b.marker:
                if not b.reason:
                    unexplained.append(f"{b.where}: ```{b.lang} {b.marker}: (no reason)")
            elif (b.page, b.line) not in claimed:
                first = b.lines()[0][:60] if b.text else ""
                unhandled.append(f"{b.where}: ```{b.lang} {first}")
    assert not unexplained, "a marker needs its reason:\n" + "\n".join(unexplained)
    assert not unhandled, (
        "code blocks that no test runs and that are not marked (```LANG not-run: REASON or "
        "```LANG illustrative: REASON; docs/development.md):\n" + "\n".join(unhandled))
    assert {how for _, _, how in claims} <= set(HOW)


def test_a_marker_is_one_of_the_known_words() -> None:
    # a misspelt marker ("not_run") would be read as part of the language's info
    # string and leave the block unclaimed and unmarked: caught above; this
    # checks the other way round, a marker word the parser does not know
    odd = []
    for page in pages():
        for b in page_blocks(page):
            line = (ROOT / page).read_text(encoding="utf-8").splitlines()[b.line - 1]
            words = line.strip("`~ ").split()
            if len(words) > 1 and not b.marker:
                odd.append(f"{b.where}: {line.strip()}")
    assert not odd, f"info strings with words that are not a marker ({MARKERS}):\n" + \
        "\n".join(odd)


def test_no_indented_code_blocks() -> None:
    found = [f"{page}:{n}" for page in pages() for n in indented_blocks(page)]
    assert not found, "indented code blocks (write them fenced, with a language):\n" + \
        "\n".join(found)


def test_every_example_file_is_read_by_a_test() -> None:
    sources = "\n".join(p.read_text(encoding="utf-8") for p in TESTS.rglob("*.py"))
    examples = sorted(p for p in (ROOT / "docs" / "examples").iterdir() if p.is_file())
    assert examples
    for path in examples:
        assert f'"{path.name}"' in sources, f"docs/examples/{path.name} is read by no test"


def test_the_documented_marker_is_the_parsers() -> None:
    example = claim_one("docs/development.md", "markdown", how="check",
                        contains="not-run:")
    (block,) = page_blocks("example.md", example.text)
    assert (block.lang, block.marker) == ("sh", "not-run")
    assert block.reason == "installs and starts a systemd unit (root, systemd)"
    assert block.lines() == ["sudo systemctl enable --now pymb"]
    assert any(b.marker == "not-run" for page in pages() for b in page_blocks(page))
