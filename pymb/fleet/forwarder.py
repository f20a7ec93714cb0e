"""The forwarder: samples from the SQLite file to an MQTT broker.

A thread publishes the samples in id order and advances a durable cursor
(the ``outbox`` table, see :mod:`pymb.store.outbox`) only past samples the
broker acknowledged. On a lost connection it reconnects with a doubling
backoff (0.5 s to 30 s); each connection starts with its profile's births,
then two lanes run side by side:

* live: samples committed since the connection started, as fast as the
  broker acknowledges them (at most ``WINDOW`` in flight);
* catch-up: everything older that is still unacknowledged (the backlog of
  an outage or of a restart, SIGKILL included), paced at ``catchup_rate``
  messages per second, marked ``is_historical`` in Sparkplug.

Run beside the logger's writer (``writer``), it publishes each sample the
writer hands it as data (:mod:`pymb.store.handoff`) before its commit: the
writer's commits stay as rare as without MQTT (SD wear), and the sample's id
is under the writer's durable high-water mark (:mod:`pymb.store.ids`), so a
power cut that takes the batch back never lets another sample have that id.
The backlog is read on the forwarder's own connection; without a writer it
publishes what is committed.

Every sample reaches the broker at least once; a sample acknowledged but not
yet recorded in the cursor when pymb dies (the cursor goes in with each of
the logger's batches, see :class:`pymb.fleet.ForwardingSink`; plus the live
lane of a connection whose catch-up had not finished) is sent again:
consumers drop duplicates by the sample's id.

The cursor is keyed by what identifies the receiver: the address the
broker's host name resolved to on the first connection of the run (the
peer of the socket), its port, the profile and the node (and the Sparkplug
group): ``mqtt://127.0.0.1:1883/plain/board-7``. Another spelling of the same
broker (``localhost``, ``127.0.0.1``) finds the same cursor; a cursor an older
pymb keyed by the URL's text is taken over. A new cursor starts at the
oldest sample (``start = "oldest"``, every sample in the database is sent)
or after the samples committed before the run (``start = "now"``); one that
would send more than a day of samples says so in one line on stderr.
"""

from __future__ import annotations

import collections
import contextlib
import ssl
import sys
import threading
import time
from typing import Any

from pymb.fleet.commands import CommandTopics
from pymb.fleet.config import MqttConfig
from pymb.fleet.cursor import Acknowledged, CursorWriter, destination
from pymb.fleet.health import Down, due_downs
from pymb.fleet.lanes import WINDOW, Publisher, catch_up_lane, live_lane
from pymb.fleet.profiles import BACKLOG, Profile, make_profile
from pymb.fleet.session import Session, require_paho
from pymb.fleet.status import ForwarderStatus
from pymb.fleet.takeover import Takeovers
from pymb.store import Outbox, StoredSample
from pymb.store.handoff import Handoff
from pymb.store.outbox import LiveWriter, last_sample_id

__all__ = ["Forwarder", "ForwarderStatus", "destination"]

REPLAY_NOTICE = 86400.0  #: seconds of samples a new cursor sends without a notice
CURSOR_EVERY = 0.25  #: seconds between writes of the cursor
_BACKOFF_FIRST, _BACKOFF_MAX = 0.5, 30.0
#: seconds before refused samples are offered again: doubling from the first to the last
RETRY_FIRST, RETRY_MAX = 5.0, 300.0


class Forwarder(threading.Thread, CommandTopics):
    """Publishes the samples of ``db_path``: those ``writer`` (the
    :class:`pymb.store.SqliteSink` writing it, if in this process) writes,
    else those committed; see the module docstring.

    ``notify()`` after each write or commit wakes it at once (it also looks every
    0.2 s); ``stop()`` ends it after at most ``cfg.drain`` seconds (or the
    ``drain`` given) spent sending what is left, then disconnects cleanly (the
    profile's goodbye).
    """

    def __init__(self, db_path: str, cfg: MqttConfig, writer: LiveWriter | None = None) -> None:
        super().__init__(name="pymb-mqtt", daemon=True)
        require_paho()
        self.handoff: Handoff | None = None  #: the writer's samples here, the cursor back
        if writer is not None:
            self.handoff = Handoff()
            writer.publish_live(self.handoff)
        self.cfg = cfg
        self.profile: Profile = make_profile(cfg)
        #: the broker as the URL names it (for messages; an older pymb's cursor key)
        self.where = destination(cfg, cfg.host)
        #: the outbox cursor's key (see the module docstring); None until the first
        #: connection of the run has resolved the broker's address
        self.dest: str | None = None
        #: print the new-cursor notice on stderr (False: the events are lines there already)
        self.say = True
        self.source = Outbox(db_path, self.handoff)  #: this thread's connection to the file
        #: where a new cursor starts with start = "now": after what is committed already
        self._now_id = max(last_sample_id(db_path), self.handoff.written if self.handoff else 0)
        self.password = cfg.password()
        self.wake = threading.Event()
        self.rebirth = threading.Event()
        self._stopping = threading.Event()
        self._drain_until = 0.0
        self.acked = Acknowledged()  #: what the broker acknowledged: the cursor and above
        self._saved_cursor = self._handed_cursor = self.cursor
        self._saved_at = 0.0
        self._writer = CursorWriter(db_path)
        self._lock = threading.Lock()
        self._events: list[tuple[float, str]] = []
        self._downs_in: list[tuple[Down, int]] = []  #: from the logger's thread
        self._downs: list[tuple[Down, int]] = []  #: not yet published (this thread)
        #: the timestamps of the last STATE and of the last online STATE accepted
        self.host_ts: float | None = None
        self.host_online_ts: float | None = None
        self._status = ForwarderStatus(False, "connecting", 0, 0, 0, None, None, 0.0, 0,
                                       self.cursor)
        #: the broker's last reason for refusing a sample, until it takes that sample
        self._refusal: str | None = None
        self._first_refused = 0  #: the lowest sample id refused since
        self._refused_here = False  #: a sample was refused on this connection
        self._said: set[str] = set()  #: the reasons said since the broker last took one
        #: (topic, reason) of the subscriptions the broker refused, said once a run
        self._subs_said: set[tuple[str, str]] = set()
        self._retry_at = 0.0  #: when this connection ends to offer them again
        self._retry_wait = RETRY_FIRST
        self._published = self._acked = self._connections = 0
        self._last_ack: float | None = None
        #: (monotonic time, samples) of the acknowledgements of the last few seconds
        self._ack_times: collections.deque[tuple[float, int]] = collections.deque()
        self.error: BaseException | None = None
        self._takeovers = Takeovers(f"pymb-{cfg.profile}-{cfg.node}", cfg.node, _BACKOFF_MAX)
        CommandTopics.__init__(self)

    # -- the public side -----------------------------------------------------------

    @property
    def cursor(self) -> int:
        """Every sample id up to this one was acknowledged (the outbox cursor)."""
        return self.acked.cursor

    def take_events(self) -> list[tuple[float, str]]:
        """(time, message) of what happened to the connection since the last call,
        for the logger's event log (see :class:`pymb.fleet.ForwardingSink`)."""
        with self._lock:
            out, self._events = self._events, []
        return out

    def record_event(self, message: str) -> None:
        """Add a line to the connection's story (the event log the logger stores)."""
        with self._lock:
            if len(self._events) < 1000:
                self._events.append((time.time(), message))

    def notify(self) -> None:
        """New samples were committed."""
        self.wake.set()

    def devices_down(self, downs: list[Down], upto: int) -> None:
        """Devices stopped answering; ``upto``: the highest sample id committed
        with the news. Each goes out (Sparkplug: DDEATH) after the samples up to
        ``upto`` and before its device's next sample."""
        with self._lock:
            self._downs_in += [(d, upto) for d in downs]
        self.wake.set()

    def status(self) -> ForwarderStatus:
        """The latest snapshot (thread-safe)."""
        with self._lock:
            return self._status

    def stop(self, drain: float | None = None) -> None:
        """Send what is left for at most ``drain`` seconds (default: the
        configuration's), then disconnect and end."""
        self._drain_until = time.monotonic() + (self.cfg.drain if drain is None else drain)
        self._stopping.set()
        self.wake.set()

    # -- the thread ----------------------------------------------------------------

    def run(self) -> None:
        self._writer.start()
        try:
            self._run()
        except BaseException as e:  # reported by the command, never lost silently
            self.error = e
        finally:
            self._save_cursor(force=True)
            self._writer.close()
            self.error = self.error or self._writer.error
            self._snapshot("stopped", False)
            self.source.close()

    def _run(self) -> None:
        backoff = _BACKOFF_FIRST
        was_down = ""
        again = False
        while not self._stopping.is_set():
            s = self._connect()
            if s is not None and s.ok:
                self._takeovers.up()
                self._connections += 1
                if self.dest is None:
                    self._key(s)
                if not again:
                    self.record_event(f"connected to {self.dest}")
                was_down = ""
                self._session = s
                try:
                    self._pump(s)
                finally:
                    self._session = None
                self._close(s)
                if self._stopping.is_set():
                    return
                again = s.again
                if again:  # to offer refused samples again: at once, no story
                    backoff = _BACKOFF_FIRST
                    continue
                anew, line = self._takeovers.down(s.ended_by_broker, s.taken_over)
                if anew:
                    backoff = _BACKOFF_FIRST
                if line is not None:
                    self._say(line)
                elif not self._takeovers.said:  # said once, not at each takeover
                    self.record_event(f"lost the connection to {self.dest}: "
                                      f"{s.reason or 'closed'}; the samples go on "
                                      "accumulating in the database")
                if self._takeovers.said:
                    s.reason = f"taken over by another {self._takeovers.client_id}?"
            else:  # the broker was away: not a takeover (a restart is not one)
                self._takeovers.away()
            again = False
            reason = "connecting" if s is None else (s.reason or "disconnected")
            if reason != was_down and not (s is not None and s.ok):
                self.record_event(f"cannot connect to {self.dest or self.where}: {reason}")
                was_down = reason
            until = time.monotonic() + backoff
            while (left := until - time.monotonic()) > 0:
                self._snapshot(f"down ({reason}), retry in {left:.0f} s", False)
                if self._stopping.wait(min(left, 0.5)):
                    return
            backoff = min(backoff * 2, _BACKOFF_MAX)

    def _say(self, line: str) -> None:
        """An event, and a line on stderr (unless the events are lines there already)."""
        self.record_event(line)
        if self.say:
            with contextlib.suppress(OSError, ValueError):
                print(f"pymb log: {line}", file=sys.stderr, flush=True)

    def _connect(self) -> Session | None:
        cfg = self.cfg
        self.profile.new_connection(self.source)
        s = Session(self, self._takeovers.client_id, WINDOW)
        self._session = s  # a command redelivered right after the CONNACK is answered on it
        c = s.client
        cfg.secure(c, self.password)
        w = self.profile.will()
        c.will_set(w.topic, w.payload, w.qos, w.retain)
        self._snapshot("connecting", False)
        try:
            c.connect(cfg.host, cfg.port, keepalive=cfg.keepalive, **s.connect_args())
        except (OSError, ssl.SSLError) as e:
            s.reason = cfg.tls_refusal(e) if isinstance(e, ssl.SSLError) else \
                (e.strerror or str(e)).lower()
            s.ok = False
            with contextlib.suppress(Exception):
                c.socket() and c.disconnect()
            return s
        c.loop_start()
        deadline = time.monotonic() + max(10.0, cfg.keepalive)
        while not s.connack.wait(0.2):  # a stop does not wait for a silent broker
            if self._stopping.is_set() or time.monotonic() > deadline:
                break
        if not s.connack.is_set() or not s.ok:
            s.ok = False
            s.reason = s.reason or "no CONNACK from the broker"
            self._close(s)
        return s

    def _key(self, s: Session) -> None:
        """Key the cursor by the broker's address (the socket's peer) and load it."""
        peer = self.cfg.host
        sock: Any = s.client.socket()
        with contextlib.suppress(OSError, AttributeError, IndexError):
            peer = str(sock.getpeername()[0])
        dest = destination(self.cfg, peer)
        src = self.source
        cursor = src.cursor_or_none(dest)
        old = None if cursor is not None or self.where == dest else src.cursor_or_none(self.where)
        if old is not None:
            src.rename_cursor(self.where, dest)  # an older pymb's key: the URL's text
            cursor = old
        if cursor is None:
            cursor = 0 if self.cfg.start == "oldest" else self._now_id
            self._replay_notice(dest, cursor)
        self.acked.cursor = self._saved_cursor = cursor
        self._writer.dest = dest
        self.dest = dest

    def _replay_notice(self, dest: str, cursor: int) -> None:
        """One line when a new cursor is to send more than a day of samples."""
        old = self.source.oldest_after(cursor)
        if old is None or time.time() - old[1] <= REPLAY_NOTICE:
            return
        count, first = old
        line = (f"a new MQTT cursor for {dest} starts at the oldest sample: {count:,} "
                f"samples back to {time.strftime('%Y-%m-%d %H:%M', time.gmtime(first))} UTC "
                f"({(time.time() - first) / 86400:,.1f} days) are sent; --mqtt-start now "
                "sends only new ones")
        self._say(line)

    def _close(self, s: Session) -> None:
        with contextlib.suppress(Exception):
            s.disconnect(end_session=self._stopping.is_set())
        with contextlib.suppress(Exception):
            s.client.loop_stop()
        # The client and the session's callbacks hold each other: without this the
        # client (and the socket pair paho keeps for its thread) waits for the cycle
        # collector, two descriptors a reconnection.
        for hook in ("on_connect", "on_disconnect", "on_publish", "on_subscribe", "on_message"):
            setattr(s.client, hook, None)

    # -- the cursor and the status ------------------------------------------------

    def _save_cursor(self, force: bool = False) -> None:
        # Beside a running writer the cursor goes in with each of its batches
        # (handed over: ForwardingSink.commit); here once the writer has closed.
        if self.source.live:
            if self.dest is not None and self.cursor != self._handed_cursor:
                self.source.set_cursor(self.dest, self.cursor)
                self._handed_cursor = self.cursor
        elif self.dest is not None and self.cursor != self._saved_cursor:
            now = time.monotonic()
            if force or now - self._saved_at >= CURSOR_EVERY:
                self._writer.put(self.cursor)
                self._saved_cursor = self.cursor
                self._saved_at = now

    def _snapshot(self, state: str, connected: bool) -> None:
        now = time.time()
        tick = time.monotonic()  # a step of the wall clock leaves the rate alone
        while self._ack_times and self._ack_times[0][0] < tick - 5:
            self._ack_times.popleft()
        span = (tick - self._ack_times[0][0]) if len(self._ack_times) > 1 else 0.0
        rate = sum(n for _, n in self._ack_times) / max(span, 1.0) if self._ack_times else 0.0
        old = self.source.oldest_after(self.cursor)
        backlog = 0 if old is None else old[0] - self.acked.above_cursor()
        age = None if old is None else max(0.0, now - old[1])
        with self._lock:
            self._status = ForwarderStatus(connected, state, self._published, self._acked,
                                           max(backlog, 0), age, self._last_ack, rate,
                                           self._connections, self.cursor, self._refusal)

    # -- one connection ------------------------------------------------------------

    def _pump(self, s: Session) -> None:
        """Publish on one connection until it is lost or the run stops."""
        prof = self.profile
        pub = Publisher(s.client, prof)
        if prof.host_topic:  # no births until the primary host says online
            while not s.host_online:
                if s.lost or self._stopping.is_set():
                    return
                self._snapshot(f"waiting for the primary host {self.cfg.primary_host}", False)
                self.wake.wait(0.2)
                self.wake.clear()
        pub.send(prof.births(self.source, self._node()), [])
        pub.barrier()
        self.rebirth.clear()
        live_start = live_after = self.source.max_id()  # the live lane: what comes after
        self._refused_here = False
        catch_after = self.acked.skip_done(self.cursor)  # the catch-up lane: up to live_start
        tokens, last_tick = 0.0, time.monotonic()
        last_snap = 0.0
        while not s.lost:
            self.wake.clear()
            if prof.host_topic and not s.host_online:
                # Sparkplug 3.0: NDEATH, disconnect, start the connection over
                s.reason = f"the primary host {self.cfg.primary_host} went offline"
                break
            self._acknowledged(pub, s)
            self._save_cursor()
            if self.rebirth.is_set():
                self.rebirth.clear()
                pub.send(prof.births(self.source, self._node()), [])
                pub.barrier()
            now = time.monotonic()
            if self._stopping.is_set() and (
                    now >= self._drain_until
                    or (pub.outstanding == 0 and self.cursor >= self.source.max_id())):
                break
            # live lane first, then the paced catch-up lane
            live_after, sent = live_lane(pub, self.source, live_after,
                                         lambda rec: self._publish_downs(pub, rec, 0))
            self._published += sent
            if self._downs or self._downs_in:
                self._publish_downs(pub, None, live_after)
            pub.send(self.answers_due(), [])  # the DDATA of DCMDs executed
            tokens = min(tokens + (now - last_tick) * self.cfg.catchup_rate,
                         max(self.cfg.catchup_rate / 10, 1.0))
            last_tick = now
            catch_after, tokens, sent = catch_up_lane(pub, self.source, self.acked, catch_after,
                                                      live_start, tokens)
            self._published += sent
            if self._refused_here and now >= self._retry_at:
                # a new connection offers them again: its catch-up lane starts at the cursor
                s.again = True
                self._retry_wait = min(self._retry_wait * 2, RETRY_MAX)
                break
            pub.barrier()
            if now - last_snap >= 0.5:
                self._snapshot("connected", True)
                last_snap = now
                pub.send(prof.node_data(self._node()), [])
            self.wake.wait(0.05 if catch_after < live_start else 0.2)
        if s.lost:
            self._acknowledged(pub, s)  # what came before the loss (a refusal, say)
            return
        # a clean end: the goodbye, then DISCONNECT
        self._save_cursor(force=True)
        for m in prof.goodbye():
            info = s.client.publish(m.topic, m.payload, m.qos, m.retain)
            with contextlib.suppress(Exception):
                info.wait_for_publish(2.0)
            refused = next((r for mid, r in list(s.acks) if mid == info.mid and r), None)
            if refused is not None:  # MQTT 5: an ACL that denies the topic, say
                self._say(f"the broker refused the goodbye on {m.topic} ({refused}); the "
                          "will registered at each connection is that message, so it is "
                          "likely dropped too: subscribers do not see this node go "
                          "offline, even when it crashes; check the broker's ACL")

    def _node(self) -> dict[str, int]:
        """The node's own metrics (Sparkplug NDATA): the backlog."""
        return {BACKLOG: self.status().backlog}

    def subscription_refused(self, topic: str, reason: str) -> None:
        """The broker refused a subscription (its ACL, say): said once a run for
        each topic and reason, with what the node then misses (paho's thread)."""
        with self._lock:
            if (topic, reason) in self._subs_said:
                return
            self._subs_said.add((topic, reason))
        self._say(f"the broker refused the subscription to {topic} ({reason}): "
                  f"{self.profile.missed(topic)}")

    def _acknowledged(self, pub: Publisher, s: Session) -> None:
        """Mark what the broker acknowledged since the last look; keep what it
        refused (MQTT 5) to offer it again."""
        for ranges, refused, topic in pub.acknowledged(s.acks):
            if refused is not None:
                self._refused(ranges, refused, topic)
                continue
            for lo, hi in ranges:
                self.acked.mark(lo, hi)
            n = len(ranges)
            self._acked += n
            self._last_ack = time.time()
            self._ack_times.append((time.monotonic(), n))
            if self._refusal is not None and any(
                    lo <= self._first_refused <= hi for lo, hi in ranges):
                self.record_event(f"the broker takes the samples it refused: sample "
                                  f"{self._first_refused} was acknowledged")
                self._said.clear()
                self._refusal = None
                self._retry_wait = RETRY_FIRST

    def _refused(self, ranges: list[tuple[int, int]], reason: str, topic: str) -> None:
        """The broker said no to a sample: it stays in the outbox (the cursor
        stops before it) and is offered again on the next connection."""
        if not self._refused_here:
            self._refused_here = True
            self._retry_at = time.monotonic() + self._retry_wait
        first = ranges[-1][1]
        if self._refusal is None or first < self._first_refused:
            self._first_refused = first
        self._refusal = reason
        if reason in self._said:
            return
        self._said.add(reason)
        line = (f"the broker refused sample {first} on {topic}: {reason}; it stays in the "
                f"database and is offered again after {self._retry_wait:g} s (doubling up to "
                f"{RETRY_MAX:g} s while the broker refuses)")
        self._say(line)

    def _publish_downs(self, pub: Publisher, rec: StoredSample | None, upto: int) -> None:
        """Publish what is due: the downs of ``rec``'s device that came after
        its previous sample, or (no rec) those committed up to ``upto``."""
        if not (self._downs or self._downs_in):
            return
        with self._lock:
            self._downs += self._downs_in
            self._downs_in = []
        due, keep = due_downs(self._downs, rec, upto)
        for d in due:
            pub.send(self.profile.device_down(d.device), [])
        self._downs = keep  # (sent: a send that raised leaves them all to send again)
