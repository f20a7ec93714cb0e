"""What the polls the TCP loop's C part carries give the writer:
:class:`Carried`.

While a connection is *armed* (:meth:`pymb.logger.tcpbase.TcpLoopBase.arm`,
:meth:`~pymb.logger.tcpbase.TcpLoopBase.chain`), its polls are read and sent
in C (:class:`pymb._native.loop.Loop`), and one wait of the C part hands over
the polls of many connections at once. Here they become one
:class:`~pymb.store.block.PollBlock` for the writer, with no Python a poll: a
poll's source is its group's (:attr:`Entry.id <pymb.logger.tcpunits.Entry.id>`,
named in C), and its registers are a slice of one copy of the C part's block.
A poll's device answered (:meth:`Report.answered
<pymb.logger.report.Report.answered>`) only where that is news: the device
failed before its connection was armed (its failures and offline time
change only while the connection is not armed), the poll leaves items out,
or the run has a problem by the device's name.
"""

from __future__ import annotations

from pymb.logger.report import Report
from pymb.logger.schedule import Health
from pymb.logger.stats import Stats
from pymb.logger.tcpunits import Entry
from pymb.store.block import PollBlock, PollSource

__all__ = ["Carried"]

_NONE: frozenset[int] = frozenset()


class Carried:
    """By poll id (:attr:`Entry.id <pymb.logger.tcpunits.Entry.id>`, ``n`` of them),
    what its armed polls give the writer, handed over by ``report``;
    ``stats``: the run's problems."""

    def __init__(self, n: int, report: Report, stats: Stats) -> None:
        self.report = report
        self.problems = stats.problems
        #: (the device's health, the items its polls leave out, the bus's name)
        self._how: list[tuple[Health, frozenset[int], str]] = [(Health("", 1, None), _NONE, "")] * n
        self._sources: list[PollSource | None] = [None] * n  #: its polls' source
        self._sizes = [0] * n  #: its polls' image's bytes
        self._loud: set[int] = set()  #: the armed polls that have news

    def arm(self, i: int, e: Entry, bus: str) -> None:
        """Polls of ``e`` (id ``i``, of bus ``bus``) are armed (its plan, so
        the items it leaves out, holds while armed)."""
        h, gone = e.unit.health, e.unsupported()
        self._how[i] = (h, gone, bus)
        self._sources[i] = e.source
        self._sizes[i] = len(e.image)
        if gone or h.failures or h.offline:
            self._loud.add(i)

    def disarm(self, i: int) -> None:
        """Polls of id ``i`` are no longer armed."""
        self._loud.discard(i)

    def block(self, done: list[int], at: list[float], offs: list[int], data: memoryview,
              clock: float) -> PollBlock:
        """The block of the polls ``done`` (their ids) read at ``at``
        (monotonic; ``clock``: wall time less monotonic time), their images
        at ``offs`` in ``data`` (the C part's block); each poll's device
        answered where that is news."""
        sources: list[PollSource] = list(map(self._sources.__getitem__, done))  # type: ignore[arg-type]
        unread = self._news(done, sources) if self._loud or self.problems else None
        return PollBlock.of(at[0] + clock, at[0], sources, at, offs,
                            bytearray(data[:offs[-1] + self._sizes[done[-1]]]), unread)

    def _news(self, done: list[int], sources: list[PollSource]) -> list[frozenset[int]] | None:
        """Each poll's device answered, where that is news; the items each
        poll left out (None: none did)."""
        how, problems, report = self._how, self.problems, self.report
        unread: list[frozenset[int]] | None = None
        for j, i in enumerate(done):
            h, gone, bus = how[i]
            if gone or h.failures or h.offline or h.name in problems:
                src = sources[j]
                if gone:
                    if unread is None:
                        unread = [_NONE] * len(done)
                    unread[j] = gone
                report.answered(bus, h, src.device, src.decode.unsupported(gone) if gone else ())
        self._loud = {i for i in self._loud
                      if how[i][1] or how[i][0].failures or how[i][0].offline}
        return unread
