"""``HubDevice.supports``: the simulated hub says which blocks its firmware
has, by the block's name given as ``name`` or, as before the keyword was
renamed, as ``block``."""

from __future__ import annotations

import pytest

from pymb import InvalidArgument
from pymb.sim import HubDevice


def test_supports_takes_the_old_keyword() -> None:
    old = HubDevice(7, firmware="1.07", dynamic=False)
    new = HubDevice(7, dynamic=False)
    assert old.supports("temperature_c")
    assert old.supports(block="temperature_c")
    assert not old.supports(block="pressure_kpa")
    assert not old.supports(name="pressure_kpa")
    assert new.supports(block="temperature2_c")
    assert not new.supports(block="nope")
    with pytest.raises(InvalidArgument):
        new.supports("temperature_c", block="temperature_c")
    with pytest.raises(InvalidArgument):
        new.supports()
