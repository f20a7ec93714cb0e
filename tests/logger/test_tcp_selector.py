"""The TCP loop's selector (pymb.logger.tcpsel): what the loop relies on of it,
over real sockets."""

from __future__ import annotations

import os
import socket

import pytest

from pymb.logger.tcpsel import READ, WRITABLE, WRITE, Selector


def test_a_ready_socket_gives_its_object_and_a_write_says_writable() -> None:
    sel = Selector()
    a, b = socket.socketpair()
    listener = socket.create_server(("127.0.0.1", 0))
    c = socket.socket()
    c.setblocking(False)
    try:
        sel.register(a, READ, "a")
        assert sel.select(0.0) == []
        b.send(b"x")
        assert [(data, bool(mask & WRITABLE)) for data, mask in sel.select(5.0)] == [("a", False)]
        c.connect_ex(listener.getsockname())
        sel.register(c, WRITE, "connecting")
        got = dict(sel.select(5.0))
        assert got["connecting"] & WRITABLE
        sel.modify(c, READ, "open")
        assert "open" not in dict(sel.select(0.0))  # nothing to read yet
        sel.unregister(a)
        assert "a" not in dict(sel.select(0.0))
    finally:
        sel.close()
        for s in (a, b, c, listener):
            s.close()


def test_it_refuses_what_selectors_refuses() -> None:
    sel = Selector()
    a, b = socket.socketpair()
    try:
        sel.register(a, READ, 1)
        with pytest.raises(KeyError):
            sel.register(a, READ, 2)
        with pytest.raises(KeyError):
            sel.unregister(b)
        with pytest.raises(KeyError):
            sel.modify(b, READ, 3)
        b.close()
        with pytest.raises(ValueError, match="invalid file descriptor"):
            sel.register(b, READ, 4)
    finally:
        sel.close()
        a.close()
        b.close()


def test_a_socket_whose_file_is_gone_is_unregistered_quietly() -> None:
    sel = Selector()
    a, b = socket.socketpair()
    try:
        sel.register(a, READ, "a")
        os.close(a.fileno())  # behind the socket's back: epoll has forgotten it
        sel.unregister(a)
        with pytest.raises(KeyError):
            sel.unregister(a)
    finally:
        a.detach()
        sel.close()
        b.close()
