"""The serial clients (RTU, ASCII) check their port and line settings alike,
before anything is opened: one InvalidArgument each, the port first."""

from __future__ import annotations

from typing import Any

import pytest

from pymb import AsciiClient, InvalidArgument, RtuClient


@pytest.mark.parametrize("cls", [RtuClient, AsciiClient])
@pytest.mark.parametrize(("args", "message"), [
    (("", 12345), "port must be a device path, got ''"),
    ((None,), "port must be a device path, got None"),
    (("/dev/ttyUSB0", 12345), "baudrate 12345 is not a rate the serial driver supports; "
                              "use one of "),
    (("/dev/ttyUSB0", 9600, "X"), "parity must be 'N', 'E' or 'O', got 'X'"),
    (("/dev/ttyUSB0", 9600, "e", 9), "data_bits must be"),
    (("/dev/ttyUSB0", 9600, "e", 8, 3), "stop_bits must be"),
])
def test_a_bad_port_or_setting_is_refused(cls: Any, args: tuple[Any, ...], message: str) -> None:
    with pytest.raises(InvalidArgument) as got:
        cls(*args)
    assert str(got.value).startswith(message)


@pytest.mark.parametrize("cls", [RtuClient, AsciiClient])
def test_the_settings_are_kept_checked(cls: Any) -> None:
    c = cls("/dev/ttyUSB0", 19200, "e", 7, 2)
    assert (c.baudrate, c.parity, c.data_bits, c.stop_bits) == (19200, "E", 7, 2)
    assert not c.connected
