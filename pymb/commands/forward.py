"""``pymb log --mqtt``: log to SQLite and forward, with the summary."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, TextIO

from pymb.commands.status import StatusLine, status_text
from pymb.errors import InvalidArgument
from pymb.fleet import ForwardingSink
from pymb.fleet.config import MqttConfig
from pymb.fleet.forwarder import Forwarder, ForwarderStatus
from pymb.fleet.profiles import SparkplugProfile
from pymb.fleet.session import require_paho
from pymb.logger import LogConfig, Logger, RunSummary
from pymb.logger.commands import CommandDesk
from pymb.logger.targets import write_targets
from pymb.service.journal import EventLines, wanted
from pymb.store import Event, SqliteSink, check_output
from pymb.store.commands import CommandLog
from pymb.store.eventlog import append_events

if TYPE_CHECKING:
    from pymb.service.run import Service

__all__ = ["forwarding", "log_and_forward", "summary_lines"]

def summary_lines(st: ForwarderStatus) -> list[str]:
    """The forwarder's part of the summary."""
    ack = "never" if st.last_ack is None else time.strftime(
        "%Y-%m-%d %H:%M:%S", time.localtime(st.last_ack))
    lines = [f"mqtt: {st.acked:,} samples acknowledged by the broker ({st.published:,} "
             f"published, {st.connections} connection(s)); last acknowledgement {ack}"]
    if st.refusal is not None:
        lines.append(f"mqtt: the broker refuses samples ({st.refusal}): they are kept in the "
                     "database and offered again")
    if st.backlog:
        age = "" if st.backlog_age is None else f", the oldest {st.backlog_age:.0f} s old"
        lines.append(f"mqtt: {st.backlog:,} samples not yet acknowledged{age}: they are kept "
                     "in the database and sent by the next run")
    else:
        lines.append("mqtt: nothing left to send")
    return lines


def forwarding(cfg: LogConfig, mqtt: MqttConfig, *, seconds: float | None,
               status: TextIO | None, service: Service[Logger] | None = None,
               ) -> tuple[RunSummary, ForwarderStatus]:
    """Log as ``cfg`` says while a forwarder publishes; then let it send what is
    left (for at most ``mqtt.drain`` seconds) and return both summaries. With a
    ``service``, events are lines on stderr too (when it is not a terminal) and the
    service has its turn in the logger's tick."""
    require_paho()  # before the database is created
    check_output(cfg.format, cfg.path)  # never into a file of another kind
    if cfg.format != "sqlite":
        raise InvalidArgument("--mqtt forwards from the SQLite database (the outbox)")
    for bus in cfg.buses:
        for d in bus.devices:
            mqtt.check_device(d.name)
    # Only this thread (the logger's run) uses the writer's connection: the
    # forwarder and the command desk hand it their work (one_thread: SQLite's
    # thread check says so if one ever does not).
    sink = SqliteSink(cfg.path, max_bytes=cfg.max_bytes, max_age=cfg.max_age,
                      on_change=cfg.on_change, one_thread=True)
    echo = EventLines(sys.stderr) if service is not None and wanted(sys.stderr) else None
    try:
        fw = Forwarder(cfg.path, mqtt, writer=sink)
    except BaseException:
        sink.close()
        raise
    fw.say = echo is None  # else its events are lines on stderr already
    desk = None
    try:
        tick: Callable[[Logger, float, bool], None] | None = None
        if status is not None:
            tick = StatusLine(status, lambda: fw.status().line())
        if service is not None:
            service.text = lambda lg, t: f"{status_text(lg, t)}  {fw.status().line()}"
            tick = service.tick(tick)
        out = ForwardingSink(sink, fw, echo)
        logger = Logger(cfg, sink=out, tick=tick)
        if cfg.allow_writes:
            desk = command_desk(cfg, logger, out, fw)
        fw.start()
        if service is not None:
            service.attach(logger)
        s = logger.run(seconds)
    finally:
        if desk is not None:
            desk.stop()
        if fw.ident is None:  # the logger could not be made: nothing was sent
            sink.close()
        else:
            fw.notify()
            fw.stop()
            fw.join(mqtt.drain + 10)
            _late_events(cfg.path, fw.take_events(), echo)
    if fw.error is not None:
        raise fw.error
    return s, fw.status()


def _late_events(path: str, events: list[tuple[float, str]],
                 echo: Callable[[Event], None] | None) -> None:
    """The forwarder's events of its drain and goodbye, which come after the
    logger's database is closed: into its event log all the same (kind
    ``mqtt``), and lines on stderr as the others are (``echo``)."""
    if not events:
        return
    rows = [Event(t, time.monotonic(), "mqtt", None, "mqtt", None, m) for t, m in events]
    append_events(path, rows)
    if echo is not None:
        for e in rows:
            echo(e)


def command_desk(cfg: LogConfig, logger: Logger, out: ForwardingSink, fw: Forwarder,
                 ) -> CommandDesk:
    """The desk that executes write commands from ``fw``'s set topics on the
    logger's devices, recorded in the database ``out`` writes: by the
    logger's thread, at its next turn (the desk's thread asks and waits)."""
    if cfg.format != "sqlite":
        raise InvalidArgument("--allow-writes needs the SQLite database: its record of "
                              "commands makes each id execute once")
    out.in_writer.wake = logger.wake
    log = CommandLog(out.in_writer)
    desk = CommandDesk(log, write_targets(logger.pollers, log), cfg.allow_writes,
                       fw.record_event)
    devices = desk.writable()
    if not devices:  # the patterns come from the command line or the file's [writes]
        can = sorted(f"{n}/{p.name}" + ("_N" if p.block else "")
                     for n, t in desk.targets.items() for p in t.map.points.values()
                     if p.writable)
        hint = (f"; writable: {', '.join(can[:10])}" + (", ..." if len(can) > 10 else "")
                if can else "; no logged device has a writable point")
        raise InvalidArgument(f"--allow-writes ([writes] allow) {' '.join(cfg.allow_writes)}: "
                              "no writable point of a logged device matches (DEVICE/POINT, "
                              f"the device's name){hint}")

    def reply(device: str, payload: bytes) -> bool:
        # offline: the record answers the command again (the broker's redelivery, a retry)
        return fw.publish_result(device, payload)

    desk.reply = reply
    source = "mqtt"
    prof = fw.profile
    if isinstance(prof, SparkplugProfile):  # DCMD: DBIRTH says writable, DDATA answers
        source = "sparkplug"
        prof.writable = desk.may_write
        desk.births = prof.birth_aliases
        desk.answer = fw.answer_dcmd
    fw.take_commands(devices, lambda device, payload, done, retained: desk.submit(
        source, device, payload, done, retained=retained))
    # A command goes from paho's thread to the desk's, the writer's lock and the TCP
    # loop's: with Python's default 5 ms switch interval, each hand-over can wait that
    # long for the GIL while the polls and the forwarder hold it.
    sys.setswitchinterval(0.0005)
    desk.start()
    return desk


def log_and_forward(cfg: LogConfig, mqtt: MqttConfig, *, seconds: float | None,
                    quiet: bool, service: Service[Logger] | None = None) -> int:
    """``pymb log --mqtt``: log and forward, then print the summary."""
    s, st = forwarding(cfg, mqtt, seconds=seconds, status=None if quiet else sys.stderr,
                       service=service)
    if not quiet:
        print(s.headline(), file=sys.stderr)
        for line in [*s.health(), *summary_lines(st)]:
            print(line, file=sys.stderr)
    for line in s.problems():  # a bus that never opened, a device that never delivered
        print(f"pymb log: {line}", file=sys.stderr)
    return s.exit_code
