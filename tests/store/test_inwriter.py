"""Another thread's work on the writer's database is done by the writer's
thread (pymb.store.inwriter): in its batch, in the order asked; a request the
writer does not take within the bound fails and is never run later; once the
writer is closed, a request fails at once."""

from __future__ import annotations

import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import wait_until

from pymb.errors import OutputError
from pymb.store import SqliteSink
from pymb.store.inwriter import InWriter


def _asked(run: InWriter, fn: Any, commit: bool) -> tuple[threading.Thread, list[Any]]:
    """``run(fn, commit)`` from a thread of its own: (the thread, what it got)."""
    got: list[Any] = []

    def ask() -> None:
        try:
            got.append(run(fn, commit))
        except OutputError as e:
            got.append(e)

    t = threading.Thread(target=ask)
    t.start()
    return t, got


def test_a_request_runs_in_the_writers_thread_in_its_batch(tmp_path: Path) -> None:
    """The writer's own calls run at once; another thread's wait for the
    writer's serve(), run there on its connection (the thread check on)."""
    db = tmp_path / "w.sqlite"
    sink = SqliteSink(db, one_thread=True)
    run = InWriter(sink)
    woken = threading.Event()
    run.wake = woken.set
    run(lambda con: con.execute("CREATE TABLE t(v)"), True)
    threads: list[int] = []

    def put(con: sqlite3.Connection) -> int:
        threads.append(threading.get_ident())
        return int(con.execute("INSERT INTO t VALUES (1)").lastrowid or 0)

    t, got = _asked(run, put, False)
    wait_until(woken.is_set, "the writer woken")
    assert not got
    run.serve()
    t.join(10)
    assert got == [1]
    assert threads == [threading.get_ident()]
    con = sqlite3.connect(db)
    try:
        assert con.execute("SELECT COUNT(*) FROM t").fetchone()[0] == 0  # in the open batch
        sink.commit()
        assert con.execute("SELECT COUNT(*) FROM t").fetchone()[0] == 1
    finally:
        con.close()
    sink.close()


def test_a_request_not_taken_in_time_fails_and_never_runs(tmp_path: Path) -> None:
    """A writer that does not come round within the bound: the request is
    refused (nothing on record, nothing executed) and taken back; a later
    serve() does not run it."""
    sink = SqliteSink(tmp_path / "s.sqlite", one_thread=True)
    run = InWriter(sink, wait=0.2)
    ran: list[bool] = []
    t, got = _asked(run, lambda con: ran.append(True), True)
    t.join(10)
    assert len(got) == 1
    assert isinstance(got[0], OutputError)
    assert "did not take it within 0.2 s" in str(got[0])
    run.serve()
    assert not ran
    sink.close()


def test_a_closed_writer_refuses_at_once(tmp_path: Path) -> None:
    """What waits when the writer closes fails, and so does a later request."""
    sink = SqliteSink(tmp_path / "c.sqlite", one_thread=True)
    run = InWriter(sink)
    woken = threading.Event()
    run.wake = woken.set
    t, got = _asked(run, lambda con: None, False)
    wait_until(woken.is_set, "the request asked")
    sink.close()
    run.close()
    t.join(10)
    assert len(got) == 1
    assert "the logger has stopped" in str(got[0])
    t, got = _asked(run, lambda con: None, False)
    t.join(10)
    assert "the logger has stopped" in str(got[0])


def test_the_thread_check_is_on_when_asked(tmp_path: Path) -> None:
    """one_thread: another thread's use of the writer's connection raises."""
    sink = SqliteSink(tmp_path / "o.sqlite", one_thread=True)
    failed: list[BaseException] = []

    def use() -> None:
        try:
            sink.db.execute("SELECT 1")
        except sqlite3.ProgrammingError as e:
            failed.append(e)

    t = threading.Thread(target=use)
    t.start()
    t.join(10)
    sink.close()
    assert failed


def test_what_a_request_wrote_is_committed_within_the_bound(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A request's write without its commit (a refused command's record)
    asks for a commit once it has waited the bound, even if the logger has
    nothing else to commit; a read asks for none; a commit ends the wait."""
    import pymb.store.inwriter as inwriter
    monkeypatch.setattr(inwriter, "COMMIT_AFTER", 0.3)
    sink = SqliteSink(tmp_path / "b.sqlite", one_thread=True)
    run = InWriter(sink)
    sink.on_commit(lambda top: run.committed())
    woken = threading.Event()
    run.wake = woken.set
    run(lambda con: con.execute("CREATE TABLE t(v)"), True)

    def served(fn: Any) -> bool:
        woken.clear()
        t, _ = _asked(run, fn, False)
        wait_until(woken.is_set, "the request asked")
        due = run.serve()
        t.join(10)
        time.sleep(0.4)
        return due

    assert not served(lambda con: con.execute("SELECT COUNT(*) FROM t").fetchone())
    assert not run.serve()  # a read: nothing to commit, however long
    assert not served(lambda con: con.execute("INSERT INTO t VALUES (1)"))
    assert run.serve()  # the write has waited the bound
    sink.commit()
    assert not run.serve()
    sink.close()
