"""A simulated map device judges each request as the Modbus application
protocol says ([MB-AP] 6 and 7), asked over Modbus TCP by a raw client
written from the specification: the function code first (01), then the
PDU's size, the quantity, the byte count and a coil's value (03), then the
addresses (02); and the largest requests the specification allows are
served, to pymodbus's client over RTU on a pseudo-terminal."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import pytest
from servekit import RawClient

from pymb import maps
from pymb.sim import Simulator
from pymb.sim.mapsim import MapSimDevice

UNIT = 5
COILS = 2100
REGISTERS = 200


def relay_map() -> str:
    """A device of 2100 writable coils (0..2099) and 200 writable holding registers."""
    out = ['schema = "pymb.map/1"', "[device]", 'id = "acme-relay"', 'table = "holding"']
    for i in range(COILS):
        out += ["[[point]]", f'name = "c{i}"', 'table = "coil"', f"address = {i}",
                'type = "bool"', 'access = "rw"']
    for i in range(REGISTERS):
        out += ["[[point]]", f'name = "h{i}"', f"address = {i}", 'type = "u16"',
                'access = "rw"']
    return "\n".join(out) + "\n"


RELAY = relay_map()


def device() -> MapSimDevice:
    return MapSimDevice(maps.loads(RELAY), UNIT, seed=0, clock=None, dynamic=False)


@pytest.fixture(scope="module")
def sim() -> Iterator[Simulator]:
    with Simulator([device()], transport="tcp") as s:
        yield s


def ask(sim: Simulator, pdu: bytes) -> bytes:
    """One request on a connection of its own; the reply's PDU."""
    c = RawClient(sim.tcp_port, timeout=5)
    try:
        return c.ask(1, UNIT, pdu)
    finally:
        c.close()


def coils_pdu(address: int, n: int, byte_count: int | None = None) -> bytes:
    bc = (n + 7) // 8 if byte_count is None else byte_count
    return struct.pack(">BHHB", 0x0F, address, n, bc) + b"\xff" * bc


def registers_pdu(address: int, n: int, byte_count: int | None = None) -> bytes:
    bc = 2 * n if byte_count is None else byte_count
    return struct.pack(">BHHB", 0x10, address, n, bc) + b"\x00\x01" * (bc // 2)


@pytest.mark.parametrize(("pdu", "code"), [
    # 01 first: a function the device does not have, whatever its size
    (b"\x2b\x0e\x01\x00", 1),          # read device identification
    (b"\x41", 1),                      # a user-defined code, no data
    (b"\x00", 1),                      # function code 0
    (b"\x08\x00\x00\x12\x34", 1),      # diagnostics
    (b"\x17" + bytes(11), 1),          # read/write registers
    # 03: a write single coil of neither ON (FF00) nor OFF (0000)
    (b"\x05\x00\x00\x12\x34", 3),
    (b"\x05\x00\x00\x00\xff", 3),
    (b"\x05\xff\xff\x00\x01", 3),      # 03 before the address's 02
    # 03: quantities outside 1..1968 coils, 1..123 registers, byte counts that disagree
    (coils_pdu(0, 0), 3),
    (coils_pdu(0, 1969), 3),
    (coils_pdu(0, 1976), 3),
    (coils_pdu(0, 8, byte_count=2), 3),
    (registers_pdu(0, 0), 3),
    (registers_pdu(0, 2, byte_count=2), 3),
    (registers_pdu(0, 2) + b"\x00\x00", 3),  # data past the byte count
    # 02: the addresses, once the request is well formed
    (coils_pdu(COILS - 1, 2), 2),
    (registers_pdu(REGISTERS - 1, 2), 2),
    (b"\x05\x08\x34\xff\x00", 2),      # coil 2100 does not exist
], ids=lambda v: v[:8].hex() if isinstance(v, bytes) else f"0{v}")
def test_a_request_is_refused_with_the_code_the_specification_names(
        sim: Simulator, pdu: bytes, code: int) -> None:
    assert ask(sim, pdu) == bytes((pdu[0] | 0x80, code))


def test_refused_writes_leave_the_device_as_it_was(sim: Simulator) -> None:
    assert ask(sim, b"\x05\x00\x07\xff\x00") == b"\x05\x00\x07\xff\x00"
    assert ask(sim, b"\x05\x00\x07\x12\x34") == b"\x85\x03"  # not read as OFF
    assert ask(sim, b"\x01\x00\x07\x00\x01") == b"\x01\x01\x01"
    assert ask(sim, registers_pdu(10, 0)) == b"\x90\x03"
    assert ask(sim, b"\x05\x00\x07\x00\x00") == b"\x05\x00\x07\x00\x00"
    assert ask(sim, b"\x01\x00\x07\x00\x01") == b"\x01\x01\x00"


def test_the_largest_requests_are_served_to_pymodbus_over_rtu() -> None:
    from pymodbus.client import ModbusSerialClient

    with Simulator([device()]) as s:
        c = ModbusSerialClient(s.port, baudrate=9600, timeout=3)
        assert c.connect()  # type: ignore[no-untyped-call]
        try:
            before = list(c.read_coils(100, count=2000, device_id=UNIT).bits[:2000])
            assert not c.write_coils(100, [True] * 1968, device_id=UNIT).isError()
            assert c.read_coils(100, count=2000, device_id=UNIT).bits[:2000] == \
                [True] * 1968 + before[1968:]
            values = list(range(1000, 1123))
            assert not c.write_registers(0, values, device_id=UNIT).isError()
            assert c.read_holding_registers(0, count=125, device_id=UNIT).registers[:123] == \
                values
            assert c.write_coil(COILS, True, device_id=UNIT).exception_code == 2
        finally:
            c.close()  # type: ignore[no-untyped-call]
