"""``pymb bench --sections soak`` (not in the default run): a month in an hour.

``pymb log`` of a sensor hub and a CoolPro forwarding to Debian's mosquitto
for ``seconds`` (``$PYMB_MONTH_SECONDS``, default 1800), while what a board
lives through happens to it in turn: the broker restarts and stalls, the
logger is SIGKILLed, the disk (a small tmpfs, as root) fills and is freed,
the wall clock steps forward and back (Debian's libfaketime, when
installed). A supervisor restarts the logger as ``Restart=on-failure``
does. The result: samples in the database against the ids a subscriber
received (duplicates counted), ``PRAGMA integrity_check``, the last logger's
memory and descriptors over the calm last 30 %, and what was left out (no
root, no faketime) with why.
"""

from __future__ import annotations

import collections
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymb.bench.cpuload import status_field
from pymb.bench.subscriber import Subscriber

__all__ = ["DEFAULT_SECONDS", "run_section"]

DEFAULT_SECONDS = 1800.0
NODE = "gw-month"
STORY = ("broker restart", "sigkill", "clock +1h", "broker stall", "disk full", "clock back",
         "sigkill", "broker restart")


def _rss_fds(pid: int) -> tuple[int, int]:
    return status_field(pid, "VmRSS"), len(os.listdir(f"/proc/{pid}/fd"))


class _Supervised:
    """``pymb log`` restarted one second after it ends (Restart=on-failure)."""

    def __init__(self, argv: list[str], env: dict[str, str]) -> None:
        self.argv, self.env = argv, env
        self.exits: list[int] = []
        self.starts = 0
        self.proc = self._start()

    def _start(self) -> subprocess.Popen[bytes]:
        self.starts += 1
        return subprocess.Popen(self.argv, env=self.env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)

    def watch(self) -> int:
        """Restart the logger if it ended; the number of exits so far."""
        code = self.proc.poll()
        if code is not None:
            self.exits.append(code)
            time.sleep(1.0)
            self.proc = self._start()
        return len(self.exits)

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait()


def _tmpfs(where: Path, size_kb: int) -> str | None:
    """Mount a tmpfs; None, or why not."""
    where.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        return "not root: no tmpfs to fill"
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(where)],
                       capture_output=True, text=True, check=False)
    return None if r.returncode == 0 else f"cannot mount a tmpfs: {r.stderr.strip()}"


def _fill(where: Path) -> Path:
    filler = where / "filler"
    with open(filler, "ab") as f:
        chunk = b"\0" * (1 << 16)
        while True:
            try:
                f.write(chunk)
                f.flush()
            except OSError:
                return filler


def _faketime(clock: Path) -> dict[str, str] | None:
    if shutil.which("faketime") is None:
        return None
    lib = subprocess.run(["faketime", "-f", "+0", "sh", "-c", 'printf %s "$LD_PRELOAD"'],
                         capture_output=True, text=True, check=False, timeout=30).stdout
    if "libfaketime" not in lib:
        return None
    clock.write_text("+0\n")
    return {"LD_PRELOAD": lib, "FAKETIME_TIMESTAMP_FILE": str(clock), "FAKETIME_NO_CACHE": "1",
            "FAKETIME_DONT_FAKE_MONOTONIC": "1"}


def _set_clock(clock: Path, spec: str) -> None:
    tmp = clock.with_suffix(".new")
    tmp.write_text(spec + "\n")
    os.replace(tmp, clock)


def _wait(pred: Callable[[], bool], timeout: float) -> bool:
    until = time.monotonic() + timeout
    while time.monotonic() < until:
        if pred():
            return True
        time.sleep(0.2)
    return pred()


def _stopped_full(logger: _Supervised, n: int) -> Callable[[], bool]:
    """True once the logger exited 5 (the full disk) since exit number ``n``."""
    def stopped() -> bool:
        logger.watch()
        return 5 in logger.exits[n:]
    return stopped


def run_section(seconds: float | None, say: Callable[[str], None]) -> dict[str, Any]:
    """The soak's result (JSON-able), or a skip reason."""
    try:
        import paho.mqtt.client  # noqa: F401
    except ImportError:
        return {"status": "skipped", "reason": "paho-mqtt is not installed"}
    from pymb.fleet.broker import Mosquitto, find_mosquitto
    from pymb.sim import SimulatorProcess
    if find_mosquitto() is None:
        return {"status": "skipped", "reason": "mosquitto is not installed"}
    if seconds is None:
        seconds = float(os.environ.get("PYMB_MONTH_SECONDS", DEFAULT_SECONDS))
    left_out: list[str] = []
    with tempfile.TemporaryDirectory(prefix="pymb-bench-month-") as tmp_name:
        tmp = Path(tmp_name)
        card = tmp / "card"
        why = _tmpfs(card, 64 << 10)
        if why is not None:
            left_out.append(f"disk full ({why})")
        clock = tmp / "faketime.rc"
        fake = _faketime(clock)
        if fake is None:
            left_out.append("clock steps (faketime is not installed)")
        sim = SimulatorProcess(["hub:250", "coolpro:40", "--tcp", "127.0.0.1:0"],
                               quiet=True).start()
        broker = Mosquitto(tmp / "broker")
        broker.start()
        sub = Subscriber(broker.port, f"pymb/{NODE}/#", "pymb-bench-month", reconnect=(1, 2))
        db = card / "data.sqlite"
        env = {**os.environ, **(fake or {})}
        logger = _Supervised([sys.executable, "-m", "pymb", "log", "--tcp", sim.endpoint,
                              "hub:250", "coolpro:40", "--interval", "0.1", "--out", str(db),
                              "--quiet", "--mqtt", broker.url, "--mqtt-node", NODE,
                              "--mqtt-drain", "120"], env)
        done: list[str] = []
        samples: list[tuple[int, int]] = []
        every = 0.7 * seconds / (2 * len(STORY))
        calm = collections.deque(["broker restart", "clock +2h"])
        t0 = time.monotonic()
        try:
            while (now := time.monotonic() - t0) < seconds:
                logger.watch()
                what = None
                if now < 0.7 * seconds and int(now / every) > len(done):
                    what = STORY[len(done) % len(STORY)]
                elif calm and now >= (0.8 + 0.1 * (2 - len(calm))) * seconds:
                    what = calm.popleft()
                if what is not None:
                    say(f"soak: {now:.0f} s, {what}")
                    done.append(what)
                    if what == "broker restart":
                        broker.stop()
                        time.sleep(min(5.0, every / 3))
                        broker.start()
                    elif what == "broker stall" and broker.proc is not None:
                        os.kill(broker.proc.pid, signal.SIGSTOP)
                        time.sleep(min(20.0, every / 2))
                        os.kill(broker.proc.pid, signal.SIGCONT)
                    elif what == "sigkill":
                        logger.kill()
                    elif what.startswith("clock") and fake is not None:
                        _set_clock(clock, {"clock +1h": "+3600", "clock back": "+0",
                                           "clock +2h": "+7200"}[what])
                    elif what == "disk full" and why is None:
                        filler = _fill(card)
                        _wait(_stopped_full(logger, len(logger.exits)), 120)
                        filler.unlink()
                if now >= 0.72 * seconds and logger.proc.poll() is None:
                    samples.append(_rss_fds(logger.proc.pid))
                time.sleep(0.5)
            logger.proc.send_signal(signal.SIGTERM)
            final = logger.proc.wait(300)
            con = sqlite3.connect(db)
            try:
                ids = {int(i) for (i,) in con.execute("SELECT id FROM samples")}
                stamps = dict(con.execute("SELECT id, monotonic FROM samples"))
                steps = int(con.execute("SELECT COUNT(*) FROM events WHERE kind = 'clock'")
                            .fetchone()[0])
            finally:
                con.close()
            _wait(lambda: set(sub.ids()) >= ids, 300)
            con = sqlite3.connect(db)
            try:
                integrity = str(con.execute("PRAGMA integrity_check").fetchone()[0])
            finally:
                con.close()
            got = sub.ids()
            # an id with two samples: two stamps at the subscriber, or one that
            # is not the database's
            reused = sum(1 for i, ts in sub.stamps().items()
                         if len(ts) > 1 or (i in stamps and stamps[i] not in ts))
        finally:
            if logger.proc.poll() is None:
                logger.kill()
            sub.close()
            broker.stop()
            sim.stop()
            if why is None:
                subprocess.run(["umount", "-l", str(card)], check=False)
    first, last = samples[len(samples) // 4], samples[-1]
    return {"status": "ok", "seconds": seconds, "samples": len(ids), "received": len(got),
            "distinct": len(set(got)), "duplicates": len(got) - len(set(got)),
            "lost": len(ids - set(got)), "taken_back": len(set(got) - ids),
            "reused": reused,
            "integrity": integrity, "events": done, "left_out": left_out,
            "exits": logger.exits, "final_exit": final, "starts": logger.starts,
            "clock_steps": steps, "rss_kb": [first[0], last[0]], "fds": [first[1], last[1]]}
