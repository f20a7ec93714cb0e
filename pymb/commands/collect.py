"""``pymb collect``: what a fleet of boards publishes, stored once in SQLite or
PostgreSQL (see docs/collect.md)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from typing import Any, TextIO

from pymb.collect import CollectConfig, Collector
from pymb.collect.sqlstore import open_stores
from pymb.commands._common import add_mqtt_access
from pymb.errors import InvalidArgument
from pymb.extras import install_hint
from pymb.fleet.config import MqttConfig

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The flags of ``pymb collect``."""
    p.add_argument("--mqtt", metavar="URL", required=True,
                   help="the broker: mqtt://HOST[:PORT] or mqtts://HOST[:PORT] (TLS)")
    p.add_argument("--out", metavar="TARGET", required=True,
                   help="a SQLite file, or postgresql://USER@HOST[:PORT]/DB "
                        "(password in $PGPASSWORD or ~/.pgpass)")
    p.add_argument("--profile", choices=("plain", "sparkplug"), default="plain",
                   help="what the boards publish: plain JSON (default) or Sparkplug B")
    p.add_argument("--prefix", default="pymb", help="plain topics' prefix (default pymb)")
    p.add_argument("--group", default="pymb", help="Sparkplug group (default pymb)")
    p.add_argument("--share", metavar="NAME",
                   help="share the stream with the other collectors of this NAME "
                        "($share/NAME/...; plain profile)")
    p.add_argument("--host-id", metavar="ID",
                   help="Sparkplug host application id (default pymb-HOSTNAME)")
    p.add_argument("--client-id", metavar="ID",
                   help="MQTT client id, the same across restarts (default "
                        "pymb-collect-PROFILE-HOSTNAME[-SHARE])")
    p.add_argument("--quiet", action="store_true", help="no status line and no summary")
    g = p.add_argument_group("broker access (as pymb log's --mqtt-* options)")
    add_mqtt_access(g, "the password's file (first line); or $PYMB_MQTT_PASSWORD")


def status_text(st: Any, elapsed: float, last: tuple[float, int, int]) -> str:
    """The status line: messages/s and rows/s since the last line, lag, errors."""
    t0, m0, r0 = last
    dt = max(elapsed - t0, 1e-9)
    return (f"{st.messages:,} messages  {(st.messages - m0) / dt:,.0f}/s  "
            f"{st.rows:,} rows  {(st.rows - r0) / dt:,.0f}/s  lag {st.lag:.1f} s  "
            f"bad {st.bad}  db {'ok' if st.db_ok else 'DOWN'}  "
            f"mqtt {'ok' if st.mqtt_ok else 'DOWN'}")


class _Output:
    """Events as lines on stderr; on a terminal, also the status line redrawn
    in place under them."""

    def __init__(self, out: TextIO, quiet: bool) -> None:
        self.out = out
        self.tty = out.isatty()
        self.status = self.tty and not quiet
        self.line = ""

    def event(self, text: str) -> None:
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        try:
            self.out.write(("\r\x1b[K" if self.status else "") + f"pymb collect: {stamp} "
                           f"{text}\n" + (self.line if self.status else ""))
            self.out.flush()
        except (OSError, ValueError):
            pass

    def draw(self, line: str) -> None:
        if not self.status:
            return
        try:
            width = os.get_terminal_size(self.out.fileno()).columns or 80
        except (OSError, ValueError):
            width = 80
        self.line = line if len(line) < width else line[:max(0, width - 2)] + "…"
        try:
            self.out.write("\r\x1b[K" + self.line)
            self.out.flush()
        except (OSError, ValueError):
            self.status = False


def run(args: argparse.Namespace) -> int:
    """Collect until SIGINT or SIGTERM (exit 0 after the batch in hand)."""
    try:
        import paho.mqtt.client  # noqa: F401
    except ImportError:
        raise InvalidArgument(f"pymb collect needs paho-mqtt: {install_hint('collect')}") from None

    mqtt = MqttConfig(url=args.mqtt, node="collector", prefix=args.prefix, group=args.group,
                      user=args.mqtt_user, password_file=args.mqtt_password_file,
                      ca=args.mqtt_ca, cert=args.mqtt_cert, key=args.mqtt_key)
    cfg = CollectConfig(mqtt=mqtt, out=args.out, profile=args.profile, share=args.share,
                        host_id=args.host_id or "", client_id=args.client_id or "")
    out = _Output(sys.stderr, args.quiet)
    stores = open_stores(cfg.out)
    target = stores[0].target
    try:
        col = Collector(cfg, stores, out.event)
        stopping = col.stop

        def on_signal(signum: int, frame: Any) -> None:
            stopping.set()

        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            col.connect()
            started = time.monotonic()
            last = (0.0, 0, 0)
            drawn = 0.0

            def tick() -> None:
                nonlocal last, drawn
                now = time.monotonic()
                if now - drawn >= 1.0:
                    el = now - started
                    out.draw(status_text(col.stats, el, last))
                    last, drawn = (el, col.stats.messages, col.stats.rows), now

            st = col.run(tick)
        finally:
            for s, h in old.items():
                signal.signal(s, h)
    finally:
        for store in stores:
            store.close()
    if out.status:
        out.out.write("\n")
    if not args.quiet:
        el = time.monotonic() - started
        print(f"pymb collect: {st.messages:,} messages, {st.rows:,} rows stored "
              f"({st.duplicates:,} already stored), {st.bad:,} bad, in {el:.1f} s "
              f"into {target}", file=sys.stderr)
    return 0
