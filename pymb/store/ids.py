"""Sample ids: the writer hands them out itself, and an id is never given
to two samples, across crashes and power cuts.

SQLite alone would give a new row the highest id in the table plus one: a
sample published (to MQTT) before its commit and then lost in a power cut
would see its id handed to the next sample. So the writer keeps a durable
high-water mark, ``meta`` row ``sample_ids_reserved``: before it hands out
an id above the mark to a sample that may be published before its commit
(:meth:`pymb.store.SqliteSink.publish_live`), it moves the mark up by a
block of ids and commits that first. After a crash the next id is above
both the highest stored id and the mark; ids lost with a batch leave a gap,
never a second sample. A clean close brings the mark down to the last id
handed out, so an orderly restart leaves no gap.
"""

from __future__ import annotations

import sqlite3

from pymb.store.outbox import max_id

__all__ = ["BLOCK", "RESERVED_KEY", "SampleIds"]

RESERVED_KEY = "sample_ids_reserved"
#: ids reserved at a time: one extra commit per this many samples (an hour of
#: 18 samples a second), and at most this many ids skipped after a crash
BLOCK = 65536


class SampleIds:
    """The ids of one writer's samples (its connection's thread only)."""

    def __init__(self, db: sqlite3.Connection) -> None:
        row = db.execute("SELECT value FROM meta WHERE key = ?", (RESERVED_KEY,)).fetchone()
        try:
            mark = int(row[0]) if row else 0
        except ValueError:
            mark = 0
        top = max_id(db)
        #: ids up to this one are durably reserved (may have been published)
        self.reserved = mark
        self._stored_mark = mark
        self.next = max(top, mark) + 1  #: the id of the next sample
        #: samples may be read (published) before their commit: ids need a mark
        self.live = False

    def take(self) -> int:
        """The next sample's id."""
        i = self.next
        self.next += 1
        return i

    def take_many(self, n: int) -> int:
        """The ids of the next ``n`` samples: the first of them (the rest follow it)."""
        i = self.next
        self.next += n
        return i

    @property
    def last(self) -> int:
        """The highest id handed out (0: none yet)."""
        return self.next - 1

    def short(self, n: int) -> bool:
        """True when ``n`` more ids need a new mark first (live only)."""
        return self.live and self.next + n - 1 > self.reserved

    def write_mark(self, db: sqlite3.Connection, n: int) -> int:
        """Write a mark covering ``n`` more ids (and a block beyond) into the
        open transaction; returns it. It counts once committed: :meth:`marked`."""
        mark = self.next + max(n, BLOCK) - 1
        db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (RESERVED_KEY, str(mark)))
        return mark

    def marked(self, mark: int) -> None:
        """The transaction holding ``mark`` committed."""
        self.reserved = self._stored_mark = mark

    def write_settled(self, db: sqlite3.Connection) -> int | None:
        """Before the last commit of a clean close: the mark brought down to the
        last id handed out (None: nothing to write)."""
        if self._stored_mark <= self.last:
            return None
        db.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (RESERVED_KEY, str(self.last)))
        return self.last
