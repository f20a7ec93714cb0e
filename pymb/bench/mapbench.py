"""The bench's ``maps`` section: decoding a 100-point f32 map in one C call.

Beside it, the hub's 700 registers decoded through ``maps.builtin("hub")``
against the dedicated hub decoder a sweep uses, in alternating pairs: the
part of a hub read that the map changes (the requests are the same six).

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

    hub_map, hub_sweep = _hub_pairs(repeat)
    return {
        "points": POINTS,
        "repeat": max(3, repeat),
        "decode_us": _median_us(lambda: d.decode(regs), repeat, 2000),
        "read_us": _median_us(lambda: d.read(regs), repeat, 500),
        "python_us": _median_us(reference, repeat, 20),
        "target_us": TARGET_US,
        "hub_map_us": hub_map,
        "hub_sweep_us": hub_sweep,
    }


def _hub_pairs(repeat: int, number: int = 500) -> tuple[float, float]:
    """The hub's 700 registers decoded through its map (one pymb_map_decode
    call into the decoder's arrays) and by the dedicated hub decoder
    (pymb_hub_decode into a reused HubReading's arrays, as ``read_all(into=)``
    does), timed in alternating pairs; medians, us. Both give the same values."""
    from pymb import _native
    from pymb.devices.hub import ALL_BLOCKS, HubReading

    rng = random.Random(1)
    regs = array("H", [rng.choice((0xFFFF, 0x8000, 0x00FF, 251, 0x80FB, 1013))
                       for _ in range(700)])
    d = maps.Decoder(maps.builtin("hub"))
    r = HubReading(100, regs)
    tenths = bytes([1]) * 100  # the map's default humidity unit, 0.1 %

    def sweep() -> None:
        _native.hub_decode(regs, 100, tenths, None, ALL_BLOCKS, 0, r.values, r.raw_states)

    sweep()
    d.decode(regs)
    assert [None if v != v else v for v in r.values] == [  # the same values, in the same order
        v for name in d.names for v in d.values()[name]]  # type: ignore[union-attr]
    via_map, dedicated = [], []
    for _ in range(max(3, repeat)):
        via_map.append(timeit.timeit(lambda: d.decode(regs), number=number) / number * 1e6)
        dedicated.append(timeit.timeit(sweep, number=number) / number * 1e6)
    return statistics.median(via_map), statistics.median(dedicated)


def targets(section: dict[str, Any]) -> list[tuple[str, str, float, str, bool]]:
    """This section's target: (what, goal, measured, unit, met)."""
    us = section["decode_us"]
    rows = [(f"decoding a {section['points']}-point f32 map in one C call from Python",
             f"<= {TARGET_US:g} us", us, "us", us <= TARGET_US)]
    if "hub_map_us" in section:
        ratio = section["hub_map_us"] / section["hub_sweep_us"]
        rows.append(("decoding the hub's 700 registers through its map, against the "
                     "dedicated sweep decoder", "<= 1.00x", ratio, "x", ratio <= 1.0))
    return rows
