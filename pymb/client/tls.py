"""Modbus/TCP Security for a client: :class:`TlsConfig`, what
:class:`~pymb.TcpClient` takes as ``tls=`` (and ``mbaps://`` addresses with
the command's ``--ca``/``--cert``/``--key``/``--server-name``)."""

from __future__ import annotations

import os
import ssl
from dataclasses import dataclass

from pymb._native.tls import ClientContext
from pymb.errors import InvalidArgument

__all__ = ["MBAPS_PORT", "TlsConfig"]

MBAPS_PORT = 802  #: Modbus/TCP Security's registered port


def _path(what: str, value: str | os.PathLike[str] | None) -> str | None:
    if value is None:
        return None
    if not isinstance(value, (str, os.PathLike)) or not os.fspath(value):
        raise InvalidArgument(f"tls {what} must be a file path, got {value!r}")
    path = os.fspath(value)
    if not os.path.isfile(path):
        raise InvalidArgument(f"tls {what} {path!r}: no such file")
    return path


def _chain_error(cert: str, key: str | None, e: BaseException) -> str:
    """Why a certificate and key did not load, in one line."""
    reason = getattr(e, "reason", None)
    if reason == "KEY_VALUES_MISMATCH":
        return f"tls key {key!r} is not the private key of cert {cert!r}"
    if key is None:
        try:
            with open(cert, "rb") as f:
                has_key = b"PRIVATE KEY" in f.read(1 << 20)
        except OSError:
            has_key = True
        if not has_key:
            return f"tls cert {cert!r} holds no private key: give its key file too"
    what = f"{cert!r} and key {key!r}" if key else repr(cert)
    return f"tls cert {what}: not a PEM certificate and its key ({reason or e})"


@dataclass(frozen=True)
class TlsConfig:
    """How a client speaks Modbus/TCP Security (TLS 1.2 or later, X.509 both
    ways, usually on port 802).

    ``ca``: the PEM file of the certificate authority that signed the
    server's certificate (None: the system's trusted authorities).
    ``cert`` and ``key``: this client's certificate and its private key
    (PEM; ``key`` None: the key is in the ``cert`` file), which a
    Modbus/TCP Security server requires and reads the client's role from.
    ``server_name``: the name the server's certificate must be made for and
    that is sent to it (None: the host connected to; an address is checked
    against the certificate's IP entries). ``check_hostname`` False checks
    only that the CA signed the certificate, not for which name.

    The files are read when the config is made (a missing file or a key
    that does not match its certificate is an
    :class:`~pymb.InvalidArgument` then); the server's certificate is
    checked on every connect, and a refused one fails that connect with
    :class:`~pymb.TlsError`.
    """

    ca: str | os.PathLike[str] | None = None
    cert: str | os.PathLike[str] | None = None
    key: str | os.PathLike[str] | None = None
    server_name: str | None = None
    check_hostname: bool = True

    def __post_init__(self) -> None:
        if self.key is not None and self.cert is None:
            raise InvalidArgument("tls key given without its certificate (cert)")
        if self.server_name is not None and (
                not isinstance(self.server_name, str) or not self.server_name):
            raise InvalidArgument(f"tls server_name must be a host name, got {self.server_name!r}")
        if not isinstance(self.check_hostname, bool):
            raise InvalidArgument(
                f"tls check_hostname must be true or false, got {self.check_hostname!r}")
        self.context()  # read the files now: a mistake shows here, not at connect

    def context(self) -> ssl.SSLContext:
        """A new client-side :class:`ssl.SSLContext` for this config: TLS 1.2
        at least, the server's certificate always verified."""
        ca = _path("ca", self.ca)
        cert = _path("cert", self.cert)
        key = _path("key", self.key)
        ctx = ClientContext(ssl.PROTOCOL_TLS_CLIENT)
        ctx.ca = ca
        ctx.minimum_version = ssl.TLSVersion.TLSv1_2
        ctx.check_hostname = self.check_hostname
        ctx.verify_mode = ssl.CERT_REQUIRED
        try:
            if ca is None:
                ctx.load_default_certs(ssl.Purpose.SERVER_AUTH)
            else:
                ctx.load_verify_locations(cafile=ca)
        except (ssl.SSLError, OSError) as e:
            raise InvalidArgument(f"tls ca {ca!r} is not a PEM certificate file ({e})") from None
        if cert is not None:
            try:
                ctx.load_cert_chain(cert, key)
            except (ssl.SSLError, OSError) as e:
                raise InvalidArgument(_chain_error(cert, key, e)) from None
        return ctx

    def server_name_for(self, host: str) -> str | None:
        """The name checked and sent for a connection to ``host``."""
        return self.server_name or host
