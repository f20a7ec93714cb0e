"""The role of a Modbus/TCP Security client, read from its X.509 certificate.

The Modbus/TCP Security specification (MB-TCP-Security-v36, 2018) carries
the client's role in a certificate extension with the object identifier
1.3.6.1.4.1.50316.802.1 whose value is a DER ``UTF8String``. Only the
certificate's own DER is walked here (tag, length, value), inside the lengths
it gives; Python's :mod:`ssl` has already verified the certificate's chain,
dates and signature before this is asked.
"""

from __future__ import annotations

__all__ = ["ROLE_OID", "CertificateError", "role_of"]

ROLE_OID = "1.3.6.1.4.1.50316.802.1"  #: the Modbus role extension


class CertificateError(ValueError):
    """The certificate's bytes are not the DER they claim to be."""


def _oid_bytes(dotted: str) -> bytes:
    parts = [int(p) for p in dotted.split(".")]
    out = bytearray([40 * parts[0] + parts[1]])
    for p in parts[2:]:
        chunk = [p & 0x7F]
        p >>= 7
        while p:
            chunk.append(0x80 | (p & 0x7F))
            p >>= 7
        out += bytes(reversed(chunk))
    return bytes(out)


_ROLE = _oid_bytes(ROLE_OID)


def _tlv(der: bytes, pos: int, end: int) -> tuple[int, int, int]:
    """The element at ``pos``: (tag, start of its value, end of its value)."""
    if pos + 2 > end:
        raise CertificateError("truncated element")
    tag, first = der[pos], der[pos + 1]
    pos += 2
    if first < 0x80:
        length = first
    else:
        n = first & 0x7F
        if n == 0 or n > 4 or pos + n > end:
            raise CertificateError("bad length")
        length = int.from_bytes(der[pos:pos + n], "big")
        pos += n
    if pos + length > end:
        raise CertificateError("element longer than its container")
    return tag, pos, pos + length


def _children(der: bytes, start: int, end: int) -> list[tuple[int, int, int]]:
    out = []
    pos = start
    while pos < end:
        tag, s, e = _tlv(der, pos, end)
        out.append((tag, s, e))
        pos = e
    return out


def role_of(der: bytes) -> str | None:
    """The Modbus role in certificate ``der`` (None when it has no role
    extension). Raises :class:`CertificateError` for bytes that are not a
    certificate, or a role that is not a UTF8String."""
    tag, s, e = _tlv(der, 0, len(der))
    if tag != 0x30:
        raise CertificateError("not a certificate")
    parts = _children(der, s, e)
    if not parts or parts[0][0] != 0x30:
        raise CertificateError("not a certificate")
    _, ts, te = parts[0]
    for tag, xs, xe in _children(der, ts, te):
        if tag != 0xA3:  # [3] extensions
            continue
        seq = _children(der, xs, xe)
        if len(seq) != 1 or seq[0][0] != 0x30:
            raise CertificateError("bad extensions")
        for etag, es, ee in _children(der, seq[0][1], seq[0][2]):
            if etag != 0x30:
                raise CertificateError("bad extension")
            fields = _children(der, es, ee)
            if not fields or fields[0][0] != 0x06 or der[fields[0][1]:fields[0][2]] != _ROLE:
                continue
            value = fields[-1]
            if value[0] != 0x04:
                raise CertificateError("role extension without a value")
            vtag, vs, ve = _tlv(der, value[1], value[2])
            if vtag != 0x0C or ve != value[2]:
                raise CertificateError("the role is not a UTF8String")
            try:
                return der[vs:ve].decode("utf-8")
            except UnicodeDecodeError:
                raise CertificateError("the role is not UTF-8") from None
    return None
