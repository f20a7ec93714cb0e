"""A contender's own process: ``python -m pymb.bench.worker NAME PORT BAUD K_OFF K_VAL``.

It opens the port with one stack, as that stack's user would, and answers
the parent on stdin/stdout, one line each (the C program speaks the same):

``sweep N``  N hub sweeps (700 registers in 6 requests, decoded), then
             ``ok CPU_NS WALL_NS...``: this process's CPU for the batch
             (``time.process_time_ns``) and each sweep's wall time.
``tele N``   N CoolPro telemetry reads, decoded; the same answer.
``verify``   one sweep: ``ok`` + the 700 raw registers, then ``ok`` + the
             700 decoded values (the parent checks both).
``tverify``  the same for one telemetry read (8 registers, 7 values).
``quit``     close the port and exit.

Every sweep checks two canary registers the parent chose from the simulated
hub's layout (``K_OFF`` always reads 0xFFFF, ``K_VAL`` never does) and the
decoded values there, so a contender that reads the wrong registers or
skips the decoding cannot post a time.
"""

from __future__ import annotations

import abc
import math
import struct
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from pymb.bench import pure
from pymb.devices import COOLPRO, HUB, CoolProTelemetry, HubReading

__all__ = ["CLIENTS", "Canary", "PurePythonClient", "main"]

HUB_SLAVE = HUB.device.default_address
CP_SLAVE = COOLPRO.device.default_address
(_TELEMETRY,) = COOLPRO.plan("telemetry")  # one request: input registers 0..7
CP_FUNCTION, CP_ADDRESS, CP_COUNT = _TELEMETRY.function, _TELEMETRY.address, _TELEMETRY.count


#: The sweep's requests: registers 31..730 in reads of at most 125, as the
#: hub's map plans a full sweep, for every contender.
SPANS = [(r.address, r.count) for r in HUB.plan("sweep")]
#: the registers of a sweep (700: every block of every channel)
HUB_REGISTERS = sum(count for _, count in SPANS)


class Canary:
    """The per-sweep check: one register that reads 0xFFFF, one that does not."""

    def __init__(self, k_off: int, k_val: int) -> None:
        self.k_off = k_off
        self.k_val = k_val

    def check(self, raw: Sequence[int], values: Sequence[float]) -> None:
        """Raise when the sweep is not the simulated hub's."""
        self.check_reading((raw, values))

    def check_reading(self, reading: tuple[Sequence[int], Sequence[float]]) -> None:
        """:meth:`check` of a sweep as a stack returns it: (registers, values)."""
        raw, values = reading
        if len(raw) != HUB_REGISTERS or len(values) != HUB_REGISTERS:
            raise RuntimeError(f"sweep returned {len(raw)} registers, {len(values)} values")
        k, v = self.k_off, self.k_val
        if raw[k] != 0xFFFF or not math.isnan(values[k]) or raw[v] == 0xFFFF or \
                math.isnan(values[v]):
            raise RuntimeError("canary registers do not hold what the simulator serves")


# -- the contenders ---------------------------------------------------------------------


class PymbClient:
    """pymb: ``SensorHub.read_all()`` (6 requests, decoded in C, GIL released)
    and ``CoolPro.read_telemetry()``."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        from pymb import RtuClient
        from pymb.devices import CoolPro, SensorHub

        self.client = RtuClient(port, baud, timeout=timeout)
        self.client.connect()
        self.hub = SensorHub(self.client, HUB_SLAVE)
        self.reading: HubReading | None = None
        self.coolpro = CoolPro(self.client, CP_SLAVE)
        #: a telemetry read as its user makes it: the CoolProTelemetry, decoded
        #: in C, as it comes (:func:`telemetry_check` takes it so)
        self.telemetry: Callable[[], CoolProTelemetry] = self.coolpro.read_telemetry

    def sweep(self) -> tuple[Sequence[int], Sequence[float]]:
        # A poller's steady state: every sweep into the same reading, which
        # allocates nothing (the canary checks each sweep before the next).
        r = self.reading = self.hub.read_all(into=self.reading)
        return r.registers, r.values

    def close(self) -> None:
        self.client.close()


class PurePythonClient(abc.ABC):
    """Base of the stacks that return raw registers: six reads, then the
    pure-Python decode of :mod:`pymb.bench.pure`."""

    @abc.abstractmethod
    def read(self, slave: int, function: int, address: int, count: int) -> Sequence[int]:
        """The registers of one read request."""

    def sweep(self) -> tuple[Sequence[int], Sequence[float]]:
        raw: list[int] = []
        for address, count in SPANS:
            raw += self.read(HUB_SLAVE, 0x03, address, count)
        return raw, pure.decode_hub(raw)

    def telemetry(self) -> tuple[Sequence[int], Sequence[float]]:
        raw = self.read(CP_SLAVE, CP_FUNCTION, CP_ADDRESS, CP_COUNT)
        return raw, pure.decode_telemetry(raw)

    def close(self) -> None:  # noqa: B027 (a no-op by default)
        pass


class PymodbusClient(PurePythonClient):
    """pymodbus: the sync ``ModbusSerialClient`` (RTU framer), its defaults
    but for a generous timeout. It polls for the reply in sleeps of at least
    1 ms (``_recv_interval``), as its users get it."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        from pymodbus.client import ModbusSerialClient
        from pymodbus.framer import FramerType

        self.client = ModbusSerialClient(port, framer=FramerType.RTU, baudrate=baud,
                                         timeout=timeout)
        if not self.client.connect():
            raise RuntimeError(f"pymodbus cannot open {port}")

    def read(self, slave: int, function: int, address: int, count: int) -> Sequence[int]:
        if function == 0x04:
            rr = self.client.read_input_registers(address, count=count, device_id=slave)
        else:
            rr = self.client.read_holding_registers(address, count=count, device_id=slave)
        if rr.isError():
            raise RuntimeError(f"pymodbus: {rr}")
        regs: Sequence[int] = rr.registers
        return regs

    def close(self) -> None:
        self.client.close()  # type: ignore[no-untyped-call]


class MinimalmodbusClient(PurePythonClient):
    """minimalmodbus: one ``Instrument`` per device (they share the port),
    ``read_registers(address, count, functioncode)``. Its 3.5-character
    silent period (at least 1.75 ms) before each request is kept, as its
    users get it; the timeout is raised from 0.05 s."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        import minimalmodbus  # type: ignore[import-untyped]

        self.instruments: dict[int, Any] = {}
        for slave in (HUB_SLAVE, CP_SLAVE):
            inst = minimalmodbus.Instrument(port, slave)
            inst.serial.baudrate = baud
            inst.serial.timeout = timeout
            self.instruments[slave] = inst

    def read(self, slave: int, function: int, address: int, count: int) -> Sequence[int]:
        regs: list[int] = self.instruments[slave].read_registers(address, count,
                                                                 functioncode=function)
        return regs

    def close(self) -> None:
        for inst in self.instruments.values():
            inst.serial.close()


class PylibmodbusClient(PurePythonClient):
    """pylibmodbus: libmodbus through an ABI-mode cffi wrapper. Paths and
    parity go in as bytes (its ``char *`` arguments take nothing else);
    ``read_registers`` returns a new ``uint16_t[]`` each call."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        from pylibmodbus import ModbusRtu  # type: ignore[import-untyped]

        self.ctx = ModbusRtu(device=port.encode(), baud=baud, parity=b"N", data_bit=8,
                             stop_bit=1)
        self.ctx.connect()
        self.ctx.set_response_timeout(timeout)
        self.slave = -1

    def read(self, slave: int, function: int, address: int, count: int) -> Sequence[int]:
        if slave != self.slave:
            self.ctx.set_slave(slave)
            self.slave = slave
        if function == 0x04:
            regs = self.ctx.read_input_registers(address, count)
        else:
            regs = self.ctx.read_registers(address, count)
        return list(regs)

    def close(self) -> None:
        self.ctx.close()


class PyserialClient(PurePythonClient):
    """A hand-written RTU master on pyserial: build the frame, CRC in pure
    Python (table-driven), write, read exactly the expected reply length,
    check address, function, byte count and CRC."""

    def __init__(self, port: str, baud: int, timeout: float) -> None:
        import serial  # type: ignore[import-untyped]

        self.serial = serial.Serial(port, baud, timeout=timeout)
        self._formats = {n: struct.Struct(f">{n}H") for _, n in SPANS}
        self._formats[CP_COUNT] = struct.Struct(f">{CP_COUNT}H")

    def read(self, slave: int, function: int, address: int, count: int) -> Sequence[int]:
        self.serial.write(pure.read_request(slave, function, address, count))
        want = pure.response_length(count)
        rsp = self.serial.read(want)
        if len(rsp) != want:
            raise RuntimeError(f"short reply: {len(rsp)} of {want} bytes")
        crc = pure.crc16(rsp[:-2])
        if rsp[-2] != crc & 0xFF or rsp[-1] != crc >> 8:
            raise RuntimeError("reply failed its CRC check")
        if rsp[0] != slave or rsp[1] != function or rsp[2] != 2 * count:
            raise RuntimeError(f"unexpected reply header {rsp[:3].hex(' ')}")
        regs: tuple[int, ...] = self._formats[count].unpack_from(rsp, 3)
        return regs

    def close(self) -> None:
        self.serial.close()


#: contender name -> client class
CLIENTS: dict[str, Callable[[str, int, float], Any]] = {
    "pymb": PymbClient,
    "pymodbus": PymodbusClient,
    "minimalmodbus": MinimalmodbusClient,
    "pylibmodbus": PylibmodbusClient,
    "pyserial": PyserialClient,
}


# -- the loop -----------------------------------------------------------------------------


def _batch(op: Callable[[], Any], n: int, check: Check) -> str:
    """``n`` calls of ``op``, each result checked by ``check``, as ``ok CPU_NS
    WALL_NS...``. What is charged is the calls and their checks, as in the C
    program's loop (its check is inside its timed call): one clock read a
    call, a call's wall time running from the end of the one before, and no
    allocation of the loop's own between two calls."""
    clock = time.perf_counter_ns
    ends = [0] * (n + 1)
    c0 = time.process_time_ns()
    ends[0] = clock()
    for i in range(1, n + 1):
        check(op())
        ends[i] = clock()
    cpu = time.process_time_ns() - c0
    return f"ok {cpu} " + " ".join(str(ends[i] - ends[i - 1]) for i in range(1, n + 1))


#: a telemetry read's decoded values as a stack returns them: the 7 values, or
#: pymb's :class:`~pymb.devices.CoolProTelemetry` (its typed fields, decoded in C)
Telemetry = Sequence[float] | CoolProTelemetry
#: a telemetry read as a stack returns it: pymb's CoolProTelemetry alone (its
#: registers are its own), or (registers, decoded values)
TelemetryRead = CoolProTelemetry | tuple[Sequence[int], Telemetry]


def telemetry_reading(read: TelemetryRead) -> tuple[Sequence[int], Telemetry]:
    """The registers and the decoded values of a telemetry read."""
    return (read.registers, read) if isinstance(read, CoolProTelemetry) else read


def telemetry_check(read: TelemetryRead) -> None:
    """Raise unless a CoolPro telemetry read came back whole with an input voltage."""
    if isinstance(read, CoolProTelemetry):  # a poller's read, checked without a tuple
        raw: Sequence[int] = read.registers
        v = read.input_voltage_v
    else:
        raw, values = read
        v = values.input_voltage_v if isinstance(values, CoolProTelemetry) else values[0]
    if len(raw) != CP_COUNT or not v > 0:
        raise RuntimeError("telemetry reads no input voltage")


def telemetry_values(values: Telemetry) -> Sequence[float]:
    """The 7 values of a telemetry read, in the C program's order (``tverify``)."""
    if not isinstance(values, CoolProTelemetry):
        return values
    t = values
    return (t.input_voltage_v, t.input_current_a, t.output_voltage_v, t.output_current_a,
            t.temperature_c, float(t.uptime_s), float(t.status))


def err_line(e: BaseException) -> str:
    """The one-line ``err`` answer a worker gives its parent for ``e``."""
    return f"err {type(e).__name__}: {e}".replace("\n", " ")


def answer_commands(lines: Any, answer: Callable[[str, list[str], str], str]) -> None:
    """Print ``ready``, then ``answer(cmd, args, line)`` for each line until ``quit`` or EOF."""
    print("ready", flush=True)
    for line in lines:
        cmd, *rest = line.split()
        if cmd == "quit":
            break
        print(answer(cmd, rest, line), flush=True)


Check = Callable[[Any], None]  #: a check of one call's result as the stack returns it
Reading = tuple[Sequence[int], Any]  #: (registers, decoded values: a sweep's or a Telemetry)


def serve(client: Any, canary: Canary, lines: Any, out: Any,
          batch: Callable[[Any, int, Check], str] = _batch,
          call: Callable[[Any], Any] | None = None) -> None:
    """Answer commands from ``lines`` on ``out`` until ``quit`` or EOF.

    ``batch(op, n, check)`` times ``n`` calls of the client's ``op`` and ``call(op)`` makes
    one; the defaults (``call=None``: ``op()``) call a blocking client, while
    :mod:`pymb.bench.aioworker` passes ones that run an asyncio client's coroutines on its loop.
    """
    for line in lines:
        cmd, _, arg = line.strip().partition(" ")
        try:
            if cmd == "sweep":
                answer = batch(client.sweep, int(arg), canary.check_reading)
            elif cmd == "tele":
                answer = batch(client.telemetry, int(arg), telemetry_check)
            elif cmd in ("verify", "tverify"):
                op = client.sweep if cmd == "verify" else client.telemetry
                got = op() if call is None else call(op)
                if cmd == "verify":
                    canary.check_reading(got)
                    raw, values = got
                else:
                    raw, read = telemetry_reading(got)
                    values = telemetry_values(read)
                answer = "ok " + " ".join(map(str, raw)) + "\nok " + " ".join(
                    repr(float(v)) for v in values)
            elif cmd == "quit":
                return
            else:
                answer = f"err unknown command {cmd!r}"
        except Exception as e:  # reported to the parent, which skips the contender
            answer = err_line(e)
        out.write(answer + "\n")
        out.flush()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the worker process."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 6 or args[0] not in CLIENTS:
        print(f"usage: python -m pymb.bench.worker {{{','.join(CLIENTS)}}} PORT BAUD "
              "K_OFF K_VAL TIMEOUT", file=sys.stderr)
        return 2
    name, port, baud, k_off, k_val, timeout = args
    try:
        client = CLIENTS[name](port, int(baud), float(timeout))
    except Exception as e:
        print(f"err cannot open {port} with {name}: {type(e).__name__}: {e}".replace("\n", " "),
              flush=True)
        return 4
    print(f"ready {name}", flush=True)
    try:
        serve(client, Canary(int(k_off), int(k_val)), sys.stdin, sys.stdout)
    finally:
        client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
