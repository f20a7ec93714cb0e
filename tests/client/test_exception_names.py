"""The names of the Modbus exceptions have one home, the C library's
pymb_strerror: the Python classes and the messages take theirs from it."""

from __future__ import annotations

from pymb._pymb_cffi import lib

import pymb
from pymb.errors import describe_exception, exception_class, request_error


def test_every_defined_code_has_its_class_and_the_c_name() -> None:
    # [MB-AP] 7: codes 01..08, 0A, 0B.
    names = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
             4: "server device failure", 5: "acknowledge", 6: "server device busy",
             7: "negative acknowledge", 8: "memory parity error",
             10: "gateway path unavailable", 11: "gateway target device failed to respond"}
    for code, name in names.items():
        cls = exception_class(code)
        assert cls is not pymb.DeviceException
        assert describe_exception(code) == cls.description == name


def test_codes_the_specification_does_not_define_are_named_so() -> None:
    for code in (9, 0x0C, 0x41, 0xFF):
        assert exception_class(code) is pymb.DeviceException
        assert describe_exception(code) == "exception code not defined by the Modbus specification"


def test_the_message_of_an_exception_names_it() -> None:
    err = request_error(int(lib.pymb_exception_errno(0x41)), function=3, slave=7, address=10,
                        count=2, port="/dev/ttyX", timeout=1.0, failed=(10, 2),
                        response=bytes((7, 0x83, 0x41, 0, 0)), header=1, frame=None)
    assert isinstance(err, pymb.DeviceException)
    assert err.code == 0x41
    assert str(err).startswith(
        "read_holding_registers(slave=7, address=10, count=2) on /dev/ttyX: device answered "
        "exception 41 (exception code not defined by the Modbus specification)")
