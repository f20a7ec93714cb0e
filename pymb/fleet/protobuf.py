"""The few protobuf messages Sparkplug B needs, encoded and decoded by hand.

The schema is the Sparkplug B 3.0 specification's ``sparkplug_b.proto``
(package ``org.eclipse.tahu.protobuf``, message ``Payload``); field numbers
below are that file's. Only what pymb publishes is encoded (payload
timestamp, seq, metrics with name, alias, timestamp, datatype,
is_historical, is_null, properties and the int, long, double, boolean and
string values); :func:`decode` reads any message into raw fields, which
:func:`number`, :func:`text` and :func:`metric_value` read (an NCMD, a DCMD,
the births and data ``pymb collect`` stores). The tests decode every payload with an independent
implementation of the same schema (pysparkplug's generated ``Payload``).

Why not the ``protobuf`` package: one dependency fewer for ``pymb-modbus[mqtt]``,
and the handful of fields here are simpler to write than to pin a
generated-code version against a runtime version.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

__all__ = ["TEXTS", "DataType", "FieldError", "Metric", "MetricValue", "Properties",
           "command_metrics", "command_values", "decode", "encode_payload", "last",
           "metric_fields", "metric_value", "number", "text"]


#: What a metric carries: None is a null of its datatype.
MetricValue = float | int | bool | str | None


class DataType(IntEnum):
    """Sparkplug B ``DataType`` values used by pymb (from the .proto)."""

    INT8 = 1
    INT16 = 2
    INT32 = 3
    INT64 = 4
    UINT8 = 5
    UINT16 = 6
    UINT32 = 7
    UINT64 = 8
    FLOAT = 9
    DOUBLE = 10
    BOOLEAN = 11
    STRING = 12


@dataclass
class Metric:
    """One ``Payload.Metric``; ``value`` None with ``datatype`` set means is_null."""

    name: str | None
    alias: int | None
    datatype: DataType
    value: MetricValue
    timestamp: int | None = None  #: ms since the epoch, UTC
    is_historical: bool = False
    properties: Sequence[tuple[str, DataType, int | str]] = field(default_factory=tuple)


#: A metric's properties: (name, datatype, value) of each.
Properties = tuple[tuple[str, DataType, int | str], ...]


def _varint(n: int) -> bytes:
    n &= 0xFFFF_FFFF_FFFF_FFFF  # 64 bits: a negative int32/int64 in two's complement
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(number: int, wire: int) -> bytes:
    return _varint(number << 3 | wire)


def _len(number: int, data: bytes) -> bytes:
    return _key(number, 2) + _varint(len(data)) + data


def _uint(number: int, n: int) -> bytes:
    return _key(number, 0) + _varint(n)


def _property_set(props: Iterable[tuple[str, DataType, int | str]]) -> bytes:
    keys, values = bytearray(), bytearray()
    for name, dtype, value in props:
        keys += _len(1, name.encode())
        v = _uint(1, int(dtype))
        if dtype == DataType.BOOLEAN:  # PropertyValue.boolean_value
            v += _uint(7, 1 if value else 0)
        elif isinstance(value, str):
            v += _len(8, value.encode())
        else:
            v += _uint(3, value & 0xFFFFFFFF)
        values += _len(2, v)
    return bytes(keys + values)


#: the signed integers' widths: a negative one is its two's complement in it
_SIGNED: dict[int, int] = {DataType.INT8: 8, DataType.INT16: 16, DataType.INT32: 32,
                           DataType.INT64: 64}


def _metric(m: Metric) -> bytes:
    out = bytearray()
    if m.name is not None:
        out += _len(1, m.name.encode())
    if m.alias is not None:
        out += _uint(2, m.alias)
    if m.timestamp is not None:
        out += _uint(3, m.timestamp)
    out += _uint(4, int(m.datatype))
    if m.is_historical:
        out += _uint(5, 1)
    v = m.value
    if v is None:
        out += _uint(7, 1)
    if m.properties:
        out += _len(9, _property_set(m.properties))
    if v is None:
        return bytes(out)
    dt = m.datatype
    if dt == DataType.BOOLEAN:
        out += _uint(14, 1 if v else 0)
    elif dt == DataType.STRING:
        out += _len(15, str(v).encode())
    elif dt == DataType.DOUBLE:
        out += _key(13, 1) + struct.pack("<d", float(v))
    elif dt == DataType.FLOAT:
        out += _key(12, 5) + struct.pack("<f", float(v))
    elif dt == DataType.UINT64:
        out += _uint(11, int(v))
    elif dt == DataType.INT64:  # long_value, two's complement
        out += _uint(11, int(v) & 0xFFFFFFFFFFFFFFFF)
    else:  # the 8-, 16- and 32-bit integers: int_value, a uint32 on the wire
        out += _uint(10, int(v) & (1 << _SIGNED.get(dt, 32)) - 1)
    return bytes(out)


def encode_payload(metrics: Iterable[Metric], *, timestamp: int | None = None,
                   seq: int | None = None) -> bytes:
    """A Sparkplug B ``Payload``: timestamp (ms), metrics, seq."""
    out = bytearray()
    if timestamp is not None:
        out += _uint(1, timestamp)
    for m in metrics:
        out += _len(2, _metric(m))
    if seq is not None:
        out += _uint(3, seq)
    return bytes(out)


Fields = dict[int, list[int | bytes]]


def decode(data: bytes) -> Fields:
    """Raw fields of one protobuf message: number -> values (ints for varint
    and fixed fields, bytes for length-delimited ones, to decode again).
    Raises ValueError on a malformed message."""
    out: Fields = {}
    i, n = 0, len(data)

    def varint() -> int:
        nonlocal i
        shift = result = 0
        while True:
            if i >= n or shift > 63:
                raise ValueError("truncated or overlong varint")
            b = data[i]
            i += 1
            result |= (b & 0x7F) << shift
            if not b & 0x80:
                return result
            shift += 7

    while i < n:
        key = varint()
        number, wire = key >> 3, key & 7
        value: int | bytes
        if wire == 0:
            value = varint()
        elif wire == 1:
            if i + 8 > n:
                raise ValueError("truncated fixed64")
            value = int.from_bytes(data[i:i + 8], "little")
            i += 8
        elif wire == 5:
            if i + 4 > n:
                raise ValueError("truncated fixed32")
            value = int.from_bytes(data[i:i + 4], "little")
            i += 4
        elif wire == 2:
            length = varint()
            if i + length > n:
                raise ValueError("truncated length-delimited field")
            value = bytes(data[i:i + length])
            i += length
        else:
            raise ValueError(f"unsupported wire type {wire}")
        if number == 0:
            raise ValueError("field number 0")
        out.setdefault(number, []).append(value)
    return out


class FieldError(ValueError):
    """A field of a value of the wrong kind: a number length-delimited, a string
    not length-delimited or not UTF-8."""


def last(f: Fields, n: int) -> int | bytes | None:
    """Field ``n``'s value (the last one, as protobuf reads a scalar given
    twice); None where absent."""
    v = f.get(n)
    return v[-1] if v else None


def number(f: Fields, n: int) -> int | None:
    """Field ``n`` as a number (varint or fixed), None where absent."""
    v = last(f, n)
    if isinstance(v, bytes):
        raise FieldError(f"field {n} is not a number")
    return v


def text(f: Fields, n: int) -> str | None:
    """Field ``n`` as a UTF-8 string, None where absent."""
    v = last(f, n)
    if v is None:
        return None
    if not isinstance(v, bytes):
        raise FieldError(f"field {n} is not a string")
    try:
        return v.decode()
    except UnicodeDecodeError:
        raise FieldError(f"field {n} is not UTF-8") from None


def metric_fields(top: Fields) -> list[Fields]:
    """The fields of each metric of a ``Payload``; ValueError on a malformed one."""
    if not all(isinstance(m, bytes) for m in top.get(2, [])):
        raise ValueError("a metric is not a message")
    return [decode(m) for m in top.get(2, []) if isinstance(m, bytes)]


#: the datatypes whose value is a string_value (String, Text, UUID)
TEXTS = {12, 14, 15}


def metric_value(f: Fields, datatype: int) -> MetricValue:
    """A metric's value from its fields, read as its datatype says: a string,
    a float (float_value, double_value), a bool, an int (an Int8..Int64 from
    its two's complement in its width); None for a null or a metric with no
    value. Raises FieldError, or OverflowError for a float sent as too big a
    varint."""
    if number(f, 7):  # is_null
        return None
    if datatype in TEXTS:
        return text(f, 15)
    if (raw := number(f, 12)) is not None:  # float_value (fixed32)
        return float(struct.unpack("<f", raw.to_bytes(4, "little"))[0])
    if (raw := number(f, 13)) is not None:  # double_value (fixed64)
        return float(struct.unpack("<d", raw.to_bytes(8, "little"))[0])
    if (raw := number(f, 14)) is not None:
        return bool(raw)
    for n in (10, 11):  # int_value, long_value
        if (raw := number(f, n)) is not None:
            bits = _SIGNED.get(datatype)
            if bits is not None:
                raw &= (1 << bits) - 1
                if raw >= 1 << (bits - 1):
                    raw -= 1 << bits
            return raw
    return text(f, 15)


def command_metrics(payload: bytes) -> list[tuple[str | None, int | None, bool | None]]:
    """(name, alias, boolean value) of each metric of an NCMD/DCMD payload."""
    return [(text(f, 1), number(f, 2), None if (b := number(f, 14)) is None else bool(b))
            for f in metric_fields(decode(payload))]


def command_values(payload: bytes,
                   declared: Callable[[str | None, int | None], int | None] | None = None,
                   ) -> tuple[int | None, int | None,
                              list[tuple[str | None, int | None, MetricValue]]]:
    """(payload timestamp, seq, [(name, alias, value)]) of a DCMD: each
    metric's value as :func:`metric_value` reads it, as its own datatype says
    or, where it has none (Sparkplug 3.0: a DCMD should not repeat it), as
    ``declared(name, alias)`` says (the birth's datatype). Raises ValueError
    on a malformed payload."""
    top = decode(payload)
    out: list[tuple[str | None, int | None, MetricValue]] = []
    for f in metric_fields(top):
        name, alias, dt = text(f, 1), number(f, 2), number(f, 4)
        if dt is None and declared is not None:
            dt = declared(name, alias)
        out.append((name, alias, metric_value(f, dt or 0)))
    return number(top, 1), number(top, 3), out
