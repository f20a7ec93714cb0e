"""The bench worker's telemetry check takes each stack's result as it comes:
the decoded values of the pure-Python stacks, pymb's CoolProTelemetry, and
both say the same values to the parent (``tverify``)."""

from __future__ import annotations

from array import array

import pytest

from pymb.bench import pure
from pymb.bench.worker import _batch, telemetry_check, telemetry_reading, telemetry_values
from pymb.devices.coolpro import CoolProTelemetry, decode_telemetry

REGS = [12000, 500, 5000, 1000, 35000, 0x0001, 0x0002, 0x0041]  # uptime 0x20001, two flags


def test_both_forms_say_the_same_values() -> None:
    t = decode_telemetry(array("H", REGS))
    assert list(telemetry_values(t)) == pytest.approx(list(pure.decode_telemetry(REGS)))
    assert telemetry_values(t)[5] == float(0x20001)
    assert telemetry_values(t)[6] == float(0x41)
    assert telemetry_reading(t) == (t.registers, t)
    telemetry_check(t)  # pymb's read as it comes
    telemetry_check((t.registers, t))  # pymb-aio's
    telemetry_check((REGS, pure.decode_telemetry(REGS)))


@pytest.mark.parametrize("pymb_form", [True, False])
def test_a_read_without_input_voltage_or_registers_fails(pymb_form: bool) -> None:
    regs = [0, *REGS[1:]]
    values = decode_telemetry(array("H", regs)) if pymb_form else pure.decode_telemetry(regs)
    with pytest.raises(RuntimeError, match="no input voltage"):
        telemetry_check(values if isinstance(values, CoolProTelemetry) else (regs, values))
    with pytest.raises(RuntimeError, match="no input voltage"):
        telemetry_check((regs, values))
    with pytest.raises(RuntimeError, match="no input voltage"):
        telemetry_check((REGS[:7], telemetry_values(values) if pymb_form else values))


def test_a_batch_times_each_call_with_its_check() -> None:
    t = decode_telemetry(array("H", REGS))
    calls: list[str] = []

    def op() -> CoolProTelemetry:
        calls.append("op")
        return t

    def check(read: CoolProTelemetry) -> None:
        assert read is t
        calls.append("check")

    answer = _batch(op, 3, check).split()
    assert answer[0] == "ok"
    assert len(answer) == 2 + 3  # the batch's CPU, then each call's wall time
    assert all(int(w) >= 0 for w in answer[1:])
    assert calls == ["op", "check"] * 3
    bad = decode_telemetry(array("H", [0, *REGS[1:]]))
    with pytest.raises(RuntimeError, match="no input voltage"):
        _batch(lambda: bad, 2, telemetry_check)
