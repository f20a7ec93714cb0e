"""The bench worker's telemetry check takes each stack's result as it comes:
the decoded values of the pure-Python stacks, pymb's CoolProTelemetry, and
both say the same values to the parent (``tverify``)."""

from __future__ import annotations

from array import array

import pytest

from pymb.bench import pure
from pymb.bench.worker import telemetry_check, telemetry_values
from pymb.devices.coolpro import decode_telemetry

REGS = [12000, 500, 5000, 1000, 35000, 0x0001, 0x0002, 0x0041]  # uptime 0x20001, two flags


def test_both_forms_say_the_same_values() -> None:
    t = decode_telemetry(array("H", REGS))
    assert list(telemetry_values(t)) == pytest.approx(list(pure.decode_telemetry(REGS)))
    assert telemetry_values(t)[5] == float(0x20001)
    assert telemetry_values(t)[6] == float(0x41)
    telemetry_check(t.registers, t)
    telemetry_check(REGS, pure.decode_telemetry(REGS))


@pytest.mark.parametrize("pymb_form", [True, False])
def test_a_read_without_input_voltage_or_registers_fails(pymb_form: bool) -> None:
    regs = [0, *REGS[1:]]
    values = decode_telemetry(array("H", regs)) if pymb_form else pure.decode_telemetry(regs)
    with pytest.raises(RuntimeError, match="no input voltage"):
        telemetry_check(regs, values)
    with pytest.raises(RuntimeError, match="no input voltage"):
        telemetry_check(REGS[:7], telemetry_values(values) if pymb_form else values)
