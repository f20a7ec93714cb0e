"""What SQLite cannot bind (a sample id beyond 64 bits, a lone surrogate in a
text or a point's name), and JSON nested deeper than a decoder recurses, is
bad input of that one message: refused as the message is parsed, and the
store goes on taking the next batches."""

from __future__ import annotations

from pathlib import Path

import pytest

from pymb.collect.rows import BadInput, plain_sample
from pymb.collect.sqlstore import SqliteStore

GOOD = b'{"time_utc": 1800000000.5, "sample": 7, "values": {"v": 1.5}}'


@pytest.mark.parametrize(("payload", "why"), [
    (b'{"time_utc": 1.0, "sample": 9223372036854775808, "values": {"a": 1}}', "64 bits"),
    (b'{"time_utc": 1.0, "sample": -9223372036854775809, "values": {"a": 1}}', "64 bits|integer"),
    (b'{"time_utc": 1.0, "values": {"a": "\\ud800"}}', "surrogate"),
    (b'{"time_utc": 1.0, "values": {"\\udc00x": 1}}', "surrogate"),
    (b'{"time_utc": 1.0, "values": {"a": ' + b"[" * 100000 + b"]" * 100000 + b"}}",
     "not JSON"),
])
def test_what_sqlite_cannot_bind_is_bad_input(tmp_path: Path, payload: bytes,
                                              why: str) -> None:
    with pytest.raises(BadInput, match=why):
        plain_sample(payload)
    store = SqliteStore(str(tmp_path / "c.sqlite"))
    try:
        b = store.batch()
        b.add_plain("n", "d", plain_sample(GOOD))
        assert store.write(b) == 1
    finally:
        store.close()


def test_the_edges_of_64_bits_are_samples() -> None:
    for n in (2**63 - 1, -(2**63)):
        assert plain_sample(b'{"time_utc": 1.0, "sample": %d, "values": {}}' % n).sample == n
