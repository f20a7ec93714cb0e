"""Map devices in the logger's configuration: :class:`MapDeviceConfig` (a
device read through a ``pymb.map/1`` map: which groups, its health timing),
the maps a configuration knows (``maps = [...]`` in TOML,
``--map FILE`` on the command line, the shipped maps) and the
``[[bus.device]]`` table of a map device."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from pymb import maps
from pymb.devices.mapreading import group_points
from pymb.devices.mapspec import FACADES, MapTarget, near
from pymb.errors import InvalidArgument
from pymb.maps import Map, MapError

__all__ = ["MAP_DEVICE_KEYS", "KnownMaps", "MapDeviceConfig", "map_device_from_toml"]

#: keys of a map device's ``[[bus.device]]`` table, besides the map's options
MAP_DEVICE_KEYS = ("type", "map", "address", "name", "groups", "offline_after",
                   "offline_retry", "deadband")


@dataclass(frozen=True)
class MapText:
    """A map with the TOML text it was loaded from (stored with its samples,
    so a database decodes without the file)."""

    map: Map
    text: str


class KnownMaps:
    """Map id -> map: the files given (``maps = [...]``, ``--map``) and the
    shipped maps, except the two facades' (``coolpro``, ``hub``)."""

    def __init__(self) -> None:
        self._maps: dict[str, MapText] = {}
        self._paths: dict[str, str] = {}

    def add_file(self, path: str | os.PathLike[str], where: str) -> MapText:
        """Load the map file at ``path``; ``where`` names the file and key
        that gave it, in errors."""
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            why = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            raise InvalidArgument(f"{where}: cannot read the map {path}: {why}") from None
        for got in self._maps.values():  # a file many devices name is loaded once
            if got.text == text and os.path.realpath(self._paths.get(got.map.id, "")) == \
                    os.path.realpath(path):
                return got
        try:
            m = maps.loads(text, source=str(path))
        except MapError as e:
            raise InvalidArgument(f"{where}: {e}") from None
        if m.id in FACADES or m.id in maps.builtin_ids():
            raise InvalidArgument(f"{where}: {path}: device id {m.id!r} is a device pymb "
                                  "ships; give the map another id")
        if m.id in self._maps:
            raise InvalidArgument(f"{where}: {path}: device id {m.id!r} is also the id of "
                                  f"{self._paths[m.id]}")
        got = self._maps[m.id] = MapText(m, text)
        self._paths[m.id] = str(path)
        return got

    def get(self, kind: str) -> MapText | None:
        """The map of device type ``kind`` (a file's, or a shipped one), or None."""
        got = self._maps.get(kind)
        if got is None and kind not in FACADES and kind in maps.builtin_ids():
            res = resources.files("pymb.maps") / "builtin" / f"{kind}.toml"
            got = self._maps[kind] = MapText(maps.builtin(kind), res.read_text(encoding="utf-8"))
        return got

    @property
    def ids(self) -> list[str]:
        """Every map id known (files and shipped maps)."""
        return sorted({*self._maps, *(i for i in maps.builtin_ids() if i not in FACADES)})

    def as_dict(self) -> dict[str, Map]:
        """Map id -> map, for :func:`pymb.devices.mapspec.parse_map_device`."""
        return {i: got.map for i in self.ids if (got := self.get(i)) is not None}


@dataclass
class MapDeviceConfig:
    """A device on a bus read through its map: the groups polled (each at
    its own interval; default every group, or every readable point in one
    poll for a map without groups), and ``offline_after`` failed polls in a
    row before it is left alone for ``offline_retry`` seconds (default: the
    map's ``[device.timing]``), and for on-change storage, deadbands by point
    name over the map's own ``deadband`` of each point."""

    source: MapText
    address: int
    name: str = ""
    groups: tuple[str, ...] = ()
    offline_after: int | None = None
    offline_retry: float | None = None
    options: Mapping[str, int | float] = field(default_factory=dict)
    deadband: Mapping[str, float] = field(default_factory=dict)
    channels: int = 0  #: 0: a map device has no hub channels
    humidity_unit: float = 0.1  #: unused: a map device has no humidity unit

    def __post_init__(self) -> None:
        m = self.map
        if not self.groups:
            self.groups = tuple(m.groups) if m.groups else ()
        for g in self.groups:
            if g not in m.groups:
                hint = near(g, list(m.groups)) or "; it has " + ", ".join(m.groups)
                raise InvalidArgument(f"groups: {m.id} has no group {g!r}{hint}")
            if not group_points(m, g):
                raise InvalidArgument(f"groups: {m.id}'s group {g!r} has no readable point")
        if self.offline_after is None:
            self.offline_after = m.timing.offline_after
        if self.offline_retry is None:
            self.offline_retry = m.timing.offline_retry
        if isinstance(self.offline_after, bool) or not isinstance(self.offline_after, int) \
                or self.offline_after < 1:
            raise InvalidArgument(f"offline_after must be a whole number of failed polls, 1 or "
                                  f"more, got {self.offline_after!r}")
        if not (math.isfinite(self.offline_retry) and self.offline_retry > 0):
            raise InvalidArgument(f"offline_retry must be a number of seconds above 0, "
                                  f"got {self.offline_retry!r}")
        for point, band in self.deadband.items():
            if point not in m.points:
                raise InvalidArgument(f"deadband: {m.id} has no point {point!r}"
                                      f"{near(point, list(m.points))}")
            if not (math.isfinite(band) and band >= 0):
                raise InvalidArgument(f"deadband: {point} must be 0 or more, got {band!r}")
        if not self.name:
            self.name = f"{m.id}-{self.address}"

    @property
    def map(self) -> Map:
        """The map, with this device's options applied."""
        return self.source.map

    @property
    def type(self) -> str:
        """The device type: the map's id."""
        return self.source.map.id

    @property
    def polls(self) -> list[tuple[str | None, float | None]]:
        """(group, interval in seconds) of each poll; (None, None) for one poll
        of every readable point at the bus's interval (a map without groups)."""
        if not self.groups:
            return [(None, None)]
        return [(g, self.map.groups[g]) for g in self.groups]

    @property
    def spec(self) -> str:
        """The device in the command-line syntax, e.g. ``eastron-sdm120:3``."""
        opts = "".join(f",{k}={v:g}" for k, v in self.options.items())
        return f"{self.type}:{self.address}{opts}"


def from_target(t: MapTarget, source: MapText) -> MapDeviceConfig:
    """The device the command line named (``eastron-sdm120:3,name=meter``)."""
    return MapDeviceConfig(MapText(t.map, source.text), t.address, t.name,
                           options=dict(t.options))


def _number(d: Mapping[str, Any], key: str, where: str) -> Any:
    v = d.get(key)
    if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
        raise InvalidArgument(f"{where}: {key} must be a number, got {v!r}")
    return v


def map_device_from_toml(d: Mapping[str, Any], known: KnownMaps, where: str,
                         base: Path) -> MapDeviceConfig:
    """A ``[[bus.device]]`` table naming a map: ``type = "<map id>"`` or
    ``map = "FILE"`` (relative to the configuration's folder); ``where``
    names the file and device in errors."""
    kind, path = d.get("type"), d.get("map")
    if path is not None:
        if not isinstance(path, str):
            raise InvalidArgument(f"{where}: map must be a file name, got {path!r}")
        src = known.add_file(base / path, f"{where}: map")
        if kind is not None and kind != src.map.id:
            raise InvalidArgument(f"{where}: type {kind!r} is not the id of map {path} "
                                  f"({src.map.id!r}); give one of them")
    else:
        got = known.get(str(kind))
        if got is None:
            hint = near(str(kind), [*FACADES, *known.ids])
            raise InvalidArgument(f"{where}: unknown type {kind!r}{hint}; give coolpro, hub, "
                                  f"a map's id or map = \"FILE\"")
        src = got
    m = src.map
    option_keys = list(m.device.options)
    for key in d:
        if key not in MAP_DEVICE_KEYS and key not in option_keys:
            raise InvalidArgument(f"{where} [[bus.device]]: unknown key {key!r} for {m.id}"
                                  f"{near(key, [*MAP_DEVICE_KEYS, *option_keys])}")
    options = {k: _number(d, k, where) for k in option_keys if k in d}
    if options:
        try:
            m = m.configure(options)
        except MapError as e:
            raise InvalidArgument(f"{where}: {e}") from None
        src = MapText(m, src.text)
    address = d.get("address", m.device.default_address)
    low, high = m.device.addresses
    if isinstance(address, bool) or not isinstance(address, int) or not low <= address <= high:
        raise InvalidArgument(f"{where}: address: {m.id} address must be {low}..{high}, "
                              f"got {address!r}")
    name = d.get("name", "")
    if not isinstance(name, str):
        raise InvalidArgument(f"{where}: name must be a string, got {name!r}")
    groups = d.get("groups", [])
    if not isinstance(groups, list) or not all(isinstance(g, str) for g in groups):
        raise InvalidArgument(f"{where}: groups must be a list of group names, "
                              f"e.g. groups = [\"fast\"]")
    after = d.get("offline_after")
    if after is not None and (isinstance(after, bool) or not isinstance(after, int)):
        raise InvalidArgument(f"{where}: offline_after must be a whole number, got {after!r}")
    retry = _number(d, "offline_retry", where)
    bands = d.get("deadband", {})
    if not isinstance(bands, dict):
        raise InvalidArgument(f"{where}: deadband must be a table: deadband = "
                              "{ voltage_v = 0.5 }")
    for k in bands:
        _number(bands, k, f"{where}: deadband")
    try:
        return MapDeviceConfig(src, address, name, tuple(groups), after,
                               None if retry is None else float(retry), options,
                               {k: float(v) for k, v in bands.items()})
    except InvalidArgument as e:
        raise InvalidArgument(f"{where}: {e}") from None


def add_maps(known: KnownMaps, files: Sequence[Any], where: str, base: Path) -> None:
    """``maps = [...]`` of a configuration (relative to its folder)."""
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        raise InvalidArgument(f"{where}: maps must be a list of map files, "
                              "e.g. maps = [\"sdm120.toml\"]")
    for f in files:
        known.add_file(base / f, f"{where}: maps")
