"""The requests of one map device on its client's line: :class:`Fetcher`.

A plan's register reads go to C in runs (one :class:`~pymb._native.link.RegisterPlan`
per run of one table, one C call each); a plan with bit reads goes request by
request. Either way the line's silences are kept (the device's
``inter_request_gap`` before a request, any device's ``turnaround`` after a
reply, shared through :func:`~pymb.devices.linequiet.quiet_of`), the map's
``response_timeout`` is the reply timeout, and exception 02 or 03 falls back
as :mod:`pymb.devices.mapdevice` says, within the same read.
"""

from __future__ import annotations

import math
import time
from array import array
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from itertools import groupby
from operator import attrgetter
from typing import NamedTuple, TypeVar

from pymb._native.link import RegisterPlan
from pymb._native.mapdecode import MapJob
from pymb.client import Client
from pymb.client.base import armed_failed, line_of, plan_go, read_plan_call
from pymb.devices.linequiet import quiet_of, sleep_until
from pymb.errors import DeviceException, DeviceFailure, IllegalDataAddress, IllegalDataValue
from pymb.maps import Buffers, Decoder, Map, Point
from pymb.maps.device_plan import PointPlanner
from pymb.maps.planner import BIT_TABLES, ReadPlan, Request, on_refusal, replans
from pymb.maps.types import STATES

__all__ = ["Fetcher", "Image", "Read", "Run", "mark_unread"]

_NEVER = math.inf
T = TypeVar("T")
_monotonic = time.monotonic


class Image(NamedTuple):
    """One table's registers of a selection: read in place, decoded in C."""

    address: int  #: of its first register
    registers: array[int]
    decoder: Decoder


def mark_unread(unread: bytearray, points: Sequence[int], defs: Sequence[Point],
                first: Sequence[int], images: dict[str, Image]) -> None:
    """In the decoders' arrays of ``images``: NaN and ``unsupported`` where a
    read got no value (``unread``, a byte per item; ``points`` index ``defs``,
    each point's first item is ``first``'s)."""
    code = STATES.index("unsupported")
    for i in points:
        p = defs[i]
        k0 = first[i]
        b = images[p.table].decoder.buffers
        slot = images[p.table].decoder.slot(p.name)
        for c in range(p.channels):
            if unread[k0 + c]:
                b.values[slot + c] = math.nan
                b.states[slot + c] = code


class Run(NamedTuple):
    """A run of a plan's requests into one table's buffer: one C call."""

    requests: tuple[Request, ...]
    image: Image
    plan: RegisterPlan  #: the requests as C takes them
    #: ``run_read_plan_held(client, plan, 0, on)`` made ready as a call of
    #: ``on`` (:func:`~pymb.client.base.read_plan_call`)
    go: Callable[[int | None], bool]


class Read:
    """One selection's read, made ready: its points (indices into the map's
    readable points) and planner items, its buffers (one :class:`Image` per
    table) with their decoders bound to them, and the plan and its runs of
    the planner's :attr:`~pymb.maps.device_plan.PointPlanner.version` they
    were made at. A read at the same version on the same connection asks the
    same requests: it runs them and decodes, nothing else."""

    __slots__ = ("decoders", "decodes", "decoding", "fetched", "images", "items", "jobs", "plan",
                 "points", "runs", "steady", "steady_call", "steady_fetch", "steady_raw",
                 "version")

    def __init__(self, points: tuple[int, ...], items: tuple[int, ...],
                 images: dict[str, Image]) -> None:
        self.points = points
        self.items = items
        self.images = images
        self.decoders = tuple(image.decoder for image in images.values())
        #: per table: its decoder and its registers
        self.fetched = tuple((image.decoder, image.registers) for image in images.values())
        #: per table: its decode made ready over its buffer
        self.jobs: dict[str, MapJob] = {t: image.decoder.prepare(image.registers)
                                        for t, image in images.items()}
        #: per table: the decoder's C call bound to its buffer, its buffers, the buffer
        self.decodes: tuple[tuple[Callable[[], int], Buffers, array[int]], ...] = tuple(
            (self.jobs[t].run, image.decoder.buffers, image.registers)
            for t, image in images.items())
        self.plan: ReadPlan | None = None
        self.runs: tuple[Run, ...] | None = None
        #: the runs again, each decoding its table once its requests have
        #: their replies (None: a table is read in more runs than one, or not
        #: at all, or the plan has bits: decoded after the read)
        self.decoding: tuple[Run, ...] | None = None
        #: the one RegisterPlan that reads and decodes it all when nothing
        #: else is to be done around it (:meth:`Fetcher.prepared`), else None
        self.steady: RegisterPlan | None = None
        #: :attr:`steady`'s run made ready (``pymb.client.base.read_plan_call``)
        self.steady_call: Callable[[int | None], bool] | None = None
        #: the same read when nothing is decoded: its one run's plan, else None
        self.steady_raw: RegisterPlan | None = None
        #: :attr:`steady_raw`'s run made ready
        self.steady_fetch: Callable[[int | None], bool] | None = None
        self.version = -1  # made at no version yet


class Fetcher:
    """The requests of the device ``m`` describes at unit id ``address`` on
    ``client``, planned by ``planner``.

    :attr:`unread` has a byte per planner item: 1 where the device refused
    the item alone (this read got no value for it); :attr:`marked` is False
    while it has none.

    Every method that asks the line is called holding ``quiet.lock``, the
    line's lock (the map devices on one client take it for each read and
    write): the silences it keeps are then the line's, whichever device and
    thread asks next.
    """

    def __init__(self, client: Client, m: Map, address: int, planner: PointPlanner) -> None:
        self.client = client
        self.map = m
        self.address = address
        self.planner = planner
        self.quiet = quiet_of(client)  #: the line's silences, shared with its other devices
        t = m.timing
        self._gap, self._turnaround = t.inter_request_gap, t.turnaround
        q = self.quiet
        if self._gap and not q.gapped:
            # from now on every request's end is noted; until the next, as
            # if one had just ended
            q.last_end, q.gapped = time.monotonic(), True
        self.unread = bytearray(len(planner.items))
        self._none_unread = bytes(len(planner.items))
        self.marked = False  #: some byte of :attr:`unread` is 1
        #: exception 04 answers asked again per request, waiting
        #: :attr:`busy_backoff` seconds (doubling) before each (a device that
        #: says busy with 04, as the sensor hub does); 0: raised at once
        self.busy_retries = 0
        self.busy_backoff = 0.02
        #: the device exceptions a read falls back on (with the map's
        #: ``split_on_exception``): 02 and 03
        self.refusals: tuple[type[DeviceException], ...] = (IllegalDataAddress,
                                                            IllegalDataValue)
        self._connections = -1  # the client's connection the planner's knowledge is from

    def fetch(self, r: Read, decode: bool = False) -> bool:
        """The requests of read ``r``, each into its place in its buffers.
        ``r`` is made again first (reconnected, planned, the unread marks
        reset) when the line was lost or reopened, when the planner learnt
        something, or when an unsupported point is due. Then each run is one
        C call holding the line (the silences as :meth:`turn` keeps them; the
        RegisterPlans carry the map's reply timeout); exception 02/03 falls
        back as :meth:`run` does. A plan with bits goes through :meth:`run`.
        With ``decode``, where each table is one run, that run's C call also
        decodes it: True when every table was decoded so (no fallback)."""
        planner, client = self.planner, self.client
        if r.version != planner.version or (
                planner.retry_at != _NEVER and planner.retry_at <= planner.clock()):
            self._remake(r)
        runs = r.decoding if decode else None
        decoded = runs is not None
        if runs is None:
            runs = r.runs
            if runs is None:
                if not client.connected or client.fresh_connections != self._connections:
                    self._remake(r)
                assert r.plan is not None
                self.run(r.plan, r.images)
                return False
        q, gap, turnaround = self.quiet, self._gap, self._turnaround
        on: int | None = self._connections  # the first run only on the connection r is from
        for p in runs:
            # the silence before it: any device's turnaround, this device's gap
            # after the last request (kept only while still to come)
            last, until = q.last_end, q.quiet_until
            if gap and last + gap > until:
                until = last + gap
            if until > last and until > _monotonic():
                sleep_until(until)
            try:
                try:
                    if not p.go(on):
                        self._remake(r)  # the line was lost or reopened: made again, read again
                        return self.fetch(r, decode)
                    on = None
                except DeviceFailure:
                    if not self.busy_retries:
                        raise
                    self._busy_again(p.plan, p.plan.failed)
            except self.refusals as exc:
                self._noted()
                if not replans(planner.limits, exc.code):
                    raise
                self._refused(p, p.plan.failed, exc.code)
                decoded = False  # what the fallback read is decoded after the read
                continue
            except BaseException:
                self._noted()
                raise
            if turnaround or q.gapped:  # the end noted where a silence needs it
                now = _monotonic()
                q.last_end = now
                if now + turnaround > q.quiet_until:
                    q.quiet_until = now + turnaround
        return decoded

    def _noted(self) -> None:
        """The end of a request that failed, noted for the line's silences."""
        now = _monotonic()
        q = self.quiet
        q.last_end = now
        q.quiet_until = max(q.quiet_until, now + self._turnaround)

    def _run_plan(self, plan: RegisterPlan, start: int) -> None:
        """``plan`` from request ``start`` on, in one C call; a request the
        device answers 04 to is asked again as :attr:`busy_retries` says."""
        try:
            self.client.run_read_plan(plan, start)
        except DeviceFailure:
            if not self.busy_retries:
                raise
            self._busy_again(plan, plan.failed)

    def _busy_again(self, plan: RegisterPlan, start: int) -> None:
        """Request ``start`` of ``plan`` was answered 04 (busy): ask again
        from it, :attr:`busy_backoff` seconds later (doubling), up to
        :attr:`busy_retries` times; then the DeviceFailure is raised."""
        retries, wait = self.busy_retries, self.busy_backoff
        while True:
            retries -= 1
            time.sleep(wait)
            wait *= 2
            try:
                self.client.run_read_plan(plan, start)
                return
            except DeviceFailure:
                if retries <= 0:
                    raise
                start = plan.failed

    def _remake(self, r: Read) -> None:
        """Reconnect if the line was lost (after a new connection: wait
        ``after_connect``, forget what the last device taught), then plan
        ``r`` and make its runs at the planner's version now."""
        self.after_connect()
        planner = self.planner
        r.plan = planner.plan(r.items)
        unread = self.unread
        if self.marked:
            unread[:] = self._none_unread
        self.marked = bool(planner.unsupported)
        for k in planner.unsupported:
            unread[k] = 1
        r.runs = self.runs(r.plan, r.images)
        r.decoding = self.runs(r.plan, r.images, r.jobs)
        # one C call is the whole read: no silence of this device's own, no
        # request asked again, no fallback, no point marked unread (so none
        # due again: the planner's retry_at changes with its version)
        one = r.decoding is not None and len(r.decoding) == 1
        alone = not (self._gap or self._turnaround or self.busy_retries or self.marked
                     or planner.limits.split_on_exception)
        r.steady = r.decoding[0].plan if one and r.decoding is not None and alone else None
        r.steady_call = None if r.steady is None or r.decoding is None else r.decoding[0].go
        raw = r.runs[0] if alone and r.runs is not None and len(r.runs) == 1 else None
        r.steady_raw = None if raw is None else raw.plan
        r.steady_fetch = None if raw is None else raw.go
        r.version = planner.version

    def prepared(self, r: Read, held: Callable[[], object], then: Callable[[], T], *,
                 fast: bool = True, decode: bool = True) -> Callable[[], T]:
        """A call that reads ``r`` and returns ``then()``, both holding the
        line's lock: ``held()`` reads it (:meth:`fetch` and the decoding, the
        lock held), except while nothing has changed since ``r`` was made
        (the planner's version, the connection, no point due to be asked
        again) and ``r`` is :attr:`Read.steady` (``fast``: nothing is to be
        done after its decoding): then its one C call is the read, in the
        silence the line keeps (:meth:`fetch`'s, with none of this device's
        own), made here while its plan is armed on the line
        (:func:`~pymb.client.base.read_plan_call`). Without ``decode``, the
        read only fetches (``held``: :meth:`fetch` of ``r``), its steady plan
        :attr:`Read.steady_raw`."""
        lock, q, planner, client = self.quiet.lock, self.quiet, self.planner, self.client
        line = line_of(client)

        def read() -> T:
            lock.acquire()
            try:
                # the lock is the client's: held, not taken again
                plan = r.steady if decode else r.steady_raw
                if plan is None or not fast or r.version != planner.version:
                    held()
                    return then()
                until = q.quiet_until
                if until > q.last_end and until > _monotonic():
                    sleep_until(until)
                try:
                    # Armed: bound to this line and its timeout since a read on
                    # this connection (its fetcher's: that changes only with the
                    # line), nothing else to check. Else the run made ready.
                    if plan.armed == line.era:
                        if plan_go(plan.c) < 0:
                            armed_failed(client, plan)
                    else:
                        run = r.steady_call if decode else r.steady_fetch
                        if run is None or not run(self._connections):  # closed, or new
                            held()
                            return then()
                except BaseException:
                    self._noted()
                    raise
                if q.gapped:  # the end noted, as fetch() does with no turnaround
                    now = q.last_end = _monotonic()
                    if now > q.quiet_until:
                        q.quiet_until = now
                return then()
            finally:
                lock.release()
        return read

    def after_connect(self) -> None:
        """Reconnect if the line was lost; after a new connection wait
        ``after_connect`` and forget what the last device taught. Before
        every read (in :meth:`fetch`) and write."""
        client = self.client
        opened = client.ensure_connected()
        if opened or client.fresh_connections != self._connections:
            self._connections = client.fresh_connections
            self.planner.forget()
            wait = self.map.timing.after_connect
            if wait > 0:
                q = self.quiet
                q.quiet_until = max(q.quiet_until, time.monotonic() + wait)

    def runs(self, plan: ReadPlan, images: dict[str, Image],
             jobs: dict[str, MapJob] | None = None) -> tuple[Run, ...] | None:
        """``plan``'s requests in runs of one table, each a RegisterPlan over
        that table's buffer (None: a plan with bits, read request by request).
        With ``jobs`` (per table, its decode made ready), each run decodes its
        table after its requests: None unless every table is one run."""
        if any(r.table in BIT_TABLES for r in plan.requests):
            return None
        t = self.map.timing
        gap = max(t.inter_request_gap, t.turnaround)
        runs = [tuple(g) for _, g in groupby(plan.requests, key=attrgetter("table"))]
        if jobs is not None and sorted(rs[0].table for rs in runs) != sorted(images):
            return None
        made = []
        for rs in runs:
            image = images[rs[0].table]
            plan_c = RegisterPlan(
                [(r.function, self.address, r.address, r.count, r.address - image.address)
                 for r in rs], image.registers, gap, t.response_timeout,
                then=None if jobs is None else jobs[rs[0].table])
            made.append(Run(rs, image, plan_c, read_plan_call(self.client, plan_c)))
        return tuple(made)

    def run(self, plan: ReadPlan, images: dict[str, Image]) -> None:
        """Every request of ``plan``, each into its place in ``images``."""
        with self.map_timeout():
            for r in plan.requests:
                self._fetch(r, images[r.table])

    def _refused(self, p: Run, refused: int, code: int) -> None:
        """Request ``refused`` of run ``p`` was refused with exception 02/03:
        fall back for it as :meth:`run` does, then run the rest of ``p`` in
        C, holding the line as :meth:`fetch` does, as often as needed."""
        gap, turnaround = self._gap, self._turnaround
        q = self.quiet
        plan = p.plan
        while refused >= 0:
            with self.map_timeout():
                self._fall_back(p.requests[refused], p.image, code)
            start, refused = refused + 1, -1
            if start >= plan.n:
                return
            sleep_until(max(q.quiet_until, q.last_end + gap))
            try:
                self._run_plan(plan, start)
            except self.refusals as exc:
                if not replans(self.planner.limits, exc.code):
                    raise
                refused, code = plan.failed, exc.code
            finally:
                now = _monotonic()
                q.last_end = now
                q.quiet_until = max(q.quiet_until, now + turnaround)

    @contextmanager
    def map_timeout(self) -> Iterator[None]:
        """The map's ``response_timeout`` on the line (the byte timeout stays)."""
        timeout, client = self.map.timing.response_timeout, self.client
        if timeout is None or timeout == client.timeout:
            yield
            return
        before = client.swap_response_timeout_prepared(timeout)
        try:
            yield
        finally:
            client.swap_response_timeout_prepared(before)

    @contextmanager
    def turn(self) -> Iterator[None]:
        """One request's turn on the line (the caller holds its lock): the
        device's silence before it (``inter_request_gap``, and any device's
        ``turnaround`` after its reply), and the end noted for the next."""
        q = self.quiet
        sleep_until(max(q.quiet_until, q.last_end + self._gap))
        try:
            yield
        finally:
            now = time.monotonic()
            q.last_end = now
            q.quiet_until = max(q.quiet_until, now + self._turnaround)

    def _wire(self, r: Request, image: Image) -> None:
        """One request on the wire, into its place in ``image``."""
        buf = image.registers
        at = r.address - image.address
        with self.turn():
            if r.table in BIT_TABLES:
                read = (self.client.read_coils if r.table == "coil"
                        else self.client.read_discrete_inputs)
                bits = read(r.address, r.count, slave=self.address)
                buf[at:at + r.count] = array("H", bits)
            else:
                view = memoryview(buf)[at:at + r.count]
                retries, wait = self.busy_retries, self.busy_backoff
                while True:
                    try:
                        self.client.read_registers_prepared(r.function, self.address,
                                                            r.address, view)
                        break
                    except DeviceFailure:
                        if retries <= 0:
                            raise
                    retries -= 1
                    time.sleep(wait)
                    wait *= 2

    def _fetch(self, r: Request, image: Image) -> None:
        """Read ``r`` into ``image``; on exception 02/03, fall back as the
        planner's policy says (:func:`pymb.maps.planner.on_refusal`), within
        this read."""
        try:
            self._wire(r, image)
            return
        except self.refusals as exc:
            if not replans(self.planner.limits, exc.code):
                raise
            code = exc.code
        self._fall_back(r, image, code)

    def _fall_back(self, r: Request, image: Image, code: int) -> None:
        """``r`` was refused with exception ``code`` (02/03): read what the
        planner's policy says instead, or mark its points unread."""
        refusal = on_refusal(self.planner, r, code)
        assert refusal is not None  # (replans said so)
        for sub in refusal.requests:
            self._fetch(sub, image)
        if refusal.unsupported:
            for k in refusal.unsupported:
                self.unread[k] = 1
            self.marked = True
