"""The MQTT settings of ``pymb log``: flags and the ``[mqtt]`` TOML table.

Flags and TOML keys have the same names (``--mqtt-profile`` is ``profile``
in ``[mqtt]``; ``--mqtt URL`` is ``url``)::

    [mqtt]
    url = "mqtts://broker.plant.example:8883"   # mqtt://HOST[:PORT] or mqtts://
    profile = "sparkplug"        # plain (default) | sparkplug
    node = "gateway-7"           # default: the host name
    group = "pymb"               # Sparkplug group
    prefix = "pymb"              # plain topics: {prefix}/{node}/{device}
    user = "gateway-7"
    password_file = "/etc/pymb/mqtt.pass"   # or PYMB_MQTT_PASSWORD; never in argv
    ca = "/etc/pymb/ca.pem"      # server verification (default: the system's CAs)
    cert = "/etc/pymb/client.pem"            # client certificate ...
    key = "/etc/pymb/client.key"             # ... and its key
    catchup_rate = 1000          # backlog messages per second after an outage
    drain = 5                    # seconds a clean stop keeps sending what is left
    primary_host = "scada"       # Sparkplug: publish only while spBv1.0/STATE/scada is online
    start = "oldest"             # a new outbox cursor: send every sample (oldest) or new ones (now)
    protocol = "5"               # MQTT 5 (default) or "3.1.1" for a broker of 3.1.1 only
"""

from __future__ import annotations

import os
import socket
import ssl
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from pymb._native.tls import certificate_refused, tls_words
from pymb.devices.spec import closest
from pymb.errors import InvalidArgument

if TYPE_CHECKING:  # the optional extra pymb-modbus[mqtt]
    from paho.mqtt.client import Client

__all__ = ["NODE_TOPICS", "PROFILES", "PROTOCOLS", "MqttConfig", "from_table"]

PROFILES = ("plain", "sparkplug")
#: the plain profile's topics ``{prefix}/{node}/NAME`` that are the node's own,
#: not a device's samples (a device may not have one of these names)
NODE_TOPICS = ("status", "set")
PASSWORD_ENV = "PYMB_MQTT_PASSWORD"
#: CONNACK reason codes of refused credentials: MQTT 5's bad user name or
#: password and not authorized (paho gives MQTT 3.1.1's 4 and 5 as these too)
_CREDENTIALS_REFUSED = frozenset({0x86, 0x87})
#: TOML key -> type; the flag is ``--mqtt-KEY`` with ``_`` as ``-`` (``url`` is ``--mqtt``)
KEYS: dict[str, type | tuple[type, ...]] = {
    "url": str, "profile": str, "node": str, "group": str, "prefix": str, "user": str,
    "password_file": str, "ca": str, "cert": str, "key": str,
    "catchup_rate": (int, float), "keepalive": int, "primary_host": str,
    "drain": (int, float), "start": str, "protocol": str,
}
PROTOCOLS = ("5", "3.1.1")  #: MQTT versions: 5 says when the broker refuses a message
STARTS = ("oldest", "now")  #: where a new outbox cursor starts
MAX_DRAIN = 3600.0  #: seconds: the longest drain accepted


@dataclass
class MqttConfig:
    """Where and how samples are forwarded to an MQTT broker."""

    url: str
    profile: str = "plain"
    node: str = ""
    group: str = "pymb"
    prefix: str = "pymb"
    user: str | None = None
    password_file: str | None = None
    ca: str | None = None
    cert: str | None = None
    key: str | None = None
    catchup_rate: float = 1000.0  #: backlog messages per second, at most
    keepalive: int = 15  #: seconds; a silent link is noticed after about 1.5 times this
    #: Sparkplug: the primary host application's id; births wait for its STATE online
    primary_host: str | None = None
    #: seconds a clean stop (SIGTERM, Ctrl-C, --seconds) keeps sending what is left;
    #: what is still unsent then stays in the database for the next run
    drain: float = 5.0
    #: where a broker's new outbox cursor starts: at the oldest sample in the
    #: database, or after those committed before the run (``now``)
    start: str = "oldest"
    #: the MQTT version: "5" (the broker says when it refuses a message) or "3.1.1"
    protocol: str = "5"

    def __post_init__(self) -> None:
        u = urlsplit(self.url)
        if u.scheme not in ("mqtt", "mqtts") or not u.hostname or u.path not in ("", "/"):
            raise InvalidArgument(f"bad MQTT URL {self.url!r}; use mqtt://HOST[:PORT] or "
                                  "mqtts://HOST[:PORT] (TLS)")
        if u.username or u.password:
            raise InvalidArgument("no user or password in the MQTT URL; use --mqtt-user and "
                                  f"--mqtt-password-file (or {PASSWORD_ENV})")
        try:
            port = u.port
        except ValueError:
            raise InvalidArgument(f"bad port in the MQTT URL {self.url!r}") from None
        self.tls = u.scheme == "mqtts"
        self.host = u.hostname
        self.port = port or (8883 if self.tls else 1883)
        if self.start not in STARTS:
            raise InvalidArgument(f"MQTT start must be oldest or now, got {self.start!r}")
        if self.protocol not in PROTOCOLS:
            raise InvalidArgument(f"MQTT protocol must be 5 or 3.1.1, got {self.protocol!r}")
        if self.profile not in PROFILES:
            raise InvalidArgument(f"unknown MQTT profile {self.profile!r}; use plain or sparkplug")
        if not self.node:
            self.node = socket.gethostname().split(".")[0] or "pymb"
        for what, value in (("node", self.node), ("group", self.group),
                            ("prefix", self.prefix)):
            if not value or any(c in value for c in "/+#") or value != value.strip():
                raise InvalidArgument(f"MQTT {what} {value!r} must be a non-empty name "
                                      "without '/', '+', '#' or surrounding spaces")
        if self.primary_host is not None:
            if self.profile != "sparkplug":
                raise InvalidArgument("--mqtt-primary-host needs --mqtt-profile sparkplug")
            h = self.primary_host
            if not h or any(c in h for c in "/+#") or h != h.strip():
                raise InvalidArgument(f"MQTT primary host {h!r} must be a non-empty name "
                                      "without '/', '+', '#' or surrounding spaces")
        if not self.tls and (self.ca or self.cert or self.key):
            raise InvalidArgument("--mqtt-ca/--mqtt-cert/--mqtt-key need an mqtts:// URL")
        if bool(self.cert) != bool(self.key):
            raise InvalidArgument("a client certificate needs both --mqtt-cert and --mqtt-key")
        for what, path in (("ca", self.ca), ("cert", self.cert), ("key", self.key),
                           ("password file", self.password_file)):
            if path and not os.access(path, os.R_OK):
                raise InvalidArgument(f"MQTT {what} {path!r} cannot be read")
        if self.catchup_rate <= 0:
            raise InvalidArgument("MQTT catchup_rate must be > 0")
        if not 0 <= self.drain <= MAX_DRAIN:  # NaN fails too
            raise InvalidArgument(f"MQTT drain must be 0..{MAX_DRAIN:g} seconds, "
                                  f"got {self.drain!r}")
        if not 5 <= self.keepalive <= 3600:
            raise InvalidArgument("MQTT keepalive must be 5..3600 seconds")
        if self.password_file and not self.user:
            raise InvalidArgument("--mqtt-password-file needs --mqtt-user")

    def check_device(self, name: str) -> None:
        """A device's name is a level of its topics: InvalidArgument for one
        with '/', '+' or '#', or (plain) one of the node's own :data:`NODE_TOPICS`."""
        if not name or any(c in name for c in "/+#"):
            raise InvalidArgument(f"device name {name!r} cannot be a level of an MQTT topic: "
                                  "use a name without '/', '+' or '#' for --mqtt")
        if self.profile == "plain" and name in NODE_TOPICS:
            raise InvalidArgument(f"device name {name!r} is the node's own topic "
                                  f"{self.prefix}/{self.node}/{name}: choose another name "
                                  "for --mqtt")

    def password(self) -> str | None:
        """The password: from the file (first line), else $PYMB_MQTT_PASSWORD."""
        if self.password_file:
            try:
                with open(self.password_file, encoding="utf-8") as f:
                    return f.readline().rstrip("\r\n")
            except OSError as e:
                raise InvalidArgument(
                    f"cannot read {self.password_file}: {e.strerror}") from None
        return os.environ.get(PASSWORD_ENV) if self.user else None

    def credentials_words(self, code: int) -> str:
        """What to add to a broker's refusal of the connection (CONNACK reason
        ``code``): a refusal of the credentials when a user was given without a
        password (an unset $PYMB_MQTT_PASSWORD, say) says so; else ""."""
        if code not in _CREDENTIALS_REFUSED or not self.user or self.password_file \
                or os.environ.get(PASSWORD_ENV) is not None:
            return ""
        return f"; no password was given: --mqtt-password-file FILE or ${PASSWORD_ENV}"

    def secure(self, client: Client, password: str | None) -> None:
        """Give a paho client this configuration's user (with ``password``, from
        :meth:`password`) and, for ``mqtts://``, TLS with the broker verified
        (``ca``, or the system's CAs) and the client certificate, if any."""
        if self.user:
            client.username_pw_set(self.user, password)
        if self.tls:
            client.tls_set(ca_certs=self.ca, certfile=self.cert, keyfile=self.key,
                           cert_reqs=ssl.CERT_REQUIRED, tls_version=ssl.PROTOCOL_TLS_CLIENT)


    def tls_refusal(self, e: ssl.SSLError) -> str:
        """A TLS failure with the broker in one line: a refused certificate says
        which CAs it was checked against (``ca``, or the system's)."""
        if isinstance(e, ssl.SSLCertVerificationError):
            return certificate_refused(e, system_cas=self.ca is None, who="broker",
                                       hint=": give the broker's CA with --mqtt-ca FILE")
        return tls_words(e).replace("the server", "the broker")


def from_table(table: dict[str, Any], where: str) -> MqttConfig:
    """An MqttConfig from a ``[mqtt]`` TOML table."""
    for k, v in table.items():
        kind = KEYS.get(k)
        if kind is None:
            raise InvalidArgument(f"{where}: [mqtt]: unknown key {k!r}{closest(k, list(KEYS))}")
        if not isinstance(v, kind) or isinstance(v, bool):
            raise InvalidArgument(f"{where}: [mqtt] {k} has the wrong type ({v!r})")
    if "url" not in table:
        raise InvalidArgument(f"{where}: [mqtt] needs url = \"mqtt://HOST[:PORT]\"")
    try:
        return MqttConfig(**table)
    except InvalidArgument as e:  # a value the table gave: say where it is
        raise InvalidArgument(f"{where}: [mqtt]: {e}") from None
