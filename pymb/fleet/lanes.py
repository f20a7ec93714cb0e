"""How one connection publishes: the messages in flight and the sample
ranges each acknowledges (QoS 1), or a SUBSCRIBE round trip as the barrier
that acknowledges what was sent before it (QoS 0); and the two lanes that
feed it, live (samples committed since the connection started, as fast as
the window allows) and catch-up (the older backlog, paced)."""

from __future__ import annotations

import collections
from collections.abc import Callable
from typing import TYPE_CHECKING

from pymb.fleet.cursor import Acknowledged
from pymb.fleet.profiles import Message, Profile
from pymb.store import Outbox, StoredSample

if TYPE_CHECKING:  # the optional extra pymb-modbus[mqtt]
    from paho.mqtt.client import Client

__all__ = ["BARRIER_EVERY", "FETCH", "WINDOW", "Publisher", "catch_up_lane", "live_lane"]

WINDOW = 200  #: messages in flight (unacknowledged), at most
FETCH = 100  #: samples read from the database at a time
BARRIER_EVERY = 50  #: Sparkplug (QoS 0): a SUBSCRIBE round trip after this many messages


class Publisher:
    """What one connection has sent and not yet seen acknowledged."""

    def __init__(self, client: Client, profile: Profile) -> None:
        self.client = client
        self.profile = profile
        self.qos1 = profile.data_qos > 0
        self.inflight: dict[int, list[tuple[int, int]]] = {}  # mid -> sample ranges it acks
        self.topics: dict[int, str] = {}  # mid -> the topic of a sample's last message
        self.unbarriered: list[tuple[int, int]] = []  # QoS 0: sent, waiting for a barrier
        self.since_barrier = 0
        self.outstanding = 0  # samples sent and not acknowledged

    def room(self) -> int:
        """Samples the window takes now."""
        return WINDOW - self.outstanding

    def send(self, msgs: list[Message], ranges: list[tuple[int, int]]) -> None:
        """Publish ``msgs``; the last one acknowledges the sample ``ranges``."""
        for i, m in enumerate(msgs):
            info = self.client.publish(m.topic, m.payload, m.qos, m.retain)
            last = i == len(msgs) - 1
            if self.qos1 and m.qos > 0:
                self.inflight[info.mid] = ranges if last else []
                if last and ranges:
                    self.topics[info.mid] = m.topic
            elif last:
                self.unbarriered.extend(ranges)
                self.since_barrier += 1

    def sample(self, msgs: list[Message], lo: int, hi: int) -> None:
        """Publish one sample's messages, acknowledging ids ``lo..hi``."""
        self.send(msgs, [(lo, hi)])
        self.outstanding += 1
        if self.since_barrier >= BARRIER_EVERY:
            self.barrier()

    def barrier(self) -> None:
        """QoS 0: a SUBSCRIBE whose SUBACK acknowledges what was sent before it."""
        if self.unbarriered and self.profile.command_topic:
            _rc, mid = self.client.subscribe(self.profile.command_topic, qos=1)
            if mid is not None:
                self.inflight[mid] = list(self.unbarriered)
            self.unbarriered.clear()
            self.since_barrier = 0

    def acknowledged(self, acks: collections.deque[tuple[int, str | None]]
                     ) -> list[tuple[list[tuple[int, int]], str | None, str]]:
        """Each acknowledgement in ``acks`` (taken from it) as (the sample ranges
        it answers, the broker's reason if it refused them, the topic)."""
        out = []
        while acks:
            mid, refused = acks.popleft()
            ranges = self.inflight.pop(mid, None)
            topic = self.topics.pop(mid, "")
            if ranges:
                self.outstanding -= len(ranges)
                out.append((ranges, refused, topic))
        return out


def live_lane(pub: Publisher, source: Outbox, after: int,
              before_each: Callable[[StoredSample], None]) -> tuple[int, int]:
    """Send the samples committed after ``after`` that the window takes
    (``before_each`` first, for each); returns (the last id sent, how many)."""
    sent = 0
    room = pub.room()
    if room > 0:
        for rec in source.samples_after(after, min(room, FETCH)):
            before_each(rec)
            pub.sample(pub.profile.data(rec, False), after + 1, rec.id)
            after = rec.id
            sent += 1
    return after, sent


def catch_up_lane(pub: Publisher, source: Outbox, acked: Acknowledged, after: int,
                  live_start: int, tokens: float) -> tuple[int, float, int]:
    """Send the backlog after ``after`` (up to the live lane's start), as
    many as the window and the pacing ``tokens`` allow, skipping what was
    acknowledged already; returns (the last id done, the tokens left, how
    many were sent)."""
    sent = 0
    room = pub.room()
    if room > 0 and tokens >= 1 and after < live_start:
        after = acked.skip_done(after)
        stop_at = min(live_start + 1, acked.next_done(after) or live_start + 1)
        durable = source.durable()  # ids up to it not in the file are gaps
        recs = source.samples_after(after, min(room, int(tokens), FETCH), before=stop_at)
        end = stop_at - 1 if durable is None else min(stop_at - 1, durable)
        if not recs and after < end:  # a gap of deleted ids
            acked.mark(after + 1, end)
            after = end
        for rec in recs:
            pub.sample(pub.profile.data(rec, True), after + 1, rec.id)
            after = rec.id
            tokens -= 1
            sent += 1
    return after, tokens, sent
