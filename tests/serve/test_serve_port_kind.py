"""``pymb serve --port PATH`` where PATH is a directory or a regular file,
which no client's request could ever open as a serial line: one line, exit 2,
before anything listens (a port that does not exist yet is served, answered
0x0A until it appears: an adapter plugged in after the service started)."""

from __future__ import annotations

from pathlib import Path

import pytest
from clikit import no_traceback
from conftest import run_pymb


@pytest.mark.parametrize(("kind", "said"), [("dir", "a directory"), ("file", "a regular file")])
def test_a_port_that_cannot_be_a_serial_line_is_refused(tmp_path: Path, kind: str,
                                                        said: str) -> None:
    port = tmp_path / kind
    if kind == "dir":
        port.mkdir()
    else:
        port.write_text("not a tty\n")
    r = run_pymb("serve", "--port", str(port), "--listen", "127.0.0.1:0", timeout=20)
    no_traceback(r)
    assert r.returncode == 2, r.stderr
    assert r.stderr == f"pymb serve: --port {port} is {said}, not a serial port\n"
