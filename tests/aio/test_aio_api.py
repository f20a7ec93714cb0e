"""pymb.aio mirrors the blocking API: every public method of each blocking
client and facade exists on its async twin with the same signature (a
coroutine unless it does no I/O), every property can be read, and the
constructors take the same arguments."""

from __future__ import annotations

import asyncio
import inspect
import typing
from typing import Any

import pytest

import pymb
import pymb.aio
from pymb.devices import COOLPRO, CoolPro, MapDevice, SensorHub
from pymb.maps import Map
from pymb.maps.device_plan import PointPlanner

#: Methods that do no I/O and take no lock: the same plain method on both sides.
NO_IO = {"fileno", "frame_time", "plan"}
#: Facade methods the async form adds (no blocking twin).
ASYNC_ONLY = {"poll", "run"}

PAIRS: list[tuple[type, type]] = [
    (pymb.RtuClient, pymb.aio.AsyncRtuClient),
    (pymb.TcpClient, pymb.aio.AsyncTcpClient),
    (pymb.RtuOverTcpClient, pymb.aio.AsyncRtuOverTcpClient),
    (pymb.AsciiClient, pymb.aio.AsyncAsciiClient),
    (pymb.UdpClient, pymb.aio.AsyncUdpClient),
    (CoolPro, pymb.aio.AsyncCoolPro),
    (SensorHub, pymb.aio.AsyncSensorHub),
    (MapDevice, pymb.aio.AsyncMapDevice),
]


def _public(cls: type) -> dict[str, Any]:
    return {name: value for name, value in inspect.getmembers(cls)
            if not name.startswith("_")}


@pytest.mark.parametrize(("blocking", "aio"), PAIRS, ids=lambda c: c.__name__)
def test_every_public_method_is_mirrored_with_its_signature(blocking: type, aio: type) -> None:
    for name, member in _public(blocking).items():
        if isinstance(member, property):
            assert isinstance(getattr(aio, name, None), property), f"{aio.__name__}.{name}"
            continue
        if not callable(member):
            continue
        mirrored = getattr(aio, name, None)
        assert mirrored is not None, f"{aio.__name__} lacks {name}"
        assert inspect.signature(mirrored) == inspect.signature(member), name
        if name in NO_IO:
            assert not inspect.iscoroutinefunction(mirrored), name
        else:
            assert inspect.iscoroutinefunction(mirrored), f"{aio.__name__}.{name} is not async"
            assert mirrored.__doc__, name
    extra = {n for n, m in _public(aio).items() if callable(m) and not isinstance(m, property)}
    assert extra - set(_public(blocking)) <= ASYNC_ONLY, extra - set(_public(blocking))


#: Settings the blocking client sets at once, under its lock, that an async
#: client changes in turn with its requests instead (docs/asyncio.md: ``await
#: client.set_timeout(...)``): assigning from the loop would block it.
READ_ONLY_ON_AIO = {"timeout"}


@pytest.mark.parametrize(("blocking", "aio"), PAIRS, ids=lambda c: c.__name__)
def test_every_public_name_is_documented_and_settable_as_its_twin(
        blocking: type, aio: type) -> None:
    assert inspect.getdoc(aio), aio.__name__
    for name, member in _public(aio).items():
        target = member.fget if isinstance(member, property) else member
        if callable(target):
            assert inspect.getdoc(target), f"{aio.__name__}.{name}"
    for name, member in _public(blocking).items():
        if isinstance(member, property) and member.fset is not None:
            twin = getattr(aio, name)
            settable = twin.fset is not None
            assert settable == (name not in READ_ONLY_ON_AIO), f"{aio.__name__}.{name}"


@pytest.mark.parametrize(("blocking", "aio"), PAIRS, ids=lambda c: c.__name__)
def test_constructors_take_the_same_arguments(blocking: type, aio: type) -> None:
    want = list(inspect.signature(blocking).parameters.values())
    got = list(inspect.signature(aio).parameters.values())
    if blocking in (CoolPro, SensorHub, MapDevice):  # an async client: same name and place
        assert got[0].name == want[0].name == "client"
        want, got = want[1:], got[1:]
    assert got == want


@pytest.mark.parametrize(("blocking", "aio"), PAIRS[:5], ids=lambda c: c.__name__)
def test_instance_attributes_read_through(blocking: type, aio: type) -> None:
    serial = (pymb.aio.AsyncRtuClient, pymb.aio.AsyncAsciiClient)
    client: pymb.aio.AsyncClient = (aio("/dev/null") if aio in serial
                                    else aio("127.0.0.1", 1502))
    twin = client.blocking
    assert isinstance(twin, blocking)
    names = [n for n in vars(twin) if not n.startswith("_")]
    assert names  # connections, baudrate, host, ...
    for n in names:
        assert getattr(client, n) == getattr(twin, n), n
    client.slave = 17
    assert twin.slave == 17
    assert not client.connected
    assert repr(client).startswith(f"<{aio.__name__} ")


def test_read_only_properties_read_the_twin_and_refuse_assignment() -> None:
    """The async side's read-only properties: each a documented property that
    gives its blocking twin's attribute of the same name and refuses
    assignment as any property without a setter does."""
    tcp = pymb.aio.AsyncTcpClient("127.0.0.1", 1502)
    cases: list[tuple[Any, tuple[str, ...]]] = [
        (tcp, ("port", "connected", "connections", "resends", "fresh_connections", "timeout",
               "host", "tcp_port", "tls")),
        (pymb.aio.AsyncRtuClient("/dev/null"), ("baudrate", "parity", "data_bits", "stop_bits")),
        (pymb.aio.AsyncUdpClient("127.0.0.1", 1502), ("host", "udp_port", "retries")),
        (pymb.aio.AsyncSensorHub(tcp, 1), ("address", "channels", "unsupported")),
        (pymb.aio.AsyncMapDevice(tcp, COOLPRO, 40), ("address", "map", "states", "planner")),
    ]
    for obj, names in cases:
        cls = type(obj)
        for n in names:
            prop = getattr(cls, n)
            assert isinstance(prop, property), f"{cls.__name__}.{n}"
            assert prop.__doc__, f"{cls.__name__}.{n}"
            assert inspect.getdoc(prop.fget) == inspect.getdoc(prop), f"{cls.__name__}.{n}"
            assert prop.fget is not None
            assert prop.fget.__name__ == n
            assert getattr(obj, n) == getattr(obj.blocking, n), f"{cls.__name__}.{n}"
            with pytest.raises(AttributeError,
                               match=f"^property '{n}' of '{cls.__name__}' object has no setter$"):
                setattr(obj, n, getattr(obj, n))


#: The read-only properties' types, as their getters were written (``-> int``).
TYPES: dict[str, Any] = {
    "port": str, "connected": bool, "connections": int, "resends": int,
    "fresh_connections": int, "timeout": float, "host": str, "tcp_port": int,
    "tls": pymb.TlsConfig | None, "baudrate": int, "parity": str, "data_bits": int,
    "stop_bits": int, "udp_port": int, "retries": int, "address": int, "channels": int,
    "unsupported": frozenset[str], "map": Map, "states": dict[str, str | list[str]],
    "planner": PointPlanner}  # (states: dict[str, PointState])


def test_read_only_properties_getters_read_as_written_ones() -> None:
    """help(), inspect and typing see each forwarding property's getter as a
    written one: ``(self) -> its type``, named and placed in its class."""
    classes = [pymb.aio.AsyncTcpClient, pymb.aio.AsyncRtuClient, pymb.aio.AsyncUdpClient,
               pymb.aio.AsyncSensorHub, pymb.aio.AsyncMapDevice]
    seen = set()
    for cls in classes:
        for name, prop in inspect.getmembers(cls, lambda o: isinstance(o, property)):
            if name not in TYPES:
                continue
            seen.add(name)
            get = prop.fget
            assert get is not None
            assert list(inspect.signature(get).parameters) == ["self"], f"{cls.__name__}.{name}"
            assert typing.get_type_hints(get) == {"return": TYPES[name]}, f"{cls.__name__}.{name}"
            assert get.__qualname__.endswith(f".{name}")
            assert get.__module__ == cls.__module__
    assert seen == set(TYPES)


def test_bad_arguments_raise_what_the_blocking_client_raises() -> None:
    with pytest.raises(pymb.InvalidArgument, match="baudrate 1234"):
        pymb.aio.AsyncRtuClient("/dev/null", 1234)
    with pytest.raises(pymb.InvalidArgument, match="port must be from 1 to 65535"):
        pymb.aio.AsyncTcpClient("127.0.0.1", 0)
    client = pymb.aio.AsyncTcpClient("127.0.0.1", 1502)
    with pytest.raises(pymb.InvalidArgument, match="slave"):
        client.slave = 256

    async def unconnected() -> None:
        with pytest.raises(pymb.ModbusConnectionError, match="not connected"):
            await client.read_holding_registers(0, 1, slave=1)
        with pytest.raises(pymb.InvalidArgument, match="count must be"):
            await client.read_holding_registers(0, 0, slave=1)

    asyncio.run(unconnected())


def test_a_facade_needs_an_async_client() -> None:
    with pytest.raises(pymb.InvalidArgument, match=r"pymb\.aio client"):
        pymb.aio.AsyncCoolPro(pymb.TcpClient("127.0.0.1", 1502))  # type: ignore[arg-type]


def test_poll_checks_its_interval() -> None:
    hub = pymb.aio.AsyncSensorHub(pymb.aio.AsyncTcpClient("127.0.0.1", 1502), 1)
    for bad in (-1, "1", True, 1e9):
        with pytest.raises(pymb.InvalidArgument, match="poll interval"):
            hub.poll(bad)  # type: ignore[arg-type]
