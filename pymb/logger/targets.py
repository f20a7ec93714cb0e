"""The map devices of a logging run that write commands may reach
(:class:`~pymb.logger.commands.Target`): on a bus with a thread, the
poller's own MapDevice (its line lock puts a write between two polls); on
the one TCP loop, a MapDevice over the device's own poll connection, lent by
the loop between two polls (:mod:`pymb.logger.tcplend`) and given back once
the command is done."""

from __future__ import annotations

import threading
from collections.abc import Sequence

from pymb.client import TcpClient
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapwrite import Budget
from pymb.logger.commands import Target
from pymb.logger.poller import BusPoller
from pymb.logger.tcpconn import Conn
from pymb.logger.tcploop import TcpMapPoller
from pymb.logger.tcpunits import Unit
from pymb.maps import Map

__all__ = ["write_targets"]


def write_targets(pollers: Sequence[object], budget: Budget) -> dict[str, Target]:
    """Every map device the ``pollers`` poll, by name; writes counted in ``budget``."""
    out: dict[str, Target] = {}
    for p in pollers:
        if isinstance(p, BusPoller):
            for info, cfg in p.devices:
                out[info.name] = _threaded(p, info.name, cfg.map, budget)
        elif isinstance(p, TcpMapPoller):
            for c in p.conns:
                for u in c.units:
                    out[u.info.name] = _looped(p, c, u, budget)
    return out


def _threaded(p: BusPoller, name: str, m: Map, budget: Budget) -> Target:
    def device() -> MapDevice | None:
        h = p.healths.get(name)
        if h is None:
            return None
        h.device.budget = budget
        return h.device

    def offline() -> bool:
        h = p.healths.get(name)
        return h is None or h.offline or not p.stats.opened.get(p.bus.name, False)

    return Target(name, m, device, offline)


def _looped(loop: TcpMapPoller, c: Conn, u: Unit, budget: Budget) -> Target:
    client = TcpClient(c.host, c.port, timeout=u.timeout)
    made: list[MapDevice] = []
    held = threading.Event()

    def device() -> MapDevice:
        # the poll under way on the connection ends first: up to twice the timeout
        loan = loop.lender.borrow(c, 2 * u.timeout + 0.5)
        held.set()
        try:
            client.attach(loan.fd, tid=loan.tid)
        except BaseException:
            release()
            raise
        if not made:
            made.append(MapDevice(client, u.config.map, u.config.address, budget=budget))
        return made[0]

    def release() -> None:
        if held.is_set():
            held.clear()
            tid = client.next_tid  # (the polls go on after the command's ids)
            client.close()
            loop.lender.give_back(c, tid)

    return Target(u.info.name, u.config.map, device, lambda: u.health.offline, release)
