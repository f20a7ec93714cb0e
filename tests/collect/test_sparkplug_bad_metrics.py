"""A Sparkplug metric malformed inside (a PropertySet that does not parse, a
float or double field sent as a varint too big for it) is bad input of its
message, for the collector's host and for a DCMD, never an exception out of
them (which ended pymb collect)."""

from __future__ import annotations

import sqlite3

import pytest

from pymb.collect.rows import BadInput
from pymb.collect.sparkplug import SparkplugHost
from pymb.logger.commands import CommandDesk
from pymb.store.commands import CommandLog


def _varint(v: int) -> bytes:
    out = b""
    while True:
        b, v = v & 0x7F, v >> 7
        if not v:
            return out + bytes([b])
        out += bytes([b | 0x80])


def _field(n: int, wire: int, value: int | bytes) -> bytes:
    key = _varint(n << 3 | wire)
    if isinstance(value, int):
        return key + _varint(value)
    return key + _varint(len(value)) + value


NAME = _field(1, 2, b"m")
METRICS = {
    "bad PropertySet": NAME + _field(4, 0, 9) + _field(7, 0, 1) + _field(9, 2, b"\xff"),
    "float as a big varint": NAME + _field(4, 0, 9) + _field(12, 0, 2**40),
    "double as a big varint": NAME + _field(4, 0, 10) + _field(13, 0, 2**68),
}


def _payload(metric: bytes) -> bytes:
    return _field(1, 0, 1800000000000) + _field(2, 2, metric) + _field(3, 0, 0)


@pytest.mark.parametrize("metric", METRICS.values(), ids=list(METRICS))
def test_the_host_says_bad_input(metric: bytes) -> None:
    host = SparkplugHost("g", "h", lambda topic, payload: None, lambda text: None)
    with pytest.raises(BadInput, match="not a Sparkplug B payload"):
        host.rows("spBv1.0/g/NBIRTH/n1", _payload(metric))
    good = NAME + _field(4, 0, 10) + _field(13, 0, 0x3FF8000000000000)  # 1.5
    assert [r[4] for r in host.rows("spBv1.0/g/NBIRTH/n1", _payload(good))] == [1.5]


def test_a_dcmd_with_a_float_too_big_is_ignored_as_not_sparkplug() -> None:
    db = sqlite3.connect(":memory:", isolation_level=None)
    events: list[str] = []
    desk = CommandDesk(CommandLog(lambda f, durable: f(db)), {}, [], events.append)
    assert desk.handle("sparkplug", "dev", _payload(METRICS["float as a big varint"])) is None
    assert any("not a Sparkplug B payload" in e for e in events), events
