"""Sparkplug B device commands (DCMD) as writes: :func:`handle_dcmd`.

A DCMD names metrics of the device's DBIRTH by name or by alias. Each
metric is checked as any write is (its point exists, is writable, its value
fits; the allow list); one refused metric refuses the whole DCMD, so nothing
of it is written, and a metric that names no metric of the DBIRTH is refused
too. The DCMD is on record before its write goes out, and is answered by a
DDATA of its metrics: the values read back where written, else their current
values (the device's latest sample, or the read back of a write the device
did not apply).

A DCMD's command id, in the ``writes`` view, is
``sparkplug:{device}:{payload timestamp}:{seq}`` (``-`` for a missing seq);
the same DCMD delivered again (same device, timestamp, seq and bytes) is
not executed again; another DCMD of the same timestamp and seq (sent within
one millisecond, without a seq) gets ``:`` and 16 hex digits of its payload's
SHA-256 after that id. A DCMD without a timestamp gets its arrival time in
nanoseconds instead, so it is never taken for another.
"""

from __future__ import annotations

import hashlib
import json
import time

from pymb.devices.mapwrite import Outcome, resolve
from pymb.errors import InvalidArgument, ModbusError, OutputError, WriteNotApplied, WriteRefused
from pymb.fleet.mapmetrics import datatype, plain_value
from pymb.fleet.profiles import write_name
from pymb.fleet.protobuf import MetricValue, command_values
from pymb.logger.refusal import Desk, Refused, Target, unrecorded
from pymb.maps import Value
from pymb.store.commands import PointRow

__all__ = ["command_id", "handle_dcmd"]

SOURCE = "sparkplug"
_UNKNOWN = ("the logger stopped while it was being executed; its DDATA carries the current "
            "values")


def command_id(device: str, timestamp: int | None, seq: int | None) -> str:
    """The record's id of a DCMD (see the module docstring)."""
    if timestamp is None:
        return f"{SOURCE}:{device}:arrived-{time.time_ns()}"
    return f"{SOURCE}:{device}:{timestamp}:{'-' if seq is None else seq}"


def _metric_value(t: Target, name: str, v: Value) -> MetricValue:
    """A value read back as its metric carries it (an enum's number, not its name)."""
    try:
        p = resolve(t.map, name)[1]
    except InvalidArgument:
        return plain_value(v)
    if p.values and isinstance(v, str):
        for raw, label in p.values.items():
            if label == v:
                return raw
    return plain_value(v)


def handle_dcmd(desk: Desk, device: str, payload: bytes, *, retained: bool = False) -> None:
    """Execute one DCMD for ``device`` and hand its DDATA to ``desk.answer``
    (``retained``: held by the broker from before the subscription, which
    Sparkplug forbids: refused unless on record)."""
    target = desk.targets.get(device)
    birth = desk.births(device) or {}
    by_alias = {a: n for n, a in birth.items()}

    def declared(name: str | None, alias: int | None) -> int | None:
        """The DBIRTH's datatype of a metric named by name or alias."""
        metric = name if name is not None else by_alias.get(alias) if alias is not None else None
        if target is None or metric is None or metric not in birth:
            return None
        try:
            return int(datatype(resolve(target.map, write_name(metric))[1]))
        except InvalidArgument:
            return None

    try:
        ts, seq, metrics = command_values(payload, declared)
    except (ValueError, UnicodeDecodeError, OverflowError) as e:  # (a float's field too big)
        desk.event(f"DCMD for {device} ignored: not a Sparkplug B payload ({e})")
        return
    cid = command_id(device, ts, seq)
    named = [n for n in (name if name is not None else
                         by_alias.get(alias) if alias is not None else None
                         for name, alias, _ in metrics) if n is not None and n in birth]
    digest = hashlib.sha256(payload).hexdigest()[:16]
    try:
        known, stored = desk.log.seen(cid)
        if stored is not None and json.loads(stored).get("digest", digest) != digest:
            cid = f"{cid}:{digest}"  # another DCMD of the same timestamp and seq
            known, stored = desk.log.seen(cid)
    except OutputError as e:
        _unrecorded(desk, cid, device, e, named)
        return
    if known:
        desk.event(f"DCMD {cid} was received before: not executed again")
        if stored is None:  # on record, no result: the logger stopped during its write
            desk.event(f"DCMD {cid}: {_UNKNOWN}")
            try:
                _finish(desk, cid, device, [], "device", named, durable=True,
                        digest=digest)
            except OutputError as e:
                desk.event(f"DCMD {cid}: its result not recorded: {e}")
            _answer(desk, device, {}, named)
            return
        _answer(desk, device, {}, json.loads(stored).get("metrics", []))
        return
    rows: list[PointRow] = []
    refusals: list[Refused | None] = []
    names: list[str] = []  #: the DBIRTH metrics it names
    items: list[tuple[str, int | None, object]] = []
    for name, alias, value in metrics:
        metric = name if name is not None else by_alias.get(alias) if alias is not None else None
        label = metric if metric is not None else (
            f"alias {alias}" if alias is not None else "(no name, no alias)")
        refusal: Refused | None = None
        if target is None or metric is None or metric not in birth:
            refusal = Refused("invalid", f"{device}: the DCMD metric {label!r} names no "
                              "metric of the DBIRTH")
            rows.append(PointRow(label, value))
        else:
            point = write_name(metric)
            names.append(metric)
            items.append((point, None, value))
            rows.append(PointRow(point, value))
            try:
                desk.check_point(target, point, value)
            except Refused as why:
                refusal = why
        refusals.append(refusal)
    if not metrics:
        refusals.append(Refused("invalid", f"{device}: the DCMD names no metric"))
    if retained:
        refusals = [Refused("invalid", f"{device}: a retained DCMD, held by the broker from "
                            "before the node subscribed: not executed")] * max(len(rows), 1)
    first = next((r for r in refusals if r is not None), None)
    if first is None and target is not None:
        try:
            dev = desk.check_command(target, {p: v for p, _, v in items})
        except OutputError as e:  # the write budget's record
            _unrecorded(desk, cid, device, e, names)
            return
        except Refused as why:
            first = why
            refusals = [why] * len(rows)
    if first is not None or target is None:
        first = first or Refused("invalid", f"no device {device!r} takes commands here")
        for row, r in zip(rows, refusals, strict=False):
            row.reason = (r or first).reason
            if r is not None:
                desk.event(f"DCMD {cid}: {row.point!r} refused ({r.reason}): {r}")
        if all(r is None for r in refusals[:len(rows)]):
            desk.event(f"DCMD {cid} refused ({first.reason}): {first}")
        try:
            desk.log.receive(cid, device, SOURCE, durable=False)
            _finish(desk, cid, device, rows, first.reason, names, durable=False, digest=digest)
        except OutputError as e:
            desk.event(f"DCMD {cid}: its refusal not recorded: {e}")
        _answer(desk, device, {}, names)
        return
    to_metric = dict(zip([p for p, _, _ in items], names, strict=True))
    outcomes: list[Outcome] = []
    reason: str | None = None
    try:
        desk.log.receive(cid, device, SOURCE, durable=True)  # on record before the write
    except OutputError as e:
        target.release()
        _unrecorded(desk, cid, device, e, names)
        return
    try:
        outcomes = dev.write_points(items, before=True)
    except WriteNotApplied as e:
        outcomes, reason = list(e.outcomes), "not_applied"
        desk.event(f"DCMD {cid} for {device} not applied: {e}")
    except WriteRefused as e:
        reason = e.reason
        desk.event(f"DCMD {cid} for {device} refused ({e.reason}): {e}")
    except ModbusError as e:
        reason = "device"
        desk.event(f"DCMD {cid} for {device} failed (device): {e}")
    finally:
        target.release()  # the line goes back to its polls
    by = {o.name: o for o in outcomes}
    values: dict[str, MetricValue] = {}
    for row in rows:
        o = by.get(row.point)
        if o is None:
            row.reason = reason
            continue
        row.before, row.after = o.before, o.after
        row.ok = bool(o.applied) or (o.applied is None and o.sent)
        row.reason = None if row.ok else reason
        if o.after is not None:
            values[to_metric[row.point]] = _metric_value(target, row.point, o.after)
    try:
        _finish(desk, cid, device, rows, reason, names, durable=True, digest=digest)
    except OutputError as e:  # it is on record as received: never written again
        desk.event(f"DCMD {cid}: its result not recorded: {e}")
    _answer(desk, device, values, names)


def _finish(desk: Desk, cid: str, device: str, rows: list[PointRow],
            reason: str | None, names: list[str], *, durable: bool, digest: str) -> None:
    result = json.dumps({"id": cid, "ok": reason is None, "reason": reason,
                         "metrics": names, "digest": digest}, separators=(",", ":"))
    desk.log.finish(cid, device, SOURCE, result, rows, durable=durable)


def _unrecorded(desk: Desk, cid: str, device: str, e: OutputError, names: list[str]) -> None:
    """A DCMD whose record could not be read or written: said, nothing written,
    answered with the current values of the metrics it names."""
    desk.event(f"DCMD {cid} for {device} {unrecorded(e)}")
    _answer(desk, device, {}, names)


def _answer(desk: Desk, device: str, values: dict[str, MetricValue],
            names: list[str]) -> None:
    if desk.answer is not None and names:
        desk.answer(device, values, names)
