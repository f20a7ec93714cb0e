"""A block of polls (:class:`pymb.store.block.PollBlock`, what the TCP loop's
C part hands the writer) stored by the SQLite writer straight from its
columns: the database is the one its polls' samples make, row for row and
byte for byte (two maps, two groups, a point refused, a size limit that
commits within the block, on-change storage); an output that takes samples,
and a sink or a wrapper that writes samples its own way, get each poll's
sample."""

from __future__ import annotations

import dataclasses
import random
import sqlite3
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path

import pytest

from pymb import maps
from pymb.devices.mapreading import GroupDecode
from pymb.errors import OutputError
from pymb.service.clock import restamped
from pymb.store import DeviceInfo, OnChange, Sample, SinkBase, SinkWrapper, SqliteSink
from pymb.store.block import PollBlock, PollSource
from pymb.store.records import Event
from pymb.store.rows import block_binds

TEXT = """schema = "pymb.map/1"
[device]
id = "blk"
table = "holding"
[groups]
fast = { interval = 0 }
slow = { interval = 1 }
[[point]]
name = "a"
address = 0
type = "u16"
group = "fast"
[[point]]
name = "b"
address = 1
type = "i32"
scale = 0.1
group = "fast"
[[point]]
name = "c"
address = 10
type = "f32"
group = "slow"
"""


def _sources() -> list[PollSource]:
    """Three polling groups: the map above's two (one device), the SDM630's
    first group (another)."""
    m = maps.loads(TEXT)
    sdm = maps.builtin("eastron-sdm630")
    sdm_text = (resources.files("pymb.maps") / "builtin" / "eastron-sdm630.toml").read_text()
    mine = DeviceInfo("b1", "127.0.0.1:1502", "blk", 3, "blk-3", map_source=TEXT)
    meter = DeviceInfo("b2", "127.0.0.1:1503", "eastron-sdm630", 1, "meter",
                       map_source=sdm_text)
    return [PollSource(mine, GroupDecode(m, "fast")), PollSource(mine, GroupDecode(m, "slow")),
            PollSource(meter, GroupDecode(sdm, next(iter(sdm.groups))))]


def _block(rng: random.Random, polls: int, refused: bool,
           sources: list[PollSource] | None = None) -> PollBlock:
    """``polls`` polls of the three groups in turn (``sources``: those of
    :func:`_sources`, made anew when not given), random registers; with
    ``refused``, the second poll's group refused its first point."""
    sources = sources or _sources()
    picked = [sources[j % len(sources)] for j in range(polls)]
    images = [rng.randbytes(2 * sum(d.count for d in s.decode.decoders)) for s in picked]
    offs = [sum(map(len, images[:j])) for j in range(polls)]
    monos = sorted(rng.uniform(100.0, 200.0) for _ in range(polls))
    unread: list[frozenset[int]] | None = None
    if refused:
        first = picked[1].decode.points[0]
        unread = [frozenset()] * polls
        unread[1] = frozenset(range(first[1], first[1] + first[2]))
    return PollBlock(1.7e9 + monos[0], monos[0], picked, monos, offs, b"".join(images), unread)


def _dump(db: Path) -> list[str]:
    con = sqlite3.connect(db)
    try:
        return list(con.iterdump())
    finally:
        con.close()


def _both(tmp_path: Path, block: PollBlock, make: Callable[[Path], SqliteSink]
          ) -> tuple[list[str], list[str]]:
    """The database of ``block`` written as a block, and of its samples."""
    a, b = make(tmp_path / "block.db"), make(tmp_path / "samples.db")
    a.write_block(block)
    b.write_batch(block.samples())
    a.close()
    b.close()
    return _dump(tmp_path / "block.db"), _dump(tmp_path / "samples.db")


@pytest.mark.parametrize("refused", [False, True])
def test_a_blocks_rows_are_its_samples_rows(tmp_path: Path, refused: bool) -> None:
    block = _block(random.Random(7), 9, refused)
    got, want = _both(tmp_path, block, SqliteSink)
    assert got == want
    rows = [r for r in got if r.startswith('INSERT INTO "samples"')]
    assert len(rows) == 9
    if refused:  # the refused point's bit in the unsupported column
        assert rows[1].endswith(",1);")
        assert rows[0].endswith(",0);")


def test_a_size_limit_commits_within_a_block_where_it_would_within_its_samples(
        tmp_path: Path) -> None:
    block = _block(random.Random(8), 200, False)

    def bounded(path: Path) -> SqliteSink:
        sink = SqliteSink(path, max_bytes=2_000_000)
        sink.wal_budget = 16_000  # a quarter: a few dozen rows
        return sink

    got, want = _both(tmp_path, block, bounded)
    assert got == want
    assert sum(r.startswith('INSERT INTO "samples"') for r in got) == 200


def _rows(db: Path) -> list[tuple[object, ...]]:
    """The ``samples`` rows as SQLite gives them back (floats compared exactly)."""
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT *, typeof(time_utc), typeof(monotonic) FROM samples "
                           "ORDER BY id").fetchall()
    finally:
        con.close()


@pytest.mark.parametrize("limit", [None, 2_000_000])
@pytest.mark.parametrize("refused", [False, True])
def test_a_later_blocks_rows_bound_three_a_row_are_its_samples_rows(
        tmp_path: Path, limit: int | None, refused: bool) -> None:
    """Once its devices are known, a block none of whose polls refused a
    point is bound 3 values a row (block_binds: SQLite makes the id, the
    wall time and the unsupported column): the same rows, to the bit."""
    first = _block(random.Random(16), 6, False)
    then = _block(random.Random(17), 150, refused, first.sources)

    def sink(path: Path) -> SqliteSink:
        made = SqliteSink(path, max_bytes=limit)
        made.wal_budget = 16_000  # (with a limit: commits within the block)
        return made

    a, b = sink(tmp_path / "block.db"), sink(tmp_path / "samples.db")
    for blk in (first, then):
        assert (block_binds(blk, a._device_ids) is not None) == (blk is then and not refused)
        a.write_block(blk)
        b.write_batch(blk.samples())
    a.close()
    b.close()
    assert _dump(tmp_path / "block.db") == _dump(tmp_path / "samples.db")
    got = _rows(tmp_path / "block.db")
    assert got == _rows(tmp_path / "samples.db")
    assert len(got) == 156
    assert {r[-2:] for r in got} == {("real", "real")}


def test_a_format1_devices_blocks_are_bound_three_a_row_unless_a_poll_is_padded(
        tmp_path: Path) -> None:
    """A CoolPro (format 1's layout: each row's registers at least its
    shipped map's group's) as a serial poller hands its polls over: a later
    block of full-size polls is bound 3 values a row, one with a poll of a
    shorter group (padded) a row at a time; the rows are its samples'."""
    m = maps.builtin("coolpro")
    text = (resources.files("pymb.maps") / "builtin" / "coolpro.toml").read_text()
    cp = DeviceInfo("rs485", "/dev/ttyUSB0", "coolpro", 40, "cp", map_source=text)
    tele, ident, config = (PollSource(cp, GroupDecode(m, g))
                           for g in ("telemetry", "identity", "config"))
    rng = random.Random(21)

    def block(picked: list[PollSource], at: float) -> PollBlock:
        images = [rng.randbytes(2 * sum(d.count for d in s.decode.decoders)) for s in picked]
        offs = [sum(map(len, images[:j])) for j in range(len(picked))]
        monos = [at + 0.001 * j for j in range(len(picked))]
        return PollBlock(1.7e9 + at, at, picked, monos, offs, bytearray(b"".join(images)))

    blocks = [block([tele, ident, config], 100.0), block([tele, ident] * 40, 101.0),
              block([tele, config, tele], 102.0)]
    a, b = SqliteSink(tmp_path / "block.db"), SqliteSink(tmp_path / "samples.db")
    for blk, three in zip(blocks, (False, True, False), strict=True):
        assert (block_binds(blk, a._device_ids) is not None) == three
        a.write_block(blk)
        b.write_batch(blk.samples())
    a.close()
    b.close()
    assert _dump(tmp_path / "block.db") == _dump(tmp_path / "samples.db")
    got = _rows(tmp_path / "block.db")
    assert got == _rows(tmp_path / "samples.db")
    assert len(got) == 86
    assert {len(r[4]) for r in got if isinstance(r[4], bytes)} == {16}  # config's 6 padded
    assert all(isinstance(r[4], bytes) for r in got)


def test_on_change_storage_takes_a_block_as_its_samples(tmp_path: Path) -> None:
    block = _block(random.Random(9), 3, False)  # a poll of each group
    again = PollBlock(block.time_utc + 50, block.monotonic + 50, block.sources,
                      [m + 50 for m in block.monos], block.offs, block.data)
    for name in ("block.db", "samples.db"):
        sink = SqliteSink(tmp_path / name, on_change=OnChange(heartbeat=3600.0))
        for b in (block, again):  # the second block repeats the first: nothing changed
            if name == "block.db":
                sink.write_block(b)
            else:
                sink.write_batch(b.samples())
        sink.close()
    got, want = _dump(tmp_path / "block.db"), _dump(tmp_path / "samples.db")
    assert got == want
    assert sum(r.startswith('INSERT INTO "samples"') for r in got) == 3


class _Taking(SinkBase):
    """An output that takes samples (and counts what it is given)."""

    def __init__(self) -> None:
        self.samples: list[Sample] = []

    def write(self, sample: Sample) -> None:
        self.samples.append(sample)

    def event(self, event: Event) -> None:
        pass

    def commit(self) -> None:
        pass

    def close(self) -> None:
        pass


def test_a_block_made_in_one_step_is_the_one_its_constructor_makes() -> None:
    block = _block(random.Random(18), 4, True)
    args = [getattr(block, f.name) for f in dataclasses.fields(PollBlock)]
    made = PollBlock.of(*args)
    assert type(made) is PollBlock
    assert vars(made) == vars(PollBlock(*args))
    assert made.samples() == block.samples()
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.data = b""  # type: ignore[misc]


def test_an_output_that_takes_samples_gets_each_polls_sample() -> None:
    block = _block(random.Random(10), 5, True)
    out = _Taking()
    out.write_block(block)
    assert out.samples == block.samples()
    assert [s.monotonic for s in out.samples] == block.monos
    assert [s.time_utc for s in out.samples] == [block.clock + m for m in block.monos]
    assert out.samples[1].data.unsupported == ("c",)  # type: ignore[union-attr]


def test_a_wrapper_passes_a_block_on_unless_it_writes_samples_its_own_way(
        tmp_path: Path) -> None:
    block = _block(random.Random(11), 4, False)
    given: list[str] = []

    class Plain(SinkWrapper[SqliteSink]):
        """Wraps events only (as the service's echoing sink does)."""

    class Seeing(SinkWrapper[SqliteSink]):
        """Looks at each sample (as the MQTT forwarding sink does)."""

        def write_batch(self, samples: Sequence[Sample]) -> None:
            given.extend(s.device.name for s in samples)
            super().write_batch(samples)

    class Spy(SqliteSink):
        blocks = 0

        def write_block(self, b: object) -> None:
            Spy.blocks += 1
            super().write_block(b)  # type: ignore[arg-type]

    plain = Plain(Spy(tmp_path / "plain.db"))
    plain.write_block(block)
    plain.close()
    assert Spy.blocks == 1
    assert given == []
    seeing = Seeing(Spy(tmp_path / "seeing.db"))
    seeing.write_block(block)
    seeing.close()
    assert Spy.blocks == 1  # (its samples went to the wrapped sink's write_batch)
    assert given == [s.device.name for s in block.sources]
    assert _dump(tmp_path / "plain.db") == _dump(tmp_path / "seeing.db")


def test_a_sqlite_sink_that_writes_samples_its_own_way_gets_them(tmp_path: Path) -> None:
    block = _block(random.Random(12), 3, False)
    seen: list[int] = []

    class Counting(SqliteSink):
        def write_batch(self, samples: Sequence[Sample]) -> None:
            seen.append(len(samples))
            super().write_batch(samples)

    sink = Counting(tmp_path / "c.db")
    sink.write_block(block)
    sink.close()
    assert seen == [3]


def test_a_clock_step_restamps_every_poll_of_a_block() -> None:
    """A block stamped before the wall clock stepped: each of its polls gets
    the time its monotonic time gives with the new offset (as a sample
    does), in whatever output it goes to."""
    block = _block(random.Random(13), 4, False)
    offset = block.clock + 3600.0
    (got,) = restamped([block], offset)
    assert isinstance(got, PollBlock)
    assert got.clock == pytest.approx(offset)
    assert [s.time_utc for s in got.samples()] == pytest.approx(
        [m + offset for m in block.monos])
    assert restamped([got], offset)[0] is got


def test_a_rolled_back_batch_takes_the_blocks_device_ids_back(tmp_path: Path) -> None:
    """The ``devices`` rows a rolled-back batch inserted are gone: the next
    block stores its devices again, as their samples would be."""
    first = _block(random.Random(14), 3, False)
    then = _block(random.Random(15), 6, False, first.sources)  # the same sources

    def disk_full(con: sqlite3.Connection) -> None:
        raise sqlite3.OperationalError("database or disk is full")

    for name in ("block.db", "samples.db"):
        sink = SqliteSink(tmp_path / name)
        for b in (first, then):
            if name == "block.db":
                sink.write_block(b)
            else:
                sink.write_batch(b.samples())
            if b is first:
                with pytest.raises(OutputError):
                    sink.in_batch(disk_full, True)
        sink.close()
    got, want = _dump(tmp_path / "block.db"), _dump(tmp_path / "samples.db")
    assert got == want
    assert sum(r.startswith('INSERT INTO "devices"') for r in got) == 3  # (blk-3: two groups)
    assert sum(r.startswith('INSERT INTO "samples"') for r in got) == 6
