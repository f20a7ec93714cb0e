"""The device syntax ``TYPE[:ADDRESS][,key=value...]`` for a device map's
id: the map types a command knows (the shipped maps, and the files given
with ``--map``) and one device of them, checked against its map.

``coolpro`` and ``hub`` have typed views (:class:`~pymb.devices.CoolPro`,
:class:`~pymb.devices.SensorHub`): the command line shows them as those
views and names them apart from the map types here; a map file's id may
not take the name of a shipped map.
"""

from __future__ import annotations

import math
import os
import re
import struct
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

from pymb import maps
from pymb.devices.spec import parse_address, split_spec
from pymb.errors import InvalidArgument
from pymb.maps import Map, MapError
from pymb.maps.codec import decode_one
from pymb.maps.model import did_you_mean
from pymb.maps.point import VIEWS
from pymb.maps.types import TABLE_FUNCTIONS

__all__ = ["TYPED_VIEWS", "MapTarget", "load_map", "map_types", "match_map", "near",
           "parse_map_device", "unknown_device"]


#: The shipped maps with a typed view (``CoolPro``, ``SensorHub``): the
#: device syntax's texts name them first, apart from the other map types,
#: and ``pymb read``/``scan``/``simulate`` show them as their views. A view
#: is named by its own map only (``[device] view`` is its id): these are
#: the views' names, known without loading every shipped map to ask it.
TYPED_VIEWS = VIEWS


def near(word: str, known: Sequence[str]) -> str:
    """``; did you mean 'x'?`` when a known name is close to ``word``, else nothing."""
    hint = did_you_mean(word, known)
    return hint if hint.startswith("; did you mean") else ""


def unknown_device(spec: str, known: Sequence[str]) -> InvalidArgument:
    """The one-line error for a device whose TYPE is none of the ``known``
    map ids, with a did-you-mean."""
    kind = split_spec(spec)[0] if spec.strip() else spec
    # The closest name first; the shipped ids (dozens) are pymb map list's to show.
    shipped = set(maps.builtin_ids())
    yours = ", ".join(sorted(k for k in known if k not in shipped))
    hint = near(kind, [*TYPED_VIEWS, *known])
    return InvalidArgument(
        f"unknown device {spec!r}" + (f"{hint} A" if hint else ": a") + " device is "
        "TYPE[:ADDRESS][,key=value...], TYPE coolpro, hub or a map's id: `pymb map list` "
        "shows the shipped maps" + (f", --map gave {yours}" if yours else
                                    "; a map file of your own needs --map FILE"))


def load_map(path: str) -> Map:
    """A map file, or a one-line usage error naming the file."""
    try:
        return maps.load(path)
    except MapError as e:
        raise InvalidArgument(str(e)) from None
    except OSError as e:
        raise InvalidArgument(f"--map {path}: {e.strerror or e}") from None


class _Known(Mapping[str, Map]):
    """The maps given, then the shipped ones, each shipped map loaded when
    first looked up: a command that reads one device does not parse them all."""

    def __init__(self, given: dict[str, Map], shipped: list[str]) -> None:
        self._given = given
        self._shipped = [i for i in shipped if i not in given]

    def __getitem__(self, key: str) -> Map:
        if key in self._given:
            return self._given[key]
        if key in self._shipped:
            return maps.builtin(key)
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        yield from self._given
        yield from self._shipped

    def __len__(self) -> int:
        return len(self._given) + len(self._shipped)


def map_types(files: Sequence[str] = (), *, views: bool = False) -> Mapping[str, Map]:
    """Map id -> map: ``files`` first (a user's map is tried first where
    several would do, as by ``pymb scan``), then the shipped maps but, unless
    ``views``, the :data:`TYPED_VIEWS` (each loaded when looked up)."""
    shipped = [i for i in maps.builtin_ids() if views or i not in TYPED_VIEWS]
    given: dict[str, Map] = {}
    paths: dict[str, str] = {}
    seen: set[str] = set()
    for path in files:
        if (real := os.path.realpath(path)) in seen:
            continue  # the same file given twice: once
        seen.add(real)
        m = load_map(path)
        if m.id in maps.builtin_ids():
            raise InvalidArgument(f"--map {path}: device id {m.id!r} is a device pymb ships; "
                                  "give the map another id")
        if m.id in given:
            raise InvalidArgument(f"--map {path}: device id {m.id!r} is also the id of "
                                  f"--map {paths[m.id]}")
        given[m.id] = m
        paths[m.id] = path
    return _Known(given, shipped)


@dataclass(frozen=True)
class MapTarget:
    """One map device as the command line named it."""

    map: Map  #: with the options given applied
    address: int
    name: str
    options: Mapping[str, int | float]

    @property
    def spec(self) -> str:
        """The device in the command-line syntax, e.g. ``eastron-sdm120:3``."""
        opts = "".join(f",{k}={v:g}" for k, v in self.options.items())
        return f"{self.map.id}:{self.address}{opts}"


def _number(text: str, what: str, spec: str) -> int | float:
    try:
        return int(text, 0)
    except ValueError:
        pass
    try:
        v = float(text)
    except ValueError:
        raise InvalidArgument(f"{spec!r}: {what} must be a number, got {text!r}") from None
    if not math.isfinite(v):
        raise InvalidArgument(f"{spec!r}: {what} must be a number, got {text!r}")
    return v


def parse_map_device(spec: str, known: Mapping[str, Map]) -> MapTarget | None:
    """``TYPE[:ADDRESS][,key=value...]`` for a map's id, checked against the
    map (address range, options); None when TYPE is not a map's id."""
    kind, addr, opts = split_spec(spec)
    m = known.get(kind)
    if m is None:
        return None
    dev = m.device
    address = dev.default_address
    if addr is not None:
        address = parse_address(addr, spec)
    low, high = dev.addresses
    if not low <= address <= high:
        raise InvalidArgument(f"{spec!r}: {m.id} address must be {low}..{high}, got {address}")
    name = ""
    options: dict[str, int | float] = {}
    allowed = [*dev.options, "name"]
    for key, eq, value in opts:
        if key not in allowed or not eq or not value:
            what = "bad option" if key in allowed else f"unknown key {key!r}"
            hint = did_you_mean(key, allowed) if what != "bad option" else ""
            raise InvalidArgument(f"{spec!r}: {what}; {m.id} takes "
                                  f"{', '.join(k + '=...' for k in allowed)}{hint}")
        if key == "name":
            if name:
                raise InvalidArgument(f"{spec!r}: name given twice")
            name = value
        elif key in options:
            raise InvalidArgument(f"{spec!r}: {key} given twice")
        else:
            options[key] = _number(value, key, spec)
    if options:
        try:
            m = m.configure(options)
        except MapError as e:
            raise InvalidArgument(f"{spec!r}: {e}") from None
    return MapTarget(m, address, name or f"{m.id}-{address}", options)


def _rule_holds(value: object, rule: maps.Identify) -> bool:
    if rule.range is not None:
        return (isinstance(value, (int, float)) and not isinstance(value, bool)
                and rule.range[0] <= value <= rule.range[1])
    if rule.regex is not None:
        return isinstance(value, str) and re.search(rule.regex, value) is not None
    return bool(value == rule.equals)


def _holds(ask: Callable[[int, int, bytes], bytes | int | None], address: int,
           m: Map) -> list[str] | None:
    """What each identify point of ``m`` reads, when every rule holds; else None."""
    seen: list[str] = []
    for rule in m.identify:
        p = m.points[rule.point]
        reply = ask(address, TABLE_FUNCTIONS[p.table], struct.pack(">HH", p.address, p.count))
        if not isinstance(reply, bytes) or not reply:
            return None
        data = reply[1:1 + reply[0]]
        if p.table in ("coil", "discrete"):
            regs = [data[i // 8] >> (i % 8) & 1 for i in range(p.count)] if \
                len(data) * 8 >= p.count else []
        else:
            regs = list(struct.unpack(f">{len(data) // 2}H", data[:len(data) // 2 * 2]))
        if len(regs) < p.count:
            return None
        value, _ = decode_one(p, regs)
        if not _rule_holds(value, rule):
            return None
        seen.append(f"{rule.point} {value:g}" if isinstance(value, float)
                    else f"{rule.point} {value}")
    return seen


def match_map(ask: Callable[[int, int, bytes], bytes | int | None], address: int,
              known: Mapping[str, Map]) -> tuple[str, str] | None:
    """The map in ``known`` whose every ``[[identify]]`` rule holds for the
    device at ``address``, as (map id, what its points read); None for none.
    Maps without rules are never matched. Where several match, the one with
    the most rules (the most specific) wins, and the detail names the others
    that match as well. ``ask(address, function, data)`` returns the reply's
    data, an exception code or None."""
    matches: list[tuple[Map, list[str]]] = []
    for m in known.values():
        if m.identify:
            seen = _holds(ask, address, m)
            if seen is not None:
                matches.append((m, seen))
    if not matches:
        return None
    most = max(len(m.identify) for m, _ in matches)
    best = [(m, seen) for m, seen in matches if len(m.identify) == most]
    m, seen = best[0]
    what = " ".join(x for x in (m.device.manufacturer, m.device.model) if x)
    detail = (f"{what}: " if what else "") + ", ".join(seen)
    if len(best) > 1:
        detail += f" (the identify rules of {', '.join(o.id for o, _ in best[1:])} hold too)"
    return m.id, detail
