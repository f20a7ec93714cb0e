"""docs/serve.md's commands, run as written against a scripted RTU peer on a
pseudo-terminal in place of /dev/ttyUSB0 (and a free port in place of 502),
and contrib/pymb-serve.service checked by systemd."""

from __future__ import annotations

import shlex
import shutil
import subprocess
from pathlib import Path

from conftest import ROOT
from docblocks import claim
from peers import PtyPeer
from servekit import Served
from unitkit import unit_of, verify_unit

from pymb.cli import EXIT_USAGE, build_parser

UNIT = ROOT / "contrib" / "pymb-serve.service"


def test_the_serve_commands_run_and_mbpoll_reads_through_them() -> None:
    (serve_block, client_block) = claim("docs/serve.md", "sh", how="run")
    with PtyPeer() as peer:
        for line in serve_block.lines():
            argv = shlex.split(line)
            assert argv[:2] == ["pymb", "serve"]
            argv = [peer.port if a == "/dev/ttyUSB0" else a for a in argv[2:]]
            i = argv.index("--listen")
            listen = argv[i + 1]
            del argv[i:i + 2]
            with Served(*argv, listen="127.0.0.1:0") as s:
                if listen.endswith(":5020") and shutil.which("mbpoll"):
                    (client,) = client_block.lines()
                    cargv = shlex.split(client.replace("5020", str(s.port)))
                    r = subprocess.run(cargv, capture_output=True, text=True, timeout=30)
                    assert r.returncode == 0, r.stdout + r.stderr
                    # mbpoll's -r is 1-based: registers 0..9 of unit 1
                    assert f"[10]: \t{(9 * 7)}" in r.stdout
                assert s.stop() == 0


def test_systemd_accepts_the_serve_unit(tmp_path: Path) -> None:
    verify_unit(UNIT, "serve", tmp_path)


def test_the_serve_units_command_line_is_one_pymb_takes() -> None:
    s = unit_of(UNIT)["Service"]
    assert s["Restart"] == "on-failure"
    assert s["RestartPreventExitStatus"] == str(EXIT_USAGE)
    args = build_parser("serve").parse_args(s["ExecStart"].split()[1:])
    assert args.command == "serve"
    assert args.listen == "0.0.0.0:502"
    assert args.quiet
