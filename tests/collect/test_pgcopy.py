"""The PostgreSQL store's binary COPY against a real PostgreSQL: a numbers-only
sample (encoded a message at a time) and every other kind of value (a row at
a time) stored as the plain profile's rows say, value by value; input
PostgreSQL would refuse is bad input, never a refused batch; a batch holding
rows stored already, and two writers storing the same rows in opposite orders
at once, store every row once."""

from __future__ import annotations

import json
import threading
import time

import pytest

pytest.register_assert_rewrite("collectkit")
from collectkit import pg_facts, psycopg  # noqa: E402

from pymb.collect import rows as rows_module  # noqa: E402
from pymb.collect.pgcopy import CopyBatch  # noqa: E402
from pymb.collect.postgres import Postgres  # noqa: E402
from pymb.collect.rows import BadInput, plain_rows, plain_sample  # noqa: E402
from pymb.collect.sqlstore import PostgresStore  # noqa: E402

pytest_plugins = ["collectkit"]


def _payload(t: float, sample: int | None, values: dict[str, object],
             states: dict[str, object] | None = None) -> bytes:
    return json.dumps({"time_utc": t, "sample": sample, "values": values,
                       "states": states or {}}).encode()


NUMBERS = _payload(1796143691.1931255, 7, {"voltage_l1_v": 230.125, "current_l1_a": 3,
                                             "on": True, "off": False, "neg": -0.0})
MIXED = _payload(1796143692.5, None,
                 {"serial": "SN-1\t2\\3", "missing": None, "off_line": None,
                  "temperature_c": [21.5, None, 19], "ok": 1.5},
                 {"off_line": "offline", "temperature_c": ["value", "no_sensor", "value"]})


def _facts(payloads: list[tuple[str, bytes]]) -> set[tuple[object, ...]]:
    out: set[tuple[object, ...]] = set()
    for node, p in payloads:
        for r in plain_rows(node, "dev", p):
            out.add((r[0], r[1], r[2], round(r[3], 5), r[4], r[5], r[6], r[7]))
    return out


def _stored(url: str) -> set[tuple[object, ...]]:
    return {(f[0], f[1], f[2], round(f[3], 5), *f[4:]) for f in pg_facts(url)}


def test_fast_path_bytes_are_the_general_paths() -> None:
    fast, general = CopyBatch(), CopyBatch()
    fast.add_plain("gw1", "dev", plain_sample(NUMBERS))
    general.add_rows(plain_rows("gw1", "dev", NUMBERS))
    assert fast.rows == general.rows == 5
    assert fast.data() == general.data()
    assert fast.newest == general.newest == pytest.approx(1796143691.1931255)


def test_every_kind_of_value_stored_as_the_rows_say(postgres: Postgres) -> None:
    store = PostgresStore(postgres.url)
    try:
        b = store.batch()
        payloads = [("gw1", NUMBERS), ("gw1", MIXED), ("gw2", NUMBERS)]
        for node, p in payloads:
            b.add_plain(node, "dev", plain_sample(p))
        assert store.write(b) == b.rows == 5 + 7 + 5
    finally:
        store.close()
    assert _stored(postgres.url) == _facts(payloads)
    with psycopg.connect(postgres.url) as con:
        row = con.execute("SELECT count(*), bool_and(received > time) FROM pymb_values"
                          ).fetchone()
        # times to the microsecond as PostgreSQL's to_timestamp rounds them
        same = con.execute("SELECT bool_and(time = to_timestamp(%s)) FROM pymb_values "
                           "WHERE point = 'voltage_l1_v'", (1796143691.1931255,)).fetchone()
    assert row == (17, True)
    assert same == (True,)


@pytest.mark.parametrize(("values", "why"), [
    ({"bad\u0000name": 1.0}, "NUL"),
    ({"text": "lone \ud800 surrogate"}, "surrogate"),
    ({"huge": 10 ** 400}, "not a number"),
])
def test_what_postgresql_cannot_hold_is_bad_input(values: dict[str, object], why: str,
                                                    postgres: Postgres) -> None:
    store = PostgresStore(postgres.url)
    try:
        b = store.batch()
        b.add_plain("gw1", "dev", plain_sample(NUMBERS))
        with pytest.raises(BadInput, match=why):
            b.add_plain("gw1", "dev", plain_sample(_payload(1.0, 1, values)))
        with pytest.raises(BadInput, match="64 bits"):
            b.add_plain("gw1", "dev", plain_sample(_payload(2.0, 2 ** 63, {"x": 1.0})))
        with pytest.raises(BadInput, match="range"):
            b.add_plain("gw1", "dev", plain_sample(_payload(1e300, 1, {"x": 1.0})))
        assert b.rows == 5  # the bad messages added nothing: the batch is whole
        assert store.write(b) == 5
    finally:
        store.close()


def test_rows_stored_already_are_skipped_and_the_rest_stored(postgres: Postgres) -> None:
    store = PostgresStore(postgres.url)
    try:
        first = store.batch()
        first.add_plain("gw1", "dev", plain_sample(NUMBERS))
        assert store.write(first) == 5
        again = store.batch()  # a redelivery, a new sample, the same sample twice
        again.add_plain("gw1", "dev", plain_sample(NUMBERS))
        again.add_plain("gw1", "dev", plain_sample(MIXED))
        again.add_plain("gw1", "dev", plain_sample(MIXED))
        assert store.write(again) == 7
        # the next 30 s of batches go through the temporary table too
        assert store._staged_until - time.monotonic() > 20
        more = store.batch()  # the next batch (through the temporary table for a while)
        more.add_plain("gw2", "dev", plain_sample(NUMBERS))
        more.add_plain("gw1", "dev", plain_sample(NUMBERS))
        assert store.write(more) == 5
    finally:
        store.close()
    assert _stored(postgres.url) == _facts([("gw1", NUMBERS), ("gw1", MIXED),
                                            ("gw2", NUMBERS)])


def test_two_writers_storing_the_same_rows_at_once_store_each_once(
        postgres: Postgres) -> None:
    stores = [PostgresStore(postgres.url) for _ in range(2)]
    payloads = [(f"gw{n}", _payload(1796143000.0 + k, k, {f"p{i}": float(i) for i in range(20)}))
                for n in range(10) for k in range(20)]
    batches = []
    for i, s in enumerate(stores):
        b = s.batch()
        for node, p in payloads if i == 0 else reversed(payloads):
            b.add_plain(node, "dev", plain_sample(p))
        batches.append(b)
    got: list[int] = []
    errors: list[BaseException] = []

    def write(i: int) -> None:
        try:
            got.append(stores[i].write(batches[i]))
        except BaseException as e:
            errors.append(e)

    threads = [threading.Thread(target=write, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    for s in stores:
        s.close()
    assert errors == []
    assert sum(got) == 4000  # between them, every row once
    assert _stored(postgres.url) == _facts(payloads)


def test_a_table_made_without_the_received_default_gets_it(postgres: Postgres) -> None:
    with psycopg.connect(postgres.url) as con:
        con.execute("""CREATE TABLE pymb_values (
            node text NOT NULL, device text NOT NULL, point text NOT NULL,
            time timestamptz NOT NULL, value double precision, text text, state text,
            sample bigint, received timestamptz NOT NULL,
            CONSTRAINT pymb_values_key UNIQUE (node, device, point, time))""")
    store = PostgresStore(postgres.url)
    try:
        b = store.batch()
        b.add_plain("gw1", "dev", plain_sample(NUMBERS))
        assert store.write(b) == 5
    finally:
        store.close()
    assert _stored(postgres.url) == _facts([("gw1", NUMBERS)])


@pytest.mark.parametrize("payload", [
    NUMBERS, MIXED,
    b'{"time_utc": 1.5, "values": {"a": NaN, "b": Infinity}}',
    b'{"time_utc": 1.5, "values": {"a": 123456789012345678901234567890}}',
    b'{"time_utc": 1.5, "values": {"a": 18446744073709551615, "b": -0.0, "c": 1e308}}',
    b'{"time_utc": 1.5, "values": {"a": "\\ud800"}}',
    b'{"time_utc": 1.5, "values": {"a": 1, "a": 2}, "states": {}}',
    '{"time_utc": 1.5, "values": {"\u00e9t\u00e9": "\u2603"}}'.encode(),
    b'{"time_utc": 1.5, "values": {"a": 1}',
    b'\xff\xfe',
])
def test_decoded_as_the_json_module_decodes(payload: bytes,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    def rows() -> str:
        try:
            return repr(plain_rows("gw1", "dev", payload))  # repr: NaN, -0.0 as written
        except BadInput as e:
            return f"BadInput: {e}"

    got = rows()
    monkeypatch.setattr(rows_module, "_loads", json.loads)
    assert got == rows()
