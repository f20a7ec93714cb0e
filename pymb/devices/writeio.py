"""The wire half of a map device's write (:meth:`pymb.devices.MapDevice.write_points`):
send a planned request, read the registers (bits) of the points written,
and read them back to tell what the device applied. Each request in the
device's turn (:meth:`pymb.devices.mapfetch.Fetcher.turn`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

from pymb.client import Client
from pymb.devices.mapfetch import Fetcher
from pymb.devices.mapwrite import Change, Outcome, WriteRequest, decoded, not_applied, resolve
from pymb.maps import Map, Value
from pymb.maps.planner import Item, plan_points

__all__ = ["read_spans", "regs_of", "scale_factors", "send", "verify"]


def send(client: Client, slave: int, fetcher: Fetcher, r: WriteRequest) -> None:
    """Send one write request, in the device's turn."""
    with fetcher.turn():
        if r.function == 5:
            client.write_coil(r.address, r.values[0], slave=slave)
        elif r.function == 15:
            client.write_coils(r.address, r.values, slave=slave)
        elif r.function == 6:
            client.write_register(r.address, r.values[0], slave=slave)
        elif r.function == 16:
            client.write_registers(r.address, r.values, slave=slave)
        else:
            client.mask_write_register(r.address, r.values[0], r.values[1], slave=slave)

def read_spans(client: Client, slave: int, fetcher: Fetcher, changes: Sequence[Change],
               ) -> dict[tuple[str, int], int]:
    """(table, address) -> register (bit) of every point of ``changes``:
    adjacent ones in one request, planned as a poll's reads are (within the
    map's ``max_registers``/``max_bits`` and ``ranges``, a point never split),
    bridging no register that is not written."""
    out: dict[tuple[str, int], int] = {}
    items = [Item(c.name, c.point.table, c.point.address, c.point.count) for c in changes]
    limits = replace(fetcher.map.limits, max_gap=0)
    for r in plan_points(items, fetcher.planner.line, limits):
        with fetcher.turn():
            if r.table == "coil":
                got = client.read_coils(r.address, r.count, slave=slave)
            else:
                got = client.read_holding_registers(r.address, r.count, slave=slave)
        out.update(((r.table, r.address + k), int(v)) for k, v in enumerate(got))
    return out

def verify(client: Client, slave: int, fetcher: Fetcher, todo: Sequence[Change],
           outcomes: Sequence[Outcome], key: str) -> None:
    """Read back what was written; :class:`~pymb.WriteNotApplied` where
    the device holds another value."""
    readable = [c for c in todo if c.point.access != "w"]
    back = read_spans(client, slave, fetcher, readable) if readable else {}
    by_name = {o.name: o for o in outcomes}
    failed: list[tuple[Change, Value]] = []
    for c in readable:
        regs = regs_of(back, c)
        assert regs is not None
        o = by_name[c.name]
        o.after = decoded(c.point, regs, c.sf)
        o.applied = tuple(regs) == c.merged(regs)
        if not o.applied:
            failed.append((c, o.after))
    if failed:
        applied = {o.name: o.after for o in outcomes if o.applied}
        e = not_applied(f"{key} on {client.port}", failed, applied)
        e.outcomes = list(outcomes)
        raise e


def regs_of(current: Mapping[tuple[str, int], int], c: Change) -> list[int] | None:
    """The registers (bits) of ``c``'s point in ``current``, or None."""
    p = c.point
    try:
        return [current[(p.table, a)] for a in range(p.address, p.address + p.count)]
    except KeyError:
        return None


def scale_factors(client: Client, slave: int, fetcher: Fetcher, m: Map,
                  items: Sequence[tuple[str, int | None, object]]) -> dict[str, int | None]:
    """The scale factors the ``scale_from`` points among ``items`` need,
    read from the device (None: not implemented): name -> value."""
    names = {sf for sf in (resolve(m, n, c)[1].scale_from for n, c, _ in items)
             if sf is not None}
    out: dict[str, int | None] = {}
    if not names:
        return out
    with fetcher.quiet.lock, fetcher.map_timeout():
        fetcher.after_connect()
        for n in sorted(names):
            q = m.points[n]
            with fetcher.turn():
                read = (client.read_input_registers if q.table == "input"
                        else client.read_holding_registers)
                got = read(q.address, 1, slave=slave)
            v = m.decode(n, list(got))
            out[n] = v if isinstance(v, int) else None
    return out
