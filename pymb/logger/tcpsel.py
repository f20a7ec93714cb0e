"""The one TCP loop's selector (:mod:`pymb.logger.tcploop`): :class:`Selector`,
one epoll (Linux) over the loop's sockets, each registered with the object
its events go to (a connection, or the lender's wake-up socket).

It does what the loop used of :mod:`selectors` (register, modify, unregister,
select, close, with its errors) and no more: :meth:`Selector.select` gives
each ready socket's object and its epoll mask, without a key to make and
look up per event (the loop wakes for each poll of each connection)."""

from __future__ import annotations

import contextlib
import math
import select
import socket
from typing import Any

__all__ = ["READ", "WRITABLE", "WRITE", "Selector"]

READ = 1  #: register for reading (as ``selectors.EVENT_READ``)
WRITE = 2  #: register for writing (as ``selectors.EVENT_WRITE``)
_EPOLL = {READ: select.EPOLLIN, WRITE: select.EPOLLOUT, READ | WRITE:
          select.EPOLLIN | select.EPOLLOUT}
#: a mask :meth:`Selector.select` gives that says writable (or an error or a
#: hang-up, which a write then says), as ``selectors`` reads epoll's
WRITABLE = ~select.EPOLLIN


def _fd(sock: socket.socket) -> int:
    fd = sock.fileno()
    if fd < 0:
        raise ValueError(f"invalid file descriptor: {sock!r}")
    return fd


class Selector:
    """One epoll; each registered socket's events go to its object."""

    __slots__ = ("_ep", "_to")

    def __init__(self) -> None:
        self._ep = select.epoll()
        self._to: dict[int, Any] = {}

    def register(self, sock: socket.socket, events: int, data: Any) -> None:
        """Watch ``sock`` for ``events`` (:data:`READ`, :data:`WRITE`); its
        events go to ``data``. KeyError: already registered; ValueError: closed."""
        fd = _fd(sock)
        if fd in self._to:
            raise KeyError(f"{sock!r} is already registered")
        self._ep.register(fd, _EPOLL[events])
        self._to[fd] = data

    def modify(self, sock: socket.socket, events: int, data: Any) -> None:
        """Watch ``sock`` (registered) for ``events`` now, for ``data``."""
        fd = _fd(sock)
        if fd not in self._to:
            raise KeyError(f"{sock!r} is not registered")
        self._ep.modify(fd, _EPOLL[events])
        self._to[fd] = data

    def unregister(self, sock: socket.socket) -> None:
        """Stop watching ``sock`` (before it is closed). KeyError: not registered."""
        fd = _fd(sock)
        del self._to[fd]
        with contextlib.suppress(OSError):  # (its file already gone: epoll forgot it)
            self._ep.unregister(fd)

    def select(self, timeout: float) -> list[tuple[Any, int]]:
        """Wait up to ``timeout`` seconds (rounded up to a millisecond, as
        epoll waits) for a watched socket: (its object, epoll mask) of each
        ready one."""
        to = self._to
        ready = self._ep.poll(math.ceil(timeout * 1e3) * 1e-3 if timeout > 0 else 0,
                              len(to) or 1)  # (not the default 1,023 events to allocate)
        return [(to[fd], ev) for fd, ev in ready if fd in to]

    def fileno(self) -> int:
        """The epoll's descriptor (the C loop waits on it: :mod:`pymb._native.loop`)."""
        return self._ep.fileno()

    def owner(self, fd: int) -> Any:
        """The object ``fd``'s events go to (None: not watched)."""
        return self._to.get(fd)

    def close(self) -> None:
        """No more waits: the epoll is closed (the sockets are not)."""
        self._ep.close()
        self._to.clear()
