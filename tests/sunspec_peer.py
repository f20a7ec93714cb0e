"""An independent SunSpec device for the tests: pysunspec2 (the SunSpec
Alliance's own Python library) builds the register image from models and
point values, pymodbus serves it (tests/sunspec_server.py, its own process),
and pysunspec2's Modbus client reads it back for the values to compare."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import sunspec2.device as ss_device
import sunspec2.modbus.client as ss_client

from pymb import maps

HERE = Path(__file__).resolve().parent
SUNS = [0x5375, 0x6E53]


def model_registers(model_id: int, values: Mapping[str, Any]) -> list[int]:
    """One model's registers (ID, L, points) as pysunspec2 writes them from
    ``values`` (point name -> raw value, a repeating group a list of such
    tables); points not given are not implemented."""
    data = {"ID": model_id, **values}
    first = ss_device.Model(model_id=model_id, data=data).get_mb()
    data["L"] = len(first) // 2 - 2
    raw = ss_device.Model(model_id=model_id, data=data).get_mb()
    return [int.from_bytes(raw[i:i + 2], "big") for i in range(0, len(raw), 2)]


def image(models: Sequence[tuple[int, Mapping[str, Any]]]) -> list[int]:
    """``SunS``, each model, the end marker (0xFFFF, L 0)."""
    out = list(SUNS)
    for mid, values in models:
        out += model_registers(mid, values)
    return [*out, 0xFFFF, 0]


@dataclass
class Server:
    """The running server: its port, and a way to change registers."""

    port: int
    unit: int
    base: int
    proc: subprocess.Popen[str]

    def set(self, registers: Mapping[int, Sequence[int]], *, after: int = 0) -> int:
        """Once ``after`` more requests have come, write each address's
        registers, all at once; the requests served so far."""
        assert self.proc.stdin is not None
        assert self.proc.stdout is not None
        cmd = {"after": after, "set": {str(a): list(v) for a, v in registers.items()}}
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        reply = self.proc.stdout.readline().split()
        assert reply, "the server said nothing"
        assert reply[0] == "OK", reply
        return int(reply[1])

    def pysunspec2(self) -> Any:
        """pysunspec2's own client of this server, scanned (close it after)."""
        dev = ss_client.SunSpecModbusClientDeviceTCP(slave_id=self.unit, ipaddr="127.0.0.1",
                                                     ipport=self.port, timeout=10)
        dev.scan()
        return dev


@contextmanager
def serve(registers: Sequence[int], tmp: Path, *, unit: int = 1,
          base: int = 40000) -> Iterator[Server]:
    """Serve ``registers`` from holding register ``base`` on as ``unit``."""
    spec = tmp / f"sunspec-{base}-{unit}.json"
    spec.write_text(json.dumps({"unit": unit, "base": base, "registers": list(registers)}))
    proc = subprocess.Popen([sys.executable, str(HERE / "sunspec_server.py"), str(spec)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().split()
        assert line, "the server printed nothing"
        assert line[0] == "READY", line
        yield Server(int(line[1]), unit, base, proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)


_COUNT_POINTS = {"NPt", "NCrv", "NCrvSet", "NCtl", "NPrt", "NStr", "NMod", "NProf", "IVLen"}
_RANGES = {
    "int16": (-32767, 32767), "uint16": (0, 0xFFFE), "count": (0, 0xFFFE),
    "acc16": (1, 0xFFFF), "enum16": (0, 0xFFFE), "bitfield16": (0, 0x7FFF),
    "sunssf": (-10, 10), "int32": (-(2**31 - 1), 2**31 - 1), "uint32": (0, 2**32 - 2),
    "acc32": (1, 2**32 - 1), "enum32": (0, 2**32 - 2), "bitfield32": (0, 2**31 - 1),
    "ipaddr": (1, 2**32 - 1), "int64": (-(2**63 - 1), 2**63 - 1), "uint64": (0, 2**63),
    "acc64": (1, 2**62),
}
#: Types the tests leave not implemented (pysunspec2 writes them as text).
SKIPPED_TYPES = ("pad", "eui48", "ipv6addr")


def random_values(model_id: int, rnd: Any, *, repeats: int = 2,
                  unimplemented: float = 0.1) -> dict[str, Any]:
    """Values for every point of ``model_id`` (a share of them left not
    implemented), ``repeats`` instances of every repeating group, counting
    points (``NPt``...) set to match; for :func:`model_registers`."""
    import struct

    definition = ss_device.get_model_def(model_id)

    def fill(g: Mapping[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for p in g.get("points", []):
            name, typ = p["name"], p["type"]
            if name in ("ID", "L") or typ in SKIPPED_TYPES:
                continue
            if name in _COUNT_POINTS:
                out[name] = repeats
                continue
            if rnd.random() < unimplemented:
                continue
            if typ == "string":
                n = rnd.randint(1, 2 * int(p["size"]))
                out[name] = "".join(rnd.choice("ABCXYZabcxyz0189 -_") for _ in range(n)).strip() \
                    or "A"
            elif typ == "float32":
                out[name] = struct.unpack(">f", struct.pack(">f", rnd.uniform(-1e6, 1e6)))[0]
            elif typ == "float64":
                out[name] = rnd.uniform(-1e9, 1e9)
            else:
                lo, hi = _RANGES[typ]
                out[name] = rnd.randint(lo, hi)
        for s in g.get("groups", []):
            c = s.get("count")
            if c is None:
                out[s["name"]] = fill(s)
            else:
                n = c if isinstance(c, int) and c > 0 else repeats
                out[s["name"]] = [fill(s) for _ in range(n)]
        return out

    return fill(definition["group"])


def pysunspec2_values(device: Any) -> dict[int, tuple[str, Any, Any]]:
    """Every point pysunspec2 read, by its on-wire address: (SunSpec type,
    raw value, computed value), None where not implemented."""
    out: dict[int, tuple[str, Any, Any]] = {}

    def walk(model: Any, g: Any) -> None:
        for p in g.points.values():
            if p.pdef["type"] in SKIPPED_TYPES:
                continue
            out[model.model_addr + p.offset] = (p.pdef["type"], p.value, p.cvalue)
        for sub in g.groups.values():
            for inst in (sub if isinstance(sub, list) else [sub]):
                walk(model, inst)

    for key, models in device.models.items():
        if isinstance(key, int):
            for model in models:
                walk(model, model)
    return out


def _flat(m: maps.Map, values: dict[str, Any]) -> dict[int, tuple[maps.Point, Any]]:
    """pymb's values by on-wire address, with their points."""
    out: dict[int, tuple[maps.Point, Any]] = {}
    for name, v in values.items():
        p = m.points[name]
        for c, x in enumerate(v if p.block else [v], 1):
            out[p.address_of(c)] = (p, x)
    return out


def _same(typ: str, theirs: Any, ours: Any) -> bool:
    if theirs is None or ours is None:
        return theirs is None and ours is None
    if isinstance(theirs, float) or isinstance(ours, float):
        return math.isclose(theirs, ours, rel_tol=1e-9, abs_tol=1e-12)
    return bool(theirs == ours)


def compare(m: maps.Map, values: dict[str, Any], theirs: dict[int, tuple[str, Any, Any]],
             scale_factors: dict[int, Any]) -> int:
    """Assert that pymb's ``values`` of map ``m`` are pysunspec2's (``theirs``,
    :func:`pysunspec2_values`), a point whose scale factor (raw, by address)
    is not implemented having none; the number of values compared."""
    ours = _flat(m, values)
    checked = 0
    for address, (typ, raw, computed) in theirs.items():
        assert address in ours, address
        p, got = ours[address]
        expected = computed
        if p.scale_from is not None:
            sf = scale_factors[m.points[p.scale_from].address]
            if sf is None:  # a not-implemented scale factor: no value, never a raw one
                expected = None
        assert _same(typ, expected, got), (p.name, address, typ, raw, computed, got)
        checked += 1
    return checked
