"""What the SQLite writer and a forwarder beside it (in this process) hand
each other, as plain data: no connection crosses their threads.

The writer, in its thread, hands over each sample it writes (its ``samples``
row, its ``hub_changes`` rows, and the ``devices`` row of a device new to
the forwarder) and, after each commit, the highest id then durable. The
forwarder reads the committed samples on its own connection and takes those
of the open batch from here, so it publishes a sample before its commit (its
id is under the writer's durable mark, :mod:`pymb.store.ids`).

The forwarder hands back what it must write (its outbox cursor, a renamed
cursor, the Sparkplug ``bdSeq``): the writer puts it in its next batch, so
forwarding adds no commit of its own (SD wear); :meth:`Handoff.put_state`
asks for that batch's commit and waits for it.

The samples held are those of the open batch the forwarder has not taken
yet: a commit lets them go (they are in the file), and so does the forwarder
reading past them. At ``limit`` no more are held until the next commit; the
forwarder then reads those from the file. What is held is always a run of
the writer's samples with none missing: what came before its first is in the
file, or will be at the next commit. The newest sample of each device is
kept apart (a forwarder's births and answers to commands).

A batch the writer rolls back (:meth:`Handoff.rolled_back`) takes back what
it handed over: its samples, its newest ones, the ``devices`` rows learnt
since the last commit (the next batch may give their ids to other devices)
and the forwarder's writes it took, which go in with the next batch.
"""

from __future__ import annotations

import collections
import sqlite3
import threading
from collections.abc import Sequence
from typing import cast

from pymb.store.reader import DeviceRow, HubRow, SampleRow, device_row

__all__ = ["LIMIT", "Handoff", "Written"]

LIMIT = 8192  #: samples of the open batch held at most

#: samples handed over: their ``samples`` rows, the ``hub_changes`` rows of
#: those stored by channel (by id), and the ``devices`` rows (by id)
Written = tuple[list[SampleRow], dict[int, tuple[HubRow, ...]], dict[int, DeviceRow]]


class Handoff:
    """The writer's samples to a forwarder, the forwarder's writes to the
    writer (see the module docstring). Thread-safe."""

    def __init__(self, limit: int = LIMIT) -> None:
        self.limit = limit
        self._lock = threading.Lock()
        self._held: collections.deque[SampleRow] = collections.deque()
        self._hubs: dict[int, tuple[HubRow, ...]] = {}  # of the samples held
        #: by id, the same object while the row stands (a reader's cache key)
        self._devices: dict[int, DeviceRow] = {}
        self._learnt: set[int] = set()  # devices rows learnt since the last commit
        self._newest: dict[int, SampleRow] = {}  # by device id
        self._newest_hub: dict[int, tuple[HubRow, ...]] = {}  # stored by channel
        #: the id of the sample written before the first held (0: none)
        self._head = 0
        self._full = False  # holding none until the next commit
        self._since: float | None = None  # the time of the open batch's first sample
        self.written = 0  #: the highest sample id written
        #: ids up to this one are in the file or never will be (a batch rolled back)
        self._gone = 0
        self.committed = 0  #: the highest sample id durable
        self.closed = False  #: the writer closed: everything it wrote is in the file
        self._last = False  # the writer's last batch took the forwarder's writes
        # the forwarder's writes for the writer's next batch
        self._cursor: tuple[str, int] | None = None
        self._renames: list[tuple[str, str]] = []
        self._states: dict[str, int] = {}
        #: the writes the open batch took (back to the queue if it is rolled back)
        self._in_batch: tuple[list[tuple[str, str]], tuple[str, int] | None, dict[str, int]] = \
            ([], None, {})
        #: a state written and not yet durable: key -> (value, its write's number)
        self._unsettled: dict[str, tuple[int, int]] = {}
        self._asked = self._taken = self._durable = 0  # state writes: asked, in a batch, durable
        self._durable_cond = threading.Condition(self._lock)
        #: set when a state write waits for a commit (the writer's owner looks)
        self.commit_wanted = threading.Event()

    # -- the writer's thread ---------------------------------------------------------

    def attach(self, last: int, top: int) -> None:
        """From now on the writer hands over what it writes: ``last``, the id
        it handed out last, ``top`` the highest one in the file (those between
        are gaps: ids skipped after a crash, never given to a sample)."""
        with self._lock:
            self._head = self.written = last
            self.committed = max(top, last)

    def wrote(self, db: sqlite3.Connection, flat: Sequence[object],
              hub: Sequence[HubRow] = ()) -> None:
        """The writer inserted rows of ``samples`` in the open batch of ``db``,
        its connection (its thread): ``flat``, their values as it bound them, 6
        a row (:func:`pymb.store.rows.insert_rows`; the registers its own copy,
        never changed after); one row: with its ``hub_changes`` rows."""
        if not flat:
            return
        # a tuple a row, grouped in C (the writer binds 6 values a row)
        rows = cast(list[SampleRow], list(zip(*(iter(flat),) * 6, strict=True)))
        dids = cast(list[int], flat[1::6])
        new = [did for did in set(dids) if did not in self._devices]
        found = {did: device_row(db, did) for did in new}
        with self._lock:
            if found:
                self._devices.update(found)
                self._learnt.update(found)
            self._newest.update(zip(dids, rows, strict=True))
            if hub:
                self._newest_hub[rows[0][1]] = tuple(hub)
            if self._since is None:
                self._since = rows[0][2]
            held = self._held
            if not self._full:
                room = self.limit - len(held)
                if len(rows) > room:
                    rows, self._full = rows[:room], True
                held.extend(rows)
                if hub and rows:
                    self._hubs[rows[-1][0]] = tuple(hub)
            self.written = cast(int, flat[-6])

    def _let_go(self, upto: int) -> None:
        """The samples held up to id ``upto`` go (the lock held)."""
        held = self._held
        if held and held[-1][0] <= upto:  # all of them, at once
            self._head = held[-1][0]
            held.clear()
            self._hubs.clear()
            return
        while held and held[0][0] <= upto:
            sid = held.popleft()[0]
            self._head = sid
            if self._hubs:
                self._hubs.pop(sid, None)

    def take_writes(self, closing: bool = False
                    ) -> tuple[list[tuple[str, str]], tuple[str, int] | None, dict[str, int]]:
        """The forwarder's writes waiting (renamed cursors, the cursor, the
        states), for the writer's open batch (:func:`pymb.store.outbox.write_pending`);
        ``closing``: the last batch, later writes are the forwarder's own."""
        with self._lock:
            out = self._renames, self._cursor, self._states
            self._renames, self._cursor, self._states = [], None, {}
            renames, cursor, states = self._in_batch
            self._in_batch = (renames + out[0], out[1] or cursor, {**states, **out[2]})
            self._taken = self._asked
            self._last = self._last or closing
            return out

    def commit_done(self, top: int) -> None:
        """The writer committed: ``top``, the highest sample id durable (the
        writer's on-commit hook)."""
        with self._lock:
            self.committed = max(self.committed, top)
            self._since = None
            self._learnt.clear()
            self._in_batch = ([], None, {})
            held = self._held
            self._let_go(top)
            if self._full:  # those not held are in the file now
                self._full = False
                held.clear()
                self._hubs.clear()
            if not held:
                self._head = self.written
            if self._durable != self._taken:
                self._durable = self._taken
                self._durable_cond.notify_all()
            if self._asked == self._taken:
                self.commit_wanted.clear()

    def rolled_back(self, last: int, top: int | None) -> None:
        """The writer rolled its open batch back: what it handed over since
        its last commit is not in the file and never will be (the ids of its
        samples are skipped, never given to others; those of its new
        ``devices`` rows may be given to other devices). ``last``: the
        highest sample id it has handed out; ``top``: the highest one in the
        file now (None: unknown, the connection failed). The forwarder's
        writes it took wait for the next batch."""
        with self._lock:
            self._held.clear()
            self._hubs.clear()
            self._full = False
            self._since = None
            # The ids above the file's top up to the last handed out are gaps:
            # the next sample held follows the top with none missing (top
            # unknown: it follows the last, taken once the forwarder is past
            # it or after the next commit).
            self._gone = max(last, self.written, self._gone)
            if top is not None:
                self.committed = max(self.committed, top)
            self._head = self._gone if top is None else self.committed
            self.written = self.committed
            for did in self._learnt:
                del self._devices[did]
            self._learnt.clear()
            for did in [d for d, row in self._newest.items()
                        if row[0] > self.committed or d not in self._devices]:
                del self._newest[did]
                self._newest_hub.pop(did, None)
            renames, cursor, states = self._in_batch
            self._in_batch = ([], None, {})
            self._renames = renames + self._renames
            self._cursor = self._cursor or cursor
            self._states = {**states, **self._states}
            self._taken = self._durable
            if self._asked != self._durable:
                self.commit_wanted.set()

    def writer_closed(self) -> None:
        """The writer closed: it hands over nothing more."""
        with self._lock:
            self.closed = True
            self._held.clear()
            self._hubs.clear()
            self._newest.clear()
            self._durable = self._taken
            self._durable_cond.notify_all()

    # -- the forwarder's thread ------------------------------------------------------

    def after(self, sample_id: int, committed: int, limit: int,
              before: int | None = None) -> Written:
        """The samples held after ``sample_id`` (below ``before``), at most
        ``limit``, when none is missing before them: the sample written
        before the first held is at or below ``sample_id``, or was durable
        at ``committed`` (and so read from the file by then). Those up to
        ``sample_id`` go: the forwarder is past them."""
        out: list[SampleRow] = []
        with self._lock:
            held = self._held
            if self._head <= max(sample_id, committed):
                self._let_go(sample_id)
                for row in held:
                    if len(out) >= limit or (before is not None and row[0] >= before):
                        break
                    out.append(row)
            return self._written(out, self._hubs)

    def _written(self, rows: list[SampleRow], hubs: dict[int, tuple[HubRow, ...]]
                 ) -> Written:
        """``rows`` with their hub rows (``hubs``: by id) and devices rows (the lock held)."""
        return rows, {r[0]: hubs[r[0]] for r in rows if r[0] in hubs} if hubs else {}, \
            {did: self._devices[did] for did in {r[1] for r in rows}}

    def uncommitted(self, above: int) -> tuple[int, float | None]:
        """(count, time of the oldest) of the open batch's samples above ``above``."""
        with self._lock:
            lo = max(above, self.committed, self._gone)
            n = max(0, self.written - lo)  # a writer's ids follow each other
            if not n:
                return 0, None
            return n, next((row[2] for row in self._held if row[0] > lo), self._since)

    def newest(self, device: str) -> Written:
        """The newest sample written of the device named ``device`` (none, or one)."""
        with self._lock:
            got = [r for did, r in self._newest.items() if self._devices[did].name == device]
            if not got:
                return [], {}, {}
            row = max(got)
            hubs = {row[0]: self._newest_hub[row[1]]} if row[4] is None and \
                row[1] in self._newest_hub else {}
            return self._written([row], hubs)

    def devices(self) -> list[DeviceRow]:
        """The devices rows handed over so far."""
        with self._lock:
            return list(self._devices.values())

    def put_cursor(self, name: str, sample_id: int) -> bool:
        """The outbox cursor of ``name``, for the writer's next batch; False
        once the writer closed (write it yourself)."""
        with self._lock:
            if self._last or self.closed:
                return False
            self._cursor = (name, sample_id)
            return True

    def put_rename(self, old: str, new: str) -> bool:
        """A cursor keyed anew, for the writer's next batch; False once closed."""
        with self._lock:
            if self._last or self.closed:
                return False
            self._renames.append((old, new))
            return True

    def put_state(self, key: str, value: int, wait: float) -> bool:
        """An integer to remember, for the writer's next batch, whose commit
        is asked for and waited for (``wait`` seconds at most); False once
        the writer closed (write it yourself)."""
        with self._lock:
            if self._last or self.closed:
                return False
            self._states[key] = value
            self._asked += 1
            asked = self._asked
            self._unsettled[key] = (value, asked)
            self.commit_wanted.set()
            self._durable_cond.wait_for(
                lambda: self._durable >= asked or (self.closed and self._taken < asked), wait)
            return self._durable >= asked or not self.closed

    def unsettled_state(self, key: str) -> int | None:
        """The last value put for ``key`` while its batch is not yet
        committed (None: the file has the last one): what the forwarder
        remembers is what it last said, durable or not (a Sparkplug bdSeq
        is never used twice)."""
        with self._lock:
            got = self._unsettled.get(key)
            if got is None:
                return None
            if self._durable >= got[1]:
                del self._unsettled[key]
                return None
            return got[0]
