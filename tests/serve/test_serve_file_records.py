"""``pymb serve`` judges the file-record functions as [MB-AP] 6.14 and 6.15
say, in front of pymodbus's Modbus TCP server (which has them): a request
the specification allows reaches the device and its answer comes back; one
it refuses is answered 03 and never sent upstream."""

from __future__ import annotations

import struct

from servekit import RawClient, Served
from wire_peers import pymodbus_server


def write_file_record(registers: int) -> bytes:
    """A write file record (6.15) of one sub-request: file 4, record 7,
    ``registers`` registers; its request data length is 7 + 2 x registers."""
    sub = struct.pack(">BHHH", 6, 4, 7, registers) + bytes(range(2 * registers))
    return bytes((0x15, len(sub))) + sub


def test_file_records_the_specification_allows_reach_the_device() -> None:
    with pymodbus_server("tcp") as port, \
            Served("--tcp", f"127.0.0.1:{port}", "--timeout", "3") as s:
        c = RawClient(s.port)
        try:
            # 6.15's example, and the longest: 122 registers, request data length 0xFB
            example = bytes.fromhex("150D0600040007000306AF04BE100D")
            assert c.ask(1, 1, example) == example
            longest = write_file_record(122)
            assert longest[1] == 0xFB
            assert c.ask(2, 1, longest) == longest
            # 6.14: read file record 4, record 1, two registers (pymodbus answers
            # a record of its own, whatever the length asked)
            assert c.ask(3, 1, bytes.fromhex("14070600040001000 2".replace(" ", "")))[0] == 0x14
            # refused by serve: a write with no record data, a read past 0xF5
            assert c.ask(4, 1, bytes.fromhex("150706000400070000")) == b"\x95\x03"
            assert c.ask(5, 1, bytes((0x14, 0xF6)) + bytes(0xF6)) == b"\x94\x03"
        finally:
            c.close()
        s.stop()
    assert any("5 requests" in line and "3 sent" in line for line in s.stderr_lines), \
        s.stderr_lines
