"""The forwarder's outbox bookkeeping: which samples the broker acknowledged
(ranges above the cursor, merged as they arrive), the cursor's key, and the
thread that writes the cursor to the outbox table."""

from __future__ import annotations

import bisect
import ipaddress
import threading

from pymb.fleet.config import MqttConfig
from pymb.store import Outbox

__all__ = ["Acknowledged", "CursorWriter", "destination"]


class Acknowledged:
    """The samples the broker acknowledged: ``cursor``, every id up to which
    was, and the acknowledged ``[lo, hi]`` ranges above it."""

    def __init__(self, cursor: int = 0) -> None:
        self.cursor = cursor
        self.done: list[list[int]] = []  #: acknowledged [lo, hi] ranges above the cursor

    def mark(self, lo: int, hi: int) -> None:
        """Samples lo..hi are acknowledged."""
        if hi <= self.cursor:
            return
        lo = max(lo, self.cursor + 1)
        d = self.done
        i = bisect.bisect_left(d, [lo, lo])
        d.insert(i, [lo, hi])
        # merge neighbours that touch
        j = max(i - 1, 0)
        while j + 1 < len(d):
            if d[j][1] + 1 >= d[j + 1][0]:
                d[j][1] = max(d[j][1], d[j + 1][1])
                del d[j + 1]
            elif j > i:
                break
            else:
                j += 1
        while d and d[0][0] <= self.cursor + 1:
            self.cursor = max(self.cursor, d.pop(0)[1])

    def skip_done(self, after: int) -> int:
        """``after`` moved past the acknowledged range it is at the edge of."""
        for lo, hi in self.done:
            if lo <= after + 1 <= hi:
                return hi
        return after

    def next_done(self, after: int) -> int | None:
        """The first id of the next acknowledged range above ``after``."""
        for lo, _hi in self.done:
            if lo > after:
                return lo
        return None

    def above_cursor(self) -> int:
        """How many samples above the cursor are acknowledged already."""
        return sum(hi - lo + 1 for lo, hi in self.done)


def destination(cfg: MqttConfig, host: str) -> str:
    """The outbox cursor's key for the broker at ``host`` (an address: IPv4-mapped
    IPv6 addresses as IPv4, IPv6 in brackets; a name as it is)."""
    try:
        ip = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        name = host.lower()
    else:
        if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        name = f"[{ip}]" if ip.version == 6 else str(ip)
    group = cfg.group + "/" if cfg.profile == "sparkplug" else ""
    return f"{'mqtts' if cfg.tls else 'mqtt'}://{name}:{cfg.port}/{cfg.profile}/{group}{cfg.node}"



class CursorWriter(threading.Thread):
    """Writes the latest cursor in its own thread and connection: the logger
    holds SQLite's write lock for most of each batch, and the forwarder must
    not wait for it."""

    def __init__(self, path: str) -> None:
        super().__init__(name="pymb-mqtt-cursor", daemon=True)
        self.path = path
        self.dest = ""  #: the cursor's key, set before the first put()
        self.cond = threading.Condition()
        self.value: int | None = None
        self.written: int | None = None
        self.closing = False
        self.error: BaseException | None = None

    def put(self, value: int) -> None:
        """Write ``value`` soon."""
        with self.cond:
            self.value = value
            self.cond.notify()

    def close(self) -> None:
        """Write what is pending, then end."""
        with self.cond:
            self.closing = True
            self.cond.notify()
        self.join(60)

    def run(self) -> None:
        src: Outbox | None = None  # opened at the first write
        try:
            while True:
                with self.cond:
                    while self.value == self.written and not self.closing:
                        self.cond.wait()
                    value, closing = self.value, self.closing
                if value is not None and value != self.written:
                    src = src or Outbox(self.path)
                    src.set_cursor(self.dest, value)
                    self.written = value
                if closing and self.value == self.written:
                    return
        except BaseException as e:
            self.error = e
        finally:
            if src is not None:
                src.close()
