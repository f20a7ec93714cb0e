"""The bench's ``maps`` section: decoding a 100-point f32 map in one C call.

Beside it, the hub's 700 registers decoded through ``maps.builtin("hub")``
(one ``pymb_map_decode`` call), checked against the pure Python reference
codec: the decoding part of a hub read.

The map is 100 ``f32`` points in consecutive register pairs (a meter's
block), the registers seeded random floats. Timed (median of ``repeat``
timeit runs): ``Decoder.decode`` (one ``pymb_map_decode`` call from Python
into the decoder's preallocated arrays), ``Decoder.read`` (the same, plus
the ``{name: value}`` dict), and the pure Python reference codec
(``Map.decode`` point by point) for scale.
"""

from __future__ import annotations

import random
import statistics
import struct
import timeit
from array import array
from collections.abc import Callable
from typing import Any

from pymb import maps

__all__ = ["POINTS", "TARGET_US", "map_text", "registers", "run_section", "targets"]

TARGET_US = 10.0  #: one C call for a 100-point f32 map, from Python
POINTS = 100


def map_text(n: int = POINTS) -> str:
    """A map of ``n`` f32 points at input registers 0, 2, 4, ..."""
    head = 'schema = "pymb.map/1"\n[device]\nid = "bench-f32"\ntable = "input"\n'
    return head + "".join(f'[[point]]\nname = "v{i}"\naddress = {2 * i}\ntype = "f32"\n'
                          for i in range(n))


def registers(n: int = POINTS, seed: int = 0) -> array[int]:
    """``2 * n`` registers holding ``n`` seeded random float32 values."""
    rng = random.Random(seed)
    data = struct.pack(f">{n}f", *(rng.uniform(-1e4, 1e4) for _ in range(n)))
    return array("H", struct.unpack(f">{2 * n}H", data))


def _median_us(fn: Callable[[], object], repeat: int, number: int) -> float:
    runs = timeit.repeat(fn, repeat=max(3, repeat), number=number)
    return statistics.median(runs) / number * 1e6


def run_section(repeat: int, say: Callable[[str], None]) -> dict[str, Any]:
    """Time the three ways of decoding the map's registers (medians, us)."""
    say(f"maps: {POINTS}-point f32 map")
    m = maps.loads(map_text(), source="bench-f32.toml")
    d = maps.Decoder(m)
    regs = registers()
    names = list(m.points)
    ref = {n: m.decode(n, regs[2 * i:2 * i + 2]) for i, n in enumerate(names)}
    assert d.read(regs) == ref  # the C decoder's values are the reference's

    def reference() -> object:
        return [m.decode(n, regs[2 * i:2 * i + 2]) for i, n in enumerate(names)]

    return {
        "points": POINTS,
        "repeat": max(3, repeat),
        "decode_us": _median_us(lambda: d.decode(regs), repeat, 2000),
        "read_us": _median_us(lambda: d.read(regs), repeat, 500),
        "python_us": _median_us(reference, repeat, 20),
        "target_us": TARGET_US,
        "hub_map_us": _hub_map_us(repeat),
    }


def _hub_map_us(repeat: int, number: int = 500) -> float:
    """The hub's 700 registers decoded through its map (one pymb_map_decode
    call into the decoder's arrays), after a check that the values are the
    pure Python codec's; median, us."""
    rng = random.Random(1)
    regs = array("H", [rng.choice((0xFFFF, 0x8000, 0x00FF, 251, 0x80FB, 1013))
                       for _ in range(700)])
    hub = maps.builtin("hub")
    d = maps.Decoder(hub)
    d.decode(regs)
    got = d.values()
    for name, p in hub.points.items():  # the same values as point by point in Python
        if p.group == "sweep":
            base = p.address - d.address
            assert got[name] == hub.decode(name, regs[base:base + p.span]), name
    return _median_us(lambda: d.decode(regs), repeat, number)


def targets(section: dict[str, Any]) -> list[tuple[str, str, float, str, bool]]:
    """This section's target: (what, goal, measured, unit, met)."""
    us = section["decode_us"]
    rows = [(f"decoding a {section['points']}-point f32 map in one C call from Python",
             f"<= {TARGET_US:g} us", us, "us", us <= TARGET_US)]
    return rows
