"""``pymb watch`` of a map device on a small terminal: the SDM630's 74 points
on 80x24 keep the status line on screen, and the points that do not fit give
way to one line that says how many more there are, as the hub view does.
A real ``pymb watch`` on its own pty against ``pymb simulate``, the screen
rebuilt by pyte."""

from __future__ import annotations

import pytest
from clikit import Pty

from pymb import maps
from pymb.sim import SimulatorProcess

pytestmark = pytest.mark.ctrl_c


@pytest.mark.parametrize(("cols", "rows"), [(80, 24), (60, 12)])
def test_watch_of_a_74_point_meter_fits_the_terminal(cols: int, rows: int) -> None:
    with SimulatorProcess(["eastron-sdm630:1"], quiet=True) as sim:
        p = Pty(["watch", "eastron-sdm630:1", "--port", sim.port], cols=cols, rows=rows)
        assert p.read_until(b"reads", 30), p.out[-500:]
        assert p.read_more(b"\x1b[H", 2, 30)  # two more screens drawn: one is whole
        screen = p.screen(cols, rows)
        p.interrupt()
    assert screen[0].startswith("eastron-sdm630:1 "), screen
    assert "reads" in screen[0], screen
    assert "faults" in screen[0], screen
    assert screen[1].startswith("l1_voltage_v"), screen
    hidden = 74 - (rows - 2)
    assert screen[rows - 1].rstrip() == f"… {hidden} more: use --group", screen
    # No line wrapped: the raw frames never write past the last column or row.
    frames = [f for f in p.out.split(b"\x1b[H") if b"reads" in f]
    assert frames
    for frame in frames:
        lines = frame.decode(errors="replace").replace("\r\n", "\n").split("\x1b[K\n")
        assert len(lines) <= rows
        assert all(len(ln.replace("\x1b[K", "").replace("\x1b[J", "")) < cols for ln in lines)


def test_a_group_that_fits_is_shown_whole() -> None:
    with SimulatorProcess(["eastron-sdm630:1"], quiet=True) as sim:
        p = Pty(["watch", "eastron-sdm630:1", "--group", "energy", "--port", sim.port])
        assert p.read_until(b"reads", 30), p.out[-500:]
        assert p.read_more(b"\x1b[H", 2, 30)
        screen = p.screen()
        p.interrupt()
    shown = [ln for ln in screen[1:] if ln.strip()]
    assert not any("more: use --group" in ln for ln in shown), screen
    m = maps.builtin("eastron-sdm630")
    energy = [n for n, pt in m.points.items() if pt.group == "energy"]
    assert 1 < len(energy) < 23
    assert [ln.split()[0] for ln in shown] == energy, screen


def test_fit_keeps_what_fits() -> None:
    from pymb.commands.watch import fit

    assert fit(["a", "b", "c"], 80, 3) == ["a", "b", "c"]
    assert fit(["a", "b", "c", "d"], 80, 3) == ["a", "b", "… 2 more: use --group"]
    assert fit(["x" * 100], 80, 3) == ["x" * 79]
    assert fit(["a"], 80, 0) == []
