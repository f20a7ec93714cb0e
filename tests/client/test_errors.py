"""pymb.errors: the exception codes come from the compiler, and every code a
device can send maps as the module says (Modbus Application Protocol
V1.1b3, section 7, is the independent reference here)."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest
from peerkit import mbap
from wire_peers import RawTcp

import pymb
from pymb import _native, errors

#: Modbus Application Protocol V1.1b3, section 7 (MODBUS Exception Codes).
SPECIFICATION = {
    0x01: pymb.IllegalFunction,
    0x02: pymb.IllegalDataAddress,
    0x03: pymb.IllegalDataValue,
    0x04: pymb.DeviceFailure,
    0x05: pymb.Acknowledge,
    0x06: pymb.DeviceBusy,
    0x07: pymb.NegativeAcknowledge,
    0x08: pymb.MemoryParityError,
    0x0A: pymb.GatewayPathUnavailable,
    0x0B: pymb.GatewayTargetFailed,
}


def test_every_code_maps_as_the_specification_says() -> None:
    for code in range(1, 256):
        cls = errors.exception_class(code)
        assert cls is SPECIFICATION.get(code, pymb.DeviceException), hex(code)
    for code, cls in SPECIFICATION.items():
        assert cls.default_code == code
        assert cls(cls.description).code == code
        assert cls.__doc__


def test_no_exception_code_is_typed_by_hand() -> None:
    """The codes are libmodbus's enum, read from the compiled extension by
    pymb._native (the one package that touches it)."""
    names = ("ILLEGAL_FUNCTION", "ILLEGAL_DATA_ADDRESS", "ILLEGAL_DATA_VALUE",
             "SLAVE_OR_SERVER_FAILURE", "ACKNOWLEDGE", "SLAVE_OR_SERVER_BUSY",
             "NEGATIVE_ACKNOWLEDGE", "MEMORY_PARITY", "GATEWAY_PATH", "GATEWAY_TARGET")
    source = Path(errors.__file__).read_text(encoding="utf-8")
    assert re.findall(r"\(DeviceException, code=(\S+)\):", source) == [
        f"DeviceExceptionCode.{n}" for n in names]
    native = Path(_native.__file__).read_text(encoding="utf-8")
    assert re.findall(r"^    (\w+) = lib\.MODBUS_EXCEPTION_(\w+)$", native, re.M) == [
        (n, n) for n in names]


def _exception_reply(code: int) -> BaseException:
    """What a read raises when a scripted TCP peer answers exception ``code``."""

    def script(i: int, adu: bytes) -> list[tuple[float, bytes]]:
        tid, _, _, unit = struct.unpack(">HHHB", adu[:7])
        return [(0, mbap(tid, unit, bytes((adu[7] | 0x80, code))))]

    with (RawTcp(script) as peer, pymb.TcpClient("127.0.0.1", peer.port, slave=1) as c,
          pytest.raises(pymb.ModbusError) as ei):
        c.read_holding_registers(0, 1)
    return ei.value


@pytest.mark.parametrize("code", [0x09, 0x0C, 0xFF])
def test_codes_the_specification_does_not_name_are_device_exceptions(code: int) -> None:
    """As the module says: 09 and 0C..FF raise DeviceException itself, with .code."""
    e = _exception_reply(code)
    assert type(e) is pymb.DeviceException
    assert isinstance(e, pymb.DeviceException)
    assert e.code == code
    assert f"exception {code:02X}" in str(e)


def test_exception_code_zero_is_a_protocol_error() -> None:
    e = _exception_reply(0)
    assert isinstance(e, pymb.ProtocolError)
    assert not isinstance(e, pymb.DeviceException)
