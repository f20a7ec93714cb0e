"""The async clients on real lines: pseudo-terminals and TCP on 127.0.0.1,
pymb's simulator, scripted peers and independent servers (pymodbus, the
libmodbus C server). One worker per line, requests in order, lines in
parallel, and nothing left behind by close() or by the loop's end."""

from __future__ import annotations

import asyncio
import gc
import struct
import threading
from array import array
from collections.abc import Callable
from pathlib import Path

import pytest
from aiokit import Ticker, fds, pymb_threads, until
from conftest import TIMEOUT, wait_until
from peerkit import Reply, registers, rtu, rtu_crc_ok
from wire_peers import RawPty, build_libmodbus_server, libmodbus_server

import pymb
from pymb.aio import AsyncClient, AsyncRtuClient, AsyncRtuOverTcpClient, AsyncTcpClient
from pymb.sim import Simulator

pytest_plugins = ["pymb.testing"]


def echo_address(slave: int = 1, *, before: Callable[[], None] | None = None,
                 delay: float = 0.0) -> Callable[[int, bytes], Reply]:
    """A device at ``slave`` whose holding register N reads 1000 + N
    (function 0x03); silent to anything else. ``before`` runs first (in
    the peer's thread), the reply follows ``delay`` seconds later."""
    def script(_: int, frame: bytes) -> Reply:
        if not rtu_crc_ok(frame) or frame[0] != slave or frame[1] != 0x03:
            return []
        if before is not None:
            before()
        address, count = struct.unpack(">HH", frame[2:6])
        return [(delay, rtu(bytes((slave, 3)) + registers(
            [1000 + address + i for i in range(count)])))]
    return script


def port_is_free(port: str) -> bool:
    """Whether a blocking client can take the port's lock now."""
    try:
        with pymb.RtuClient(port, 9600):
            return True
    except pymb.ModbusConnectionError:
        return False


def test_requests_over_a_pty_and_tcp_against_the_simulator(
        pymb_simulator: Callable[..., Simulator]) -> None:
    rtu_sim = pymb_simulator("coolpro", "hub")
    tcp_sim = pymb_simulator("coolpro", transport="tcp")

    async def main() -> None:
        async with AsyncRtuClient(rtu_sim.port, 9600, slave=40) as c, \
                AsyncTcpClient(tcp_sim.host, tcp_sim.tcp_port, slave=40) as t:
            regs = await c.read_input_registers(0, 8)
            assert regs.typecode == "H"
            assert len(regs) == 8
            assert regs[0] > 20000  # millivolts of a 24 V supply
            assert list(await c.read_holding_registers(0, 2)) == [40, 0]
            assert list(await t.read_holding_registers(0, 1)) == [40]
            out = array("H", bytes(16))
            await t.read_input_registers_into(0, out)
            assert out[0] > 20000
            with pytest.raises(pymb.IllegalDataAddress):
                await c.read_input_registers(8, 1)
            assert len(await c.read_holding_registers(31, 700, slave=1)) == 700
            assert c.connections == t.connections == 1

    asyncio.run(main())


@pytest.mark.parametrize("mode", ["tcp", "rtu-over-tcp"])
def test_against_a_pymodbus_server(mode: str) -> None:
    pytest.importorskip("pymodbus")
    from wire_peers import pymodbus_server

    async def main(port: int) -> None:
        c: AsyncClient
        if mode == "tcp":
            c = AsyncTcpClient("127.0.0.1", port, slave=17, timeout=2)
        else:
            c = AsyncRtuOverTcpClient("127.0.0.1", port, slave=17, timeout=2)
        async with c:
            assert list(await c.read_holding_registers(0, 300)) == [7 * a for a in range(300)]
            assert list(await c.read_input_registers(10, 2)) == [40010, 40011]
            await c.write_register(900, 4242)
            await c.write_registers(901, [1, 2, 3])
            await c.mask_write_register(902, 0x00FF, 0x1200)
            assert list(await c.read_holding_registers(900, 4)) == [4242, 1, 0x1202, 3]
            await c.write_coils(2, [1, 1])
            assert list(await c.read_coils(0, 4)) == [0, 1, 1, 1]
            assert list(await c.read_discrete_inputs(0, 2)) == [1, 0]
            assert list(await c.write_read_registers(950, [9, 8], 949, 3)) == [7 * 949, 9, 8]
            assert await c.raw_request(0x08, b"\x00\x00\x12\x34") == b"\x00\x00\x12\x34"
            with pytest.raises(pymb.IllegalDataAddress):
                await c.read_holding_registers(990, 20)
            # many at once, in one queue: each gets its own answer
            got = await asyncio.gather(*(c.read_holding_registers(a, 1) for a in range(40)))
            assert [list(r) for r in got] == [[7 * a] for a in range(40)]

    with pymodbus_server(mode) as port:
        asyncio.run(main(port))


@pytest.fixture(scope="module")
def libmodbus_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_libmodbus_server(tmp_path_factory.mktemp("libmodbus"))


def test_against_the_libmodbus_server_on_a_pty(libmodbus_exe: Path) -> None:
    async def main(where: str) -> None:
        async with AsyncRtuClient(where, 115200, slave=17, timeout=2) as c:
            assert list(await c.read_holding_registers(0, 5)) == [0, 3, 6, 9, 12]
            await c.write_registers(6, [1, 2, 3])
            await c.write_coil(1, True)
            reads = await asyncio.gather(c.read_holding_registers(5, 4), c.read_coils(1, 1),
                                         c.read_input_registers(10, 2))
            assert [list(r) for r in reads] == [[15, 1, 2, 3], [1], [40010, 40011]]
            with pytest.raises(pymb.IllegalFunction):
                await c.raw_request(0x41)

    with libmodbus_server(libmodbus_exe, "rtu") as where:
        asyncio.run(main(where))


def test_concurrent_awaits_on_one_client_queue_and_never_interleave() -> None:
    # The peer frames requests by the line's silence: two requests written
    # back to back would arrive as one frame with a bad CRC and get no answer.
    async def main(port: str) -> None:
        async with AsyncRtuClient(port, 115200, slave=1, timeout=1.0) as c:
            got = await asyncio.gather(*(c.read_holding_registers(a, 2) for a in range(30)))
            assert [list(r) for r in got] == [[1000 + a, 1001 + a] for a in range(30)]
            assert c.worker_threads == 1

    with RawPty(echo_address()) as peer:
        asyncio.run(main(peer.port))
        assert len(peer.requests) == 30
        assert all(rtu_crc_ok(f) and len(f) == 8 for f in peer.requests)
        assert [struct.unpack(">H", f[2:4])[0] for f in peer.requests] == list(range(30))


def test_two_lines_run_in_parallel() -> None:
    # Each device answers only once both have a request: two lines taking
    # turns (one request at a time in the process) would time out here.
    both = threading.Barrier(2)

    async def main(a: str, b: str) -> None:
        async with AsyncRtuClient(a, 115200, slave=1, timeout=3.0) as ca, \
                AsyncRtuClient(b, 115200, slave=1, timeout=3.0) as cb:
            ra, rb = await asyncio.gather(ca.read_holding_registers(1, 1),
                                          cb.read_holding_registers(2, 1))
            assert (list(ra), list(rb)) == ([1001], [1002])

    def wait_for_both() -> None:
        both.wait(2.5)

    with RawPty(echo_address(before=wait_for_both)) as pa, \
            RawPty(echo_address(before=wait_for_both)) as pb:
        asyncio.run(main(pa.port, pb.port))


def test_a_dead_device_times_out_without_stalling_the_loop() -> None:
    async def main(port: str) -> None:
        async with AsyncRtuClient(port, 115200, timeout=TIMEOUT) as c:
            ticker = Ticker().start()
            with pytest.raises(pymb.ModbusTimeout):
                await c.read_holding_registers(0, 1, slave=9)  # nobody at 9
            await ticker.stop()
            # the loop ticked through the wait (a blocked loop shows one late tick)
            assert len(ticker.late) >= TIMEOUT / 0.010 / 3
            assert list(await c.read_holding_registers(7, 1, slave=1)) == [1007]

    with RawPty(echo_address()) as peer:
        asyncio.run(main(peer.port))


def test_an_unplugged_port_fails_then_the_client_reconnects(
        pymb_simulator: Callable[..., Simulator]) -> None:
    sim = pymb_simulator("coolpro")

    async def main() -> None:
        async with AsyncRtuClient(sim.port, 9600, slave=40, timeout=TIMEOUT) as c:
            await c.read_holding_registers(0, 1)
            sim.unplug()
            with pytest.raises(pymb.ModbusConnectionError):
                await c.read_holding_registers(0, 1)
            await until(lambda: not pymb_threads(), "the worker of a lost line to end")
            sim.replug()
            assert list(await c.read_holding_registers(0, 1)) == [40]
            assert c.connections == 2

    asyncio.run(main())


def test_settings_and_run_apply_in_turn_with_the_requests() -> None:
    async def main(port: str) -> None:
        async with AsyncRtuClient(port, 115200, slave=1, timeout=1.0) as c:
            await c.set_timeout(0.5, 0.1)
            assert (c.timeout, c.blocking.timeout) == (0.5, 0.5)

            def read_twice() -> list[int]:  # two requests, nothing between them
                b = c.blocking
                return [b.read_holding_registers(3, 1)[0], b.read_holding_registers(4, 1)[0]]

            first, pair, last = await asyncio.gather(
                c.read_holding_registers(1, 1), c.run(read_twice), c.read_holding_registers(5, 1))
            assert (list(first), pair, list(last)) == ([1001], [1003, 1004], [1005])
            with pytest.raises(pymb.InvalidArgument, match="timeout"):
                await c.set_timeout(0)
            with pytest.raises(AttributeError):
                c.timeout = 1.0  # type: ignore[misc]  # in turn only: set_timeout
            # a new slave applies to the requests not yet started
            on_the_wire = asyncio.ensure_future(c.read_holding_registers(6, 1))
            await until(lambda: len(peer.requests) == 5, "the request on the wire")
            queued = asyncio.ensure_future(c.read_holding_registers(7, 1))
            c.slave = 2  # nobody answers at 2
            assert list(await on_the_wire) == [1006]
            with pytest.raises(pymb.ModbusTimeout):
                await queued

    with RawPty(echo_address(delay=0.05)) as peer:
        asyncio.run(main(peer.port))
        assert [(f[0], struct.unpack(">H", f[2:4])[0]) for f in peer.requests] == \
            [(1, 1), (1, 3), (1, 4), (1, 5), (1, 6), (2, 7)]


def test_close_ends_the_worker_and_releases_port_and_descriptors(
        pymb_simulator: Callable[..., Simulator]) -> None:
    rtu_sim = pymb_simulator("coolpro")
    tcp_sim = pymb_simulator("coolpro", transport="tcp")
    gc.collect()
    before = fds()

    async def main() -> None:
        c = AsyncRtuClient(rtu_sim.port, 9600, slave=40)
        t = AsyncTcpClient(tcp_sim.host, tcp_sim.tcp_port, slave=40)
        for _ in range(2):  # close, then open again
            await c.connect()
            await t.connect()
            guards = sorted(task.get_name() for task in asyncio.all_tasks()
                            if task.get_name().startswith("pymb-aio guard"))
            assert guards == [f"pymb-aio guard {rtu_sim.port}",
                              f"pymb-aio guard {t.port}"]
            await asyncio.gather(c.read_input_registers(0, 8), t.read_input_registers(0, 8))
            assert len(pymb_threads()) == 2
            assert not port_is_free(rtu_sim.port)
            await asyncio.gather(c.close(), t.close())
            assert pymb_threads() == []
            await asyncio.sleep(0)  # the guards' turn to end
            assert not [task for task in asyncio.all_tasks()
                        if task.get_name().startswith("pymb-aio guard")]
            assert port_is_free(rtu_sim.port)
        await c.close()  # twice is fine
        assert c.worker_threads == 3  # one per connection, and one for the last close

    asyncio.run(main())
    gc.collect()
    assert fds() == before


@pytest.mark.parametrize("how", ["returns", "raises mid-request"])
def test_the_loop_shutting_down_closes_an_open_client(how: str) -> None:
    gc.collect()
    before = fds()
    clients: list[AsyncRtuClient] = []

    async def main(port: str) -> None:
        c = AsyncRtuClient(port, 115200, slave=1, timeout=2.0)
        clients.append(c)
        await c.connect()
        assert list(await c.read_holding_registers(1, 1)) == [1001]
        if how == "raises mid-request":
            slow = asyncio.ensure_future(c.read_holding_registers(2, 1))
            await until(lambda: len(peer.requests) == 2, "the second request on the wire")
            slow.cancel()
            raise KeyError("the program fails")

    with RawPty(echo_address(delay=0.2 if how != "returns" else 0.0)) as peer:
        if how == "returns":
            asyncio.run(main(peer.port))
        else:
            with pytest.raises(KeyError):
                asyncio.run(main(peer.port))
        # asyncio.run's end closed the line: no worker, no descriptor, no lock
        assert pymb_threads() == []
        assert not clients[0].connected
        assert port_is_free(peer.port)
    clients.clear()
    gc.collect()
    assert fds() == before


def test_a_client_moved_to_a_new_loop_is_watched_by_that_loop() -> None:
    # The first loop is closed by hand without cancelling its tasks (no
    # asyncio.run): its guard never runs. The loop the client is used in
    # next closes it at its end.
    with RawPty(echo_address()) as peer:
        c = AsyncRtuClient(peer.port, 115200, slave=1)
        first = asyncio.new_event_loop()
        first.run_until_complete(c.connect())
        first.close()

        async def main() -> None:
            await c.connect()  # already open: one more guard, on this loop
            assert list(await c.read_holding_registers(3, 1)) == [1003]

        asyncio.run(main())
        assert not c.connected
        assert pymb_threads() == []
        assert port_is_free(peer.port)


def test_a_client_dropped_while_open_is_closed_with_a_warning() -> None:
    async def main(port: str) -> None:
        c = AsyncRtuClient(port, 115200, slave=1)
        await c.connect()
        await c.read_holding_registers(1, 1)
        with pytest.warns(ResourceWarning, match="unclosed <AsyncRtuClient"):
            del c
        await until(lambda: not pymb_threads(), "the dropped client's worker to end")
        assert port_is_free(port)

    with RawPty(echo_address()) as peer:
        asyncio.run(main(peer.port))
    wait_until(lambda: not pymb_threads(), "no worker left")
