"""The devices in the logger's configuration: :class:`DeviceConfig` (a
device read through its ``pymb.map/1`` map, a shipped one or a file's:
which groups, its health timing, its options),
the maps a configuration knows (``maps = [...]`` in TOML,
``--map FILE`` on the command line, the shipped maps) and the
``[[bus.device]]`` table of a map device."""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from pymb import maps
from pymb.client import Client
from pymb.devices.coolpro import coolpro_device
from pymb.devices.hubsweep import SweepReader
from pymb.devices.mapdevice import MapDevice
from pymb.devices.mapreading import MapReading, group_points
from pymb.devices.mapspec import (
    MapTarget,
    near,
    parse_map_device,
    unknown_device,
)
from pymb.devices.spec import closest, split_spec
from pymb.errors import InvalidArgument
from pymb.maps import Map, MapError
from pymb.maps.model import check_address

__all__ = ["MAP_DEVICE_KEYS", "VIEW_OPENERS", "DeviceConfig", "KnownMaps", "MapText",
           "map_device_from_toml", "parse_device", "shipped"]

#: keys of a map device's ``[[bus.device]]`` table, besides the map's options
MAP_DEVICE_KEYS = ("type", "map", "address", "name", "groups", "offline_after",
                   "offline_retry", "deadband")


@dataclass(frozen=True)
class MapText:
    """A map with the TOML text it was loaded from (stored with its samples,
    so a database decodes without the file)."""

    map: Map
    text: str


def shipped(kind: str) -> MapText:
    """The shipped map of device type ``kind``, with its text."""
    res = resources.files("pymb.maps") / "builtin" / f"{kind}.toml"
    return MapText(maps.builtin(kind), res.read_text(encoding="utf-8"))


class KnownMaps:
    """Map id -> map: the files given (``maps = [...]``, ``--map``) and the
    shipped maps."""

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
        if m.id in maps.builtin_ids():
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
        if got is None and kind in maps.builtin_ids():
            got = self._maps[kind] = shipped(kind)
        return got

    @property
    def ids(self) -> list[str]:
        """Every map id known (files and shipped maps)."""
        return sorted({*self._maps, *maps.builtin_ids()})


#: an option's value: a number, or for an option given per channel one number a channel
Option = int | float | tuple[int | float, ...]
#: an opened device: its :class:`MapDevice` and a read of one group (None: all)
Opened = tuple[MapDevice, Callable[[str | None], MapReading]]


def _configured(source: MapText, options: Mapping[str, Option]) -> MapText:
    """``source`` with ``options`` applied; an option given per channel (a
    tuple: the hub's humidity unit) configures the map with its most common
    value (ties: the map's default), after each value is checked."""
    m = source.map
    one: dict[str, int | float] = {}
    for key, value in options.items():
        if not isinstance(value, tuple):
            one[key] = value
            continue
        channels = options.get("channels", m.options.get("channels"))
        if channels is None or isinstance(channels, tuple):
            raise InvalidArgument(f"{m.id}: {key} takes one value, got {list(value)!r}")
        if len(value) != channels:
            raise InvalidArgument(f"{len(value)} {key} values given for {channels} channels")
        for v in set(value):
            try:
                m.configure({key: v})
            except MapError as e:
                raise InvalidArgument(str(e)) from None
        default = m.options.get(key)
        one[key] = max(dict.fromkeys(value), key=lambda v: (value.count(v), v == default))
    if not one:
        return source
    try:
        return MapText(m.configure(one), source.text)
    except MapError as e:
        raise InvalidArgument(str(e)) from None


@dataclass
class DeviceConfig:
    """A device on a bus read through its map: ``source`` is the map (with
    ``options`` applied) or a shipped map's id (``"coolpro"``, ``"hub"``,
    ``"eastron-sdm120"``: ``options`` are applied here); ``address`` None is
    the map's default address. The groups polled (each at its own interval,
    or at the bus's for a group of ``poll = "bus"``; default every group but
    those of ``poll = "request"``, which are never polled, or every readable
    point in one poll for a map without groups), and ``offline_after`` failed polls
    in a row before it is left alone for ``offline_retry`` seconds (default:
    the map's ``[device.timing]``), and for on-change storage, deadbands by
    point name over the map's own ``deadband`` of each point."""

    source: MapText | str
    address: int | None = None
    name: str = ""
    groups: tuple[str, ...] = ()
    offline_after: int | None = None
    offline_retry: float | None = None
    options: Mapping[str, Option] = field(default_factory=dict)
    deadband: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.source, str):
            if self.source not in maps.builtin_ids():
                raise InvalidArgument(f"unknown device type {self.source!r}; use coolpro, hub "
                                      f"or a shipped map's id"
                                      f"{near(self.source, maps.builtin_ids())}")
            self.source = _configured(shipped(self.source), self.options)
        m = self.map
        self.address = check_address(m, self.address)
        if not self.groups:
            self.groups = tuple(g for g in m.groups if m.polled(g) != "request")
            if m.groups and not self.groups:  # (not a map without groups, read whole)
                raise InvalidArgument(f"every group of {m.id} is read on request "
                                      "(poll = \"request\"): nothing to poll")
        for g in self.groups:
            if g not in m.groups:
                hint = near(g, list(m.groups)) or "; it has " + ", ".join(m.groups)
                raise InvalidArgument(f"groups: {m.id} has no group {g!r}{hint}")
            if not group_points(m, g):
                raise InvalidArgument(f"groups: {m.id}'s group {g!r} has no readable point")
            if m.polled(g) == "request":
                raise InvalidArgument(f"groups: {m.id}'s group {g!r} is read on request, "
                                      "never polled")
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
    def text(self) -> MapText:
        """The map with the text it was loaded from."""
        assert isinstance(self.source, MapText)  # made one by __post_init__
        return self.source

    @property
    def map(self) -> Map:
        """The map, with this device's options applied."""
        return self.text.map

    @property
    def type(self) -> str:
        """The device type: the map's id."""
        return self.map.id

    def option(self, key: str) -> Option:
        """An option's value: as given (a tuple: one value a channel), else
        the map's (its default); KeyError for an option the map lacks."""
        return self.options.get(key, self.map.options[key])

    @property
    def polls(self) -> list[tuple[str | None, float | None]]:
        """(group, interval in seconds) of each poll; (None, None) for one poll
        of every readable point at the bus's interval (a map without groups);
        a group of ``poll = "bus"`` at the bus's interval (None)."""
        if not self.groups:
            return [(None, None)]
        m = self.map
        return [(g, None if m.polled(g) == "bus" else m.groups[g]) for g in self.groups]

    def open(self, client: Client, baudrate: int | None = None) -> Opened:
        """The device on ``client``: its :class:`MapDevice` (plans priced at
        ``baudrate`` where the client has none) and a read of one group as a
        :class:`MapReading`; a device whose map names a typed view
        (``[device] view``) as the view reads it (:data:`VIEW_OPENERS`)."""
        assert self.address is not None
        opener = VIEW_OPENERS.get(self.map.device.view)
        if opener is not None:
            return opener(self, client)
        dev = MapDevice(client, self.map, self.address, baudrate=baudrate)
        return dev, functools.partial(_read_group, dev)

    def sweep_reader(self, client: Client) -> SweepReader:
        """A hub's reader on ``client`` (its blocks and channels read as map readings)."""
        assert self.address is not None
        return SweepReader(client, self.address, int(self.map.options["channels"]),
                           self.option("humidity_unit"))  # type: ignore[arg-type]

    @property
    def spec(self) -> str:
        """The device in the command-line syntax, e.g. ``hub:250,channels=50``:
        the options that differ from the map's defaults, in the map's order."""
        default = self.map.device.options
        opts = "".join(f",{k}={v:g}" for k in default
                       if not isinstance(v := self.options.get(k, default[k]), tuple)
                       and v != default[k])
        return f"{self.type}:{self.address}{opts}"


def _read_group(dev: MapDevice, group: str | None) -> MapReading:
    return dev.read_group(group)


def _open_hub(cfg: DeviceConfig, client: Client) -> Opened:
    hub = cfg.sweep_reader(client)
    return hub.device, hub


def _open_coolpro(cfg: DeviceConfig, client: Client) -> Opened:
    assert cfg.address is not None
    dev = coolpro_device(client, cfg.address)
    return dev, functools.partial(_read_group, dev)


#: How :meth:`DeviceConfig.open` opens a device whose map names a typed view
#: (``[device] view``, one of :data:`pymb.maps.point.VIEWS`): the hub as
#: :class:`~pymb.devices.hubsweep.SweepReader` reads it (its firmware rules,
#: a busy hub, a humidity unit per channel), the CoolPro as
#: :func:`~pymb.devices.coolpro.coolpro_device` (no silence kept after a
#: reply, an exception raised as the device answered it).
VIEW_OPENERS: Mapping[str, Callable[[DeviceConfig, Client], Opened]] = {
    "hub": _open_hub, "coolpro": _open_coolpro}


def from_target(t: MapTarget, source: MapText) -> DeviceConfig:
    """The device the command line named (``eastron-sdm120:3,name=meter``)."""
    return DeviceConfig(MapText(t.map, source.text), t.address, t.name,
                        options=dict(t.options))


def parse_device(spec: str, known: KnownMaps | None = None) -> DeviceConfig:
    """A device as the command line names it, ``TYPE[:ADDRESS][,key=value...]``:
    ``coolpro``, ``hub:250,channels=50`` or a map's id (a shipped map's, or
    one of ``known``'s files), checked against its map."""
    known = known or KnownMaps()
    kind = split_spec(spec)[0]
    src = known.get(kind)
    target = parse_map_device(spec, {kind: src.map}) if src is not None else None
    if src is None or target is None:
        raise unknown_device(spec, list(known.ids))
    return from_target(target, src)


def _number(d: Mapping[str, Any], key: str, where: str, kind: str = "a number") -> Any:
    v = d.get(key)
    if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
        raise InvalidArgument(f"{where}: {key} must be {kind}, got {v!r}")
    return v


def _option(d: Mapping[str, Any], key: str, where: str, m: Map) -> Option:
    """An option's value: a number, or a list of numbers (one a channel);
    a whole number where the map's default is one."""
    kind = "a whole number" if isinstance(m.device.options[key], int) else "a number"
    v = d[key]
    if isinstance(v, list):
        for x in v:
            _number({key: x}, key, where, kind)
        return tuple(v)
    return _number(d, key, where, kind)  # type: ignore[no-any-return]


def map_device_from_toml(d: Mapping[str, Any], known: KnownMaps, where: str,
                         base: Path) -> DeviceConfig:
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
            hint = near(str(kind), known.ids)
            raise InvalidArgument(f"{where}: unknown type {kind!r}{hint} (give coolpro, hub, "
                                  f"a map's id or map = \"FILE\")")
        src = got
    m = src.map
    option_keys = list(m.device.options)
    for key in d:
        if key not in MAP_DEVICE_KEYS and key not in option_keys:
            # (the typed views' tables are named by their type already)
            of = "" if m.device.view else f" for {m.id}"
            raise InvalidArgument(f"{where} [[bus.device]]: unknown key {key!r}{of}"
                                  f"{closest(key, [*MAP_DEVICE_KEYS, *option_keys])}")
    options = {k: _option(d, k, where, m) for k in option_keys if k in d}
    try:
        src = _configured(src, options)
    except InvalidArgument as e:
        raise InvalidArgument(f"{where}: {e}") from None
    m = src.map
    address = d.get("address", m.device.default_address)
    low, high = m.device.addresses
    if isinstance(address, bool) or not isinstance(address, int):
        raise InvalidArgument(f"{where}: address has the wrong type ({address!r})")
    if not low <= address <= high:
        raise InvalidArgument(f"{where}: {m.id} address must be {low}..{high}, "
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
        return DeviceConfig(src, address, name, tuple(groups), after,
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
