"""A prepared list of register reads (:class:`RegisterPlan`), the record
:mod:`pymb._native.link` runs in one C call, and the reply timeout as
libmodbus takes it."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

from pymb._native.mapdecode import MapJob
from pymb._pymb_cffi import ffi

__all__ = ["RegisterPlan", "seconds_us"]

_from_buffer = ffi.from_buffer


def seconds_us(seconds: float) -> tuple[int, int]:
    """A timeout as libmodbus takes it: (seconds, microseconds), at least 1 us."""
    return divmod(max(1, round(seconds * 1e6)), 1_000_000)


@functools.lru_cache(maxsize=256)
def _held_as(us: tuple[int, int]) -> tuple[int, int]:
    """One tuple for each reply timeout: the line tells whether its context
    holds a plan's timeout by identity (``plan.hold is line._held``), so
    plans of the same timeout (devices of one map on one line) share it."""
    return us


class RegisterPlan:
    """A prepared list of register reads into one writable ``array('H')``
    (pymb_read_plan, held as a ``pymbi_plan``): ``requests`` are (function,
    slave, address, count, offset into ``dest``) tuples, checked by the
    caller and again in C before anything is sent; ``gap`` seconds of
    silence between two requests; ``timeout``: the reply timeout of its
    requests (None: the line's); ``then``: a decode made ready over ``dest``
    (:class:`~pymb._native.mapdecode.MapJob`) that each run decodes in the
    same C call once every request from its start on has its reply
    (:attr:`decoded` says whether the last run did). After a failed run,
    :attr:`failed` is the index of the request that failed."""

    __slots__ = ("armed", "c", "failed", "gap_us", "hold", "n", "nregs", "regs", "reqs",
                 "requests", "then", "timeout", "timeout_us")

    def __init__(self, requests: Sequence[tuple[int, int, int, int, int]], dest: Any,
                 gap: float = 0.0, timeout: float | None = None,
                 then: MapJob | None = None) -> None:
        self.timeout = timeout
        self.timeout_us = seconds_us(timeout or 0)
        #: what the line's context holds while this plan runs (None: the line's own)
        self.hold = _held_as(self.timeout_us) if timeout is not None else None
        self.requests = tuple(requests)
        self.n = len(self.requests)
        self.reqs = ffi.new("pymb_plan_request[]", max(1, self.n))
        for i, (function, slave, address, count, offset) in enumerate(self.requests):
            r = self.reqs[i]
            r.function, r.slave, r.address, r.count, r.offset = (
                function, slave, address, count, offset)
        self.regs = _from_buffer("uint16_t[]", dest, True)
        self.nregs = len(self.regs)
        self.gap_us = max(0, min(0xFFFFFFFF, round(gap * 1e6)))
        self.then = then  # kept alive with the plan that points to it
        c = self.c = ffi.new("pymbi_plan *")
        c.reqs, c.n, c.gap_us, c.regs, c.nregs = self.reqs, self.n, self.gap_us, self.regs, \
            self.nregs
        c.then = then.cdata if then is not None else ffi.NULL
        self.failed = -1
        #: the :attr:`~pymb._native.link.Link.era` it was armed at
        #: (``pymb.client.base.read_plan_call``): while the line's is the same, its
        #: record is bound to the line, the context holds its reply timeout and its
        #: read is on the connection it was armed on; -1: never
        self.armed = -1

    @property
    def decoded(self) -> bool:
        """Whether the last run decoded :attr:`then`."""
        return bool(self.c.decoded)
