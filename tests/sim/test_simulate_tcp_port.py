"""``pymb simulate --tcp HOST:0`` says the port it bound, in the endpoint line
and in the mbpoll hint, and the hint works as printed (Debian's mbpoll)."""

from __future__ import annotations

import shlex
import shutil
import signal
import subprocess

from conftest import PYMB, PYMB_ENV


def test_the_mbpoll_hint_names_the_port_bound() -> None:
    mbpoll = shutil.which("mbpoll")
    assert mbpoll, "mbpoll is not installed: .ci/setup installs it"
    proc = subprocess.Popen([*PYMB, "simulate", "coolpro:40", "--tcp", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=PYMB_ENV)
    try:
        assert proc.stdout is not None
        assert proc.stderr is not None
        endpoint = proc.stdout.readline().strip()
        host, port = endpoint.rsplit(":", 1)
        assert host == "127.0.0.1"
        assert int(port) > 0
        hints = []
        while (line := proc.stderr.readline()) and "Ctrl-C" not in line:
            if line.strip().startswith("try: "):
                hints.append(line.strip()[len("try: "):])
        (hint,) = hints
        argv = shlex.split(hint)
        assert argv[argv.index("-p") + 1] == port
        assert argv[-1] == host
        done = subprocess.run([mbpoll, *argv[1:]], capture_output=True, text=True, timeout=30,
                              check=False)
        assert done.returncode == 0, done.stdout + done.stderr
        assert "[0]:" in done.stdout  # Vin, read from the simulator at that port
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
    assert proc.returncode == 0
