"""The CoolPro power-supply monitor ([CP] CP-MODBUS-RTU rev 1).

Telemetry (input registers 0..7) and identity (100..107) are each one
request, decoded by pymb's C core: milliunits to volts, amps and °C, 32-bit
values low word first.
"""

from __future__ import annotations

import functools
from array import array
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import KEEP, IntFlag

from pymb import _native
from pymb.client import Client
from pymb.devices.maps import COOLPRO, COOLPRO_BAUD_RATES, COOLPRO_RESET_VALUE
from pymb.errors import InvalidArgument

__all__ = ["CoolPro", "CoolProConfig", "CoolProIdentity", "CoolProStatus", "CoolProTelemetry"]


class CoolProStatus(IntFlag, boundary=KEEP):
    """Status flags, input register 7 ([CP] "Status Flags bit field").

    Bits 7..15 are reserved: they are kept as raw bits, never dropped
    (``CoolProStatus(0x8001)`` keeps 0x8000).
    """

    SYSTEM_STARTUP = 0x0001  #: device is initialising
    DAILY_RESET = 0x0002  #: daily reset has occurred (uptime counter reset)
    INPUT_MEASUREMENT_FAULT = 0x0004  #: input measurement sensor fault
    OUTPUT_MEASUREMENT_FAULT = 0x0008  #: output measurement sensor fault
    CALIBRATION_INVALID = 0x0010  #: stored calibration data failed validation
    CALIBRATION_MISSING = 0x0020  #: no calibration data stored
    TEMPERATURE_SENSOR_FAULT = 0x0040  #: temperature sensor fault

    @property
    def reserved(self) -> int:
        """The reserved bits (7..15) as they came."""
        return int(self) & 0xFF80


_ZEROS = array("H", bytes(2 * _native.MAX_READ_REGISTERS))
_new = object.__new__


@functools.lru_cache(maxsize=1024)
def _status(raw: int) -> CoolProStatus:
    """CoolProStatus(raw), cached: flag values repeat from read to read."""
    return CoolProStatus(raw)


@dataclass(frozen=True)
class CoolProTelemetry:
    """Live telemetry, one request (input registers 0..7)."""

    input_voltage_v: float
    input_current_a: float
    output_voltage_v: float
    output_current_a: float
    temperature_c: float
    uptime_s: int
    status: CoolProStatus
    registers: array[int] = field(repr=False, compare=False)  #: raw registers 0..7


@dataclass(frozen=True)
class CoolProIdentity:
    """Device information, one request (input registers 100..107)."""

    serial_number: int
    hardware_revision: int
    firmware_version: str  #: "major.minor.patch"
    manufactured: datetime  #: UTC
    registers: array[int] = field(repr=False, compare=False)


@dataclass(frozen=True)
class CoolProConfig:
    """Configuration (holding registers 0..1). Written values are stored at
    once but take effect only after :meth:`CoolPro.reset`."""

    address: int
    baud_rate: int  #: bit/s
    baud_rate_index: int


def decode_telemetry(regs: array[int]) -> CoolProTelemetry:
    """Input registers 0..7 (an ``array('H')``) as :class:`CoolProTelemetry`,
    decoded in C, with no I/O: the one decoder of the facade, the store's
    reader and the logger."""
    # The result's fields are set directly (a frozen dataclass's __init__
    # makes a call per field): this is a CoolPro logger's hot path.
    t = _new(CoolProTelemetry)
    d = t.__dict__
    (d["input_voltage_v"], d["input_current_a"], d["output_voltage_v"],
     d["output_current_a"], d["temperature_c"], d["uptime_s"],
     status) = _native.coolpro_telemetry(regs)
    d["status"] = _status(status)
    d["registers"] = regs
    return t


def decode_identity(regs: array[int]) -> CoolProIdentity:
    """Input registers 100..107 (an ``array('H')``) as :class:`CoolProIdentity`,
    with no I/O: the one decoder of the facade and of device identification."""
    serial, hw, major, minor, patch, made = _native.coolpro_identity(regs)
    return CoolProIdentity(serial, hw, f"{major}.{minor}.{patch}",
                           datetime.fromtimestamp(made, UTC), regs)


class CoolPro:
    """The CoolPro at ``address`` (1..247, default 40) on ``client``.

    After :meth:`set_address` and :meth:`reset`, this object talks to the
    new address. A new baud rate takes effect at the reset too: reopen the
    client at that rate (it may serve other devices on the bus, so pymb does
    not change it by itself).
    """

    def __init__(self, client: Client, address: int = COOLPRO.default_address) -> None:
        if not callable(getattr(client, "read_registers_prepared", None)):
            raise InvalidArgument(f"a CoolPro needs a pymb client, got {client!r}")
        self.client = client
        self.address = self._valid_address(address)
        self._pending_address: int | None = None
        self._telemetry = COOLPRO.span("telemetry")
        self._identity = COOLPRO.span("identity")
        self._config = COOLPRO.span("config")

    @staticmethod
    def _valid_address(address: int) -> int:
        low, high = COOLPRO["address"].valid or (1, 247)
        if isinstance(address, bool) or not isinstance(address, int) or not (
            low <= address <= high
        ):
            raise InvalidArgument(f"CoolPro address must be {low}..{high}, got {address!r}")
        return address

    def _read(self, span: tuple[int, int, int]) -> array[int]:
        # The span comes from the map and the address was checked: no per-call checks.
        function, address, count = span
        regs = _ZEROS[:count]
        self.client.read_registers_prepared(function, self.address, address, regs)
        return regs

    def read_telemetry(self) -> CoolProTelemetry:
        """Voltages, currents, temperature, uptime and status flags."""
        # The hot path of a CoolPro logger: one array, one C read, one C decode.
        return decode_telemetry(self._read(self._telemetry))

    def read_identity(self) -> CoolProIdentity:
        """Serial number, hardware revision, firmware version, manufacture date."""
        return decode_identity(self._read(self._identity))

    def read_config(self) -> CoolProConfig:
        """Device address and baud rate as stored (effective after a reset)."""
        regs = self._read(self._config)
        address, index = regs[0], regs[1]
        baud = COOLPRO_BAUD_RATES[index] if index < len(COOLPRO_BAUD_RATES) else 0
        return CoolProConfig(address, baud, index)

    def set_address(self, address: int) -> None:
        """Store a new device address (1..247); it takes effect at :meth:`reset`."""
        new = self._valid_address(address)
        self.client.write_register(COOLPRO["address"].address, new, slave=self.address)
        self._pending_address = new

    def set_baud_rate(self, baud_rate: int) -> None:
        """Store a new baud rate (9600, 19200, 38400, 57600 or 115200 bit/s);
        it takes effect at :meth:`reset`."""
        if baud_rate not in COOLPRO_BAUD_RATES:
            raise InvalidArgument(
                f"CoolPro baud rate must be one of {list(COOLPRO_BAUD_RATES)}, got {baud_rate!r}"
            )
        self.client.write_register(COOLPRO["baud_rate_index"].address,
                                   COOLPRO_BAUD_RATES.index(baud_rate), slave=self.address)

    def reset(self) -> None:
        """Reset the device (write 0xAA55 to the reset register). The device
        echoes, then restarts: its uptime restarts and the startup flag is
        set for a moment; a stored address or baud rate takes effect now."""
        self.client.write_register(COOLPRO["reset"].address, COOLPRO_RESET_VALUE,
                                   slave=self.address)
        if self._pending_address is not None:
            self.address, self._pending_address = self._pending_address, None
