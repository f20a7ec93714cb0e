"""The forwarder's side of write commands: the topics it subscribes to on
every connection (the plain profile's ``.../set``, Sparkplug's DCMD), the
commands it hands on, the results it publishes (a result message; Sparkplug:
a DDATA of the metrics a DCMD named). What a command does is
:mod:`pymb.logger.commands`'s."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence

from pymb.fleet.config import MqttConfig
from pymb.fleet.profiles import NAMESPACE, Message, Profile
from pymb.fleet.protobuf import MetricValue
from pymb.fleet.session import Session
from pymb.store import Outbox

__all__ = ["CommandTopics"]


class CommandTopics:
    """Mixed into the forwarder: ``set_topics`` (topic -> device) are
    subscribed to (QoS 1) on each connection."""

    cfg: MqttConfig
    profile: Profile
    source: Outbox
    wake: threading.Event  #: wakes the forwarder's thread

    def __init__(self) -> None:
        #: set topic -> device: the plain profile's write commands (see :meth:`take_commands`)
        self.set_topics: dict[str, str] = {}
        self._commands: Callable[[str, bytes, Callable[[], None] | None, bool], None] | None = \
            None
        self._session: Session | None = None  #: the connection up now, if any
        #: (device, values read back, metric names, time) of DCMDs answered, for the DDATA
        self._answers: list[tuple[str, dict[str, MetricValue], list[str], float]] = []
        #: device -> metric -> (time, value) read back by the last DCMD that wrote it
        self._read_back: dict[str, dict[str, tuple[float, MetricValue]]] = {}
        self._answers_lock = threading.Lock()

    def take_commands(self, devices: list[str],
                      submit: Callable[[str, bytes, Callable[[], None] | None, bool], None]
                      ) -> None:
        """Subscribe (QoS 1) to ``{prefix}/{node}/{device}/set`` of each of
        ``devices`` from the next connection on (before :meth:`start`); each
        command goes to ``submit(device, payload, done, retained)``, ``done()``
        to be called once it is answered (None: nothing to call), ``retained``
        when the broker held it retained from before the subscription."""
        cfg = self.cfg
        if cfg.profile == "sparkplug":  # DCMD on spBv1.0/{group}/DCMD/{node}/{device}
            base = f"{NAMESPACE}/{cfg.group}/DCMD/{cfg.node}"
            self.set_topics = {f"{base}/{d}": d for d in devices}
        else:
            base = f"{cfg.prefix}/{cfg.node}"
            self.set_topics = {f"{base}/{d}/set": d for d in devices}
        self._commands = submit

    def command_arrived(self, topic: str, payload: bytes,
                        done: Callable[[], None] | None = None, *,
                        retained: bool = False) -> None:
        """A command on a set topic (paho's thread): handed on, never waited for;
        ``done()`` acknowledges it to the broker once it is answered."""
        if self._commands is not None:
            self._commands(self.set_topics[topic], payload, done, retained)
        elif done is not None:
            done()

    def publish_result(self, device: str, payload: bytes) -> bool:
        """Publish a command's result (QoS 1, not retained) on
        ``{prefix}/{node}/{device}/set/result``; False when no connection is up
        (the result is on record: the command sent again gets it)."""
        s = self._session
        if s is None or s.lost or not s.ok:
            return False
        topic = f"{self.cfg.prefix}/{self.cfg.node}/{device}/set/result"
        info = s.client.publish(topic, payload, qos=1, retain=False)
        return bool(info.rc == 0)


    def answer_dcmd(self, device: str, values: Mapping[str, MetricValue],
                    names: Sequence[str]) -> None:
        """A DCMD was executed (or refused): the forwarder's thread publishes a
        DDATA of ``names``, with ``values`` (read back) where given, else the
        current value (any thread)."""
        with self._answers_lock:
            if len(self._answers) < 1000:
                self._answers.append((device, dict(values), list(names), time.time()))
        self.wake.set()

    def answers_due(self) -> list[Message]:
        """The DDATA of the DCMDs answered since the last call (the forwarder's
        thread: the profile's seq and the outbox are its own). A metric not
        written carries the latest sample's value, or the value a DCMD read back
        after that sample's poll began."""
        with self._answers_lock:
            answers, self._answers = self._answers, []
        out: list[Message] = []
        for device, values, names, t in answers:
            known = self._read_back.setdefault(device, {})
            known.update((k, (t, v)) for k, v in values.items())
            latest = self.source.latest(device)
            # a value read back after the latest sample's poll began is the newer one
            since = -1.0 if latest is None else latest.time_utc
            newer = {k: v for k, (tk, v) in known.items() if tk > since and k in names}
            out += self.profile.command_data(device, {**newer, **values}, names, latest)
        return out
