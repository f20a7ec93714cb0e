"""Write commands from the network (MQTT ``.../set``), executed once per id:
:class:`CommandDesk`.

A command is checked whole (its points exist, are writable, allowed by
``[writes] allow`` and fit their maps), then its write budget; a refusal
writes nothing. A command that will write is put on record (committed)
*before* its write goes out, so a logger killed between the write and the
result never writes it again: the command redelivered, or sent again with
the same id, is answered from the record. Writes use the device's own
:class:`~pymb.devices.MapDevice` and its line lock, so they go between polls.
"""

from __future__ import annotations

import collections
import fnmatch
import json
import threading
import time
from collections.abc import Callable, Mapping, Sequence

from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapwrite import Outcome, check, check_budgets, resolve
from pymb.errors import InvalidArgument, ModbusError, OutputError, WriteNotApplied, WriteRefused
from pymb.fleet.protobuf import MetricValue
from pymb.jsonvalue import JsonObject
from pymb.logger.dcmd import handle_dcmd
from pymb.logger.refusal import Refused, Target, unrecorded
from pymb.maps import Value
from pymb.store.commands import CommandLog, PointRow

__all__ = ["CommandDesk", "Refused", "Target", "allowed", "reason_of"]

QUEUE_MAX = 2048  #: commands waiting at most; more are dropped (and said once)
#: why a command the broker held retained from before the logger subscribed is
#: not executed: commands are never queued past the moment they could be executed
RETAINED = ("a retained command, held by the broker from before the logger subscribed: not "
            "executed (publish commands without retain)")
_UNKNOWN = ("the logger stopped while this command was being executed; it is not executed "
            "again: read the points to know their values")


def allowed(patterns: Sequence[str], device: str, point: str) -> bool:
    """Whether ``DEVICE/POINT`` matches one of ``patterns`` (fnmatch)."""
    return any(fnmatch.fnmatchcase(f"{device}/{point}", p) for p in patterns)


def reason_of(e: InvalidArgument) -> str:
    """``range`` for a value outside what the point takes, else ``invalid``."""
    text = str(e)
    if any(w in text for w in ("outside", "not one of its values", "does not fit", "too long",
                               "longer than")):
        return "range"
    if "read-only" in text:
        return "not_allowed"
    return "invalid"


def _now_iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t * 1000) % 1000:03d}Z"


class CommandDesk(threading.Thread):
    """Executes the commands :meth:`submit` hands it, one at a time, and
    hands each result to ``reply(device, payload)``."""

    def __init__(self, log: CommandLog, targets: Mapping[str, Target], allow: Sequence[str],
                 event: Callable[[str], None]) -> None:
        super().__init__(name="pymb-commands", daemon=True)
        self.log = log
        self.targets = dict(targets)
        self.allow = tuple(allow)
        self.event = event
        #: publishes a result; False: not sent (the broker is not acknowledged the command)
        self.reply: Callable[[str, bytes], bool] | None = None
        #: Sparkplug: (device, values read back, metric names) of an executed DCMD
        self.answer: Callable[[str, dict[str, MetricValue], list[str]], None] | None = None
        #: Sparkplug: the device's DBIRTH metrics (name -> alias), None before it
        self.births: Callable[[str], dict[str, int] | None] = lambda device: None
        self._queue: collections.deque[
            tuple[str, str, bytes, Callable[[], None] | None, bool]] = collections.deque()
        self._cond = threading.Condition()
        self._stop = False
        self._dropped = 0
        self.handled = 0  #: commands answered
        #: the record of the command in hand's result, written once it is answered
        self._records: list[Callable[[], None]] = []

    def writable(self) -> list[str]:
        """The devices with at least one point commands may write."""
        return [n for n, t in self.targets.items()
                if any(p.writable and allowed(self.allow, n, p.name)
                       for p in t.map.points.values())]

    def submit(self, source: str, device: str, payload: bytes,
               done: Callable[[], None] | None = None, *, retained: bool = False) -> None:
        """A command arrived (any thread; never blocks); ``done()`` is called
        once its result is handed to :attr:`reply` (or it is dropped): the
        broker's acknowledgement of a persistent session's command.
        ``retained``: the broker held it from before the subscription (it is
        not executed: :data:`RETAINED`)."""
        with self._cond:
            if len(self._queue) >= QUEUE_MAX:
                self._dropped += 1
                if self._dropped == 1:
                    self.event(f"write commands arrive faster than they can be answered: "
                               f"more than {QUEUE_MAX} wait; the rest are dropped unanswered")
            else:
                self._queue.append((source, device, bytes(payload), done, retained))
                self._cond.notify()
                return
        if done is not None:
            done()

    def stop(self) -> None:
        """End after the command in hand."""
        with self._cond:
            self._stop = True
            self._cond.notify()

    def run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                source, device, payload, done, retained = self._queue.popleft()
                if not self._queue:
                    self._dropped = 0
            try:
                out = self.run_command(source, device, payload, retained=retained)
            except Exception as e:  # a database failure: said, and the desk goes on
                self.event(f"write command for {device} failed: {e}")
                out = None
            else:
                self.handled += 1
            sent = True
            if out is not None and self.reply is not None:
                sent = self.reply(device, out)
            try:
                self.record()  # the result's record waits for no lock before it goes out
            except Exception as e:
                self.event(f"write command for {device}: its result not recorded: {e}")
            if done is not None and sent:  # else delivered again on the next connection
                done()

    # -- one command ------------------------------------------------------------------

    def handle(self, source: str, device: str, payload: bytes) -> bytes | None:
        """Execute one command and record its result; returns the result to
        publish (a DCMD's answer goes to :attr:`answer` instead)."""
        try:
            return self.run_command(source, device, payload)
        finally:
            self.record()

    def record(self) -> None:
        """Record the result of the command executed last (:meth:`run_command`)."""
        records, self._records = self._records, []
        for r in records:
            r()

    def run_command(self, source: str, device: str, payload: bytes, *,
                    retained: bool = False) -> bytes | None:
        """Execute one command; returns the result to publish. Its result's
        record waits for :meth:`record` (the command itself is on record
        before its write), so the result goes out first: the desk executes
        one command at a time, so the next, the same id sent again, finds it.
        A ``retained`` command on record gets its result; else it is refused."""
        if source == "sparkplug":
            handle_dcmd(self, device, payload, retained=retained)
            return None
        try:
            doc = json.loads(payload)
        except (ValueError, UnicodeDecodeError, RecursionError):  # (nested too deep)
            doc = None
        cid = doc.get("id") if isinstance(doc, dict) else None
        if not (isinstance(cid, str) and 1 <= len(cid) <= 64 and cid.isprintable()):
            why = "not a JSON object" if not isinstance(doc, dict) else \
                "the id must be a string of 1 to 64 printable characters"
            self.event(f"write command for {device} refused: {why}")
            return self._result(cid if isinstance(cid, str) else None, False, {}, "invalid", why)
        try:
            known, stored = self.log.seen(cid)
        except OutputError as e:
            return self._unrecorded(cid, device, e)
        if stored is not None:
            return stored.encode()
        if known:  # on record, no result: the logger stopped during its write
            out = self._result(cid, False, {}, "device", _UNKNOWN)
            try:
                self.log.finish(cid, device, source, out.decode(), [])
            except OutputError as e:
                self.event(f"write command {cid} for {device}: its result not recorded: {e}")
            return out
        values = doc.get("values")
        target = self.targets.get(device)
        rows: list[PointRow] = []
        try:
            if target is None:
                raise Refused("invalid", f"no device {device!r} takes commands here")
            if retained:
                raise Refused("invalid", RETAINED)
            if not isinstance(values, dict) or not values:
                raise Refused("invalid", "values must be an object of point names to values")
            rows = [PointRow(str(n), v) for n, v in values.items()]
            dev = self.check_command(target, values)
        except OutputError as e:  # the write budget's record
            return self._unrecorded(cid, device, e)
        except Refused as r:
            for row in rows:
                row.reason = r.reason
            self._records.append(lambda: self.log.receive(cid, device, source, durable=False))
            return self._finish(cid, device, source, rows, {}, r.reason, str(r), durable=False)
        items = [(n, None, v) for n, v in values.items()]
        try:
            self.log.receive(cid, device, source, durable=True)  # on record before the write
        except OutputError as e:
            target.release()
            return self._unrecorded(cid, device, e)
        try:
            outcomes = dev.write_points(items, before=True)
        except WriteNotApplied as e:
            self._fill(rows, e.outcomes, "not_applied")
            return self._finish(cid, device, source, rows, e.applied, "not_applied", str(e))
        except WriteRefused as e:
            for row in rows:
                row.reason = e.reason
            return self._finish(cid, device, source, rows, {}, e.reason, str(e))
        except ModbusError as e:
            for row in rows:
                row.reason = "device"
            return self._finish(cid, device, source, rows, {}, "device", str(e))
        finally:
            target.release()  # the line goes back to its polls
        self._fill(rows, outcomes, None)
        return self._finish(cid, device, source, rows, {o.name: o.after for o in outcomes},
                            None, None)

    def may_write(self, device: str, name: str) -> bool:
        """Whether commands may write point ``name`` (``x_N``: a block's
        channel) of ``device``: writable in its map and allowed."""
        t = self.targets.get(device)
        if t is None or not allowed(self.allow, device, name):
            return False
        try:
            return resolve(t.map, name)[1].writable
        except InvalidArgument:
            return False

    def check_point(self, t: Target, name: str, value: object) -> None:
        """Section 1's checks of one value and the allow list: a ``Refused``
        when it may not be written."""
        m = t.map
        try:
            _, p = resolve(m, name)
        except InvalidArgument as e:
            raise Refused("invalid", str(e)) from None
        if not p.writable:
            raise Refused("not_allowed", f"{t.name}: point {name!r} is read-only")
        if not allowed(self.allow, t.name, name):
            raise Refused("not_allowed", f"{t.name}: point {name!r} is not in the "
                           "allow list of [writes] (or --allow-writes)")
        try:
            check(m, [(name, None, value)])
        except InvalidArgument as e:
            raise Refused(reason_of(e), str(e)) from None

    def check_command(self, t: Target, values: Mapping[str, object]) -> MapDevice:
        """A whole command checked (each value, the device online, the budgets):
        the device to write, or a ``Refused``."""
        m = t.map
        for name, value in values.items():
            self.check_point(t, name, value)
        try:
            changes = check(m, [(n, None, v) for n, v in values.items()])
        except InvalidArgument as e:
            raise Refused(reason_of(e), str(e)) from None
        try:
            dev = None if t.offline() else t.device()
        except ModbusError as e:
            raise Refused("device", str(e)) from None
        if dev is None:
            raise Refused("device", f"{t.name} is offline: nothing was sent")
        try:
            check_budgets(dev.budget, f"{m.id}:{dev.address}", changes, t.name)
        except BaseException as e:
            t.release()  # (a database failure too: the line goes back to its polls)
            if isinstance(e, WriteRefused):
                raise Refused(e.reason, str(e)) from None
            raise
        return dev

    @staticmethod
    def _fill(rows: list[PointRow], outcomes: Sequence[Outcome], reason: str | None) -> None:
        by = {o.name: o for o in outcomes}
        for row in rows:
            o = by.get(row.point)
            if o is None:
                continue
            row.before, row.after = o.before, o.after
            row.ok = bool(o.applied) or (o.applied is None and o.sent)
            row.reason = None if row.ok else reason

    def _finish(self, cid: str, device: str, source: str, rows: list[PointRow],
                values: Mapping[str, Value], reason: str | None, error: str | None, *,
                durable: bool = False) -> bytes:
        out = self._result(cid, reason is None, values, reason, error)
        self._records.append(lambda: self.log.finish(cid, device, source, out.decode(), rows,
                                                     durable=durable))
        if reason is not None:
            self.event(f"write command {cid} for {device} refused ({reason}): {error}")
        return out

    def _unrecorded(self, cid: str, device: str, e: OutputError) -> bytes:
        """The result of a command whose record could not be read or written:
        refused (reason ``device``: try again later), nothing written."""
        why = unrecorded(e)
        self.event(f"write command {cid} for {device} {why}")
        return self._result(cid, False, {}, "device", why)

    @staticmethod
    def _result(cid: str | None, ok: bool, values: Mapping[str, Value], reason: str | None,
                error: str | None) -> bytes:
        doc: JsonObject = {"id": cid, "ok": ok}
        if not ok:
            doc["reason"] = reason
            doc["error"] = error
        doc["values"] = dict(values)
        doc["time"] = _now_iso(time.time())
        try:
            return json.dumps(doc, ensure_ascii=False, allow_nan=False,
                              separators=(",", ":")).encode()
        except UnicodeEncodeError:  # a lone surrogate (an id refused): as \uXXXX escapes
            return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode()
