"""The two devices' register maps, as data.

This is the only place a register number appears. The facades, the
simulators, the CLI's output and the register tables of docs/registers.md are derived
from these rows (or tested against them), after SunSpec's models: each point
is a row with its name, function code, address, type, scale, unit, markers,
access and the document's description.

Sources:
  [CP]    CoolPro Modbus RTU Communications Protocol, CP-MODBUS-RTU rev 1
  [HUB]   RS485 Modbus Communication Protocol V1.5 (100-channel sensor hub)
  [NOTES] docs/device-notes.md, the project's reading of both
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import StrEnum

__all__ = [
    "COOLPRO",
    "COOLPRO_BAUD_RATES",
    "COOLPRO_GAP_S",
    "COOLPRO_RESET_VALUE",
    "COOLPRO_STATUS_BITS",
    "HUB",
    "HUB_FIRMWARE_PROFILES",
    "Access",
    "Block",
    "DeviceMap",
    "HubMap",
    "Register",
    "Type",
    "markdown_tables",
]


class Type(StrEnum):
    """How a point's raw registers become a value."""

    U16 = "u16"  #: unsigned 16-bit
    I16 = "i16"  #: two's complement 16-bit
    U32_LE_WORDS = "u32_lo_hi"  #: 32-bit, low word first, each word big-endian
    SIGN_MAGNITUDE = "sign_magnitude"  #: bit 15 sign, bits 14..0 magnitude
    BITS = "bits"  #: a bit field


class Access(StrEnum):
    """Whether a point is read, written, or both."""

    R = "r"
    RW = "rw"
    W = "w"


@dataclass(frozen=True)
class Register:
    """One point of a device map (one or two registers)."""

    name: str  #: Python attribute name, unit suffixed (``input_voltage_v``)
    function: int  #: function code that reads it (0x03 holding, 0x04 input)
    address: int  #: on-wire PDU address of its first register
    type: Type
    scale: float = 1.0  #: engineering value = raw * scale
    unit: str = ""
    access: Access = Access.R
    description: str = ""
    valid: tuple[int, int] | None = None  #: accepted raw range for writes
    ref: str = ""  #: where the document defines it
    group: str = ""  #: which one-request read it belongs to

    @property
    def count(self) -> int:
        """Registers it spans."""
        return 2 if self.type is Type.U32_LE_WORDS else 1

    @property
    def integral(self) -> bool:
        """True when the value is a count or a bit field (no scale): an integer."""
        return self.scale == 1


@dataclass(frozen=True)
class DeviceMap:
    """A device's points, in address order per function code."""

    name: str
    default_address: int
    default_baud: int
    registers: tuple[Register, ...]
    function_codes: tuple[int, ...]
    exception_codes: dict[int, str] = field(default_factory=dict)
    addresses: tuple[int, int] = (1, 247)  #: device addresses it can be set to
    max_read: int = 125  #: registers per read, [MB-AP] 6.3, 6.4

    def __getitem__(self, name: str) -> Register:
        for r in self.registers:
            if r.name == name:
                return r
        raise KeyError(name)

    def group(self, group: str) -> tuple[Register, ...]:
        """The points read together in one request, in address order."""
        return tuple(r for r in self.registers if r.group == group)

    def span(self, group: str) -> tuple[int, int, int]:
        """(function, first address, count) of one group's request."""
        regs = self.group(group)
        first = regs[0].address
        last = max(r.address + r.count for r in regs)
        return regs[0].function, first, last - first


# ---------------------------------------------------------------------------
# CoolPro

#: [CP] "Baud Rate Index": holding register 1 holds the index into this tuple.
COOLPRO_BAUD_RATES = (9600, 19200, 38400, 57600, 115200)
#: [CP] "Reset Command": write this to holding register 2.
#: [CP] "Frame timing": the fixed ~8 ms inter-frame gap; the CoolPro answers no sooner
#: than this after a request ends ([NOTES] "timing").
COOLPRO_GAP_S = 0.008
COOLPRO_RESET_VALUE = 0xAA55

#: [CP] "Status Flags bit field": bit -> (name, description). Bits 7..15 are
#: reserved and reported as raw bits.
COOLPRO_STATUS_BITS: dict[int, tuple[str, str]] = {
    0: ("SYSTEM_STARTUP", "Device is initialising (cleared once startup completes)"),
    1: ("DAILY_RESET", "Daily reset has occurred (uptime counter reset)"),
    2: ("INPUT_MEASUREMENT_FAULT", "Fault communicating with the input measurement sensor"),
    3: ("OUTPUT_MEASUREMENT_FAULT", "Fault communicating with the output measurement sensor"),
    4: ("CALIBRATION_INVALID", "Stored calibration data failed validation"),
    5: ("CALIBRATION_MISSING", "No calibration data stored"),
    6: ("TEMPERATURE_SENSOR_FAULT", "Fault communicating with the temperature sensor"),
}

_H, _I = 0x03, 0x04
_CP = "[CP] ch. 03"

COOLPRO = DeviceMap(
    name="coolpro",
    default_address=40,
    default_baud=9600,
    function_codes=(0x03, 0x04, 0x06),
    exception_codes={
        0x01: "Illegal Function: function code not supported",
        0x02: "Illegal Data Address: register address invalid",
        0x03: "Illegal Data Value: value out of range",
        0x04: "Slave Device Failure: device cannot process the request",
    },
    registers=(
        # Holding registers (FC 0x03 read, 0x06 write): configuration.
        Register("address", _H, 0, Type.U16, access=Access.RW, valid=(1, 247),
                 description="Device Address; takes effect after reset",
                 ref=f"{_CP}, 40001", group="config"),
        Register("baud_rate_index", _H, 1, Type.U16, access=Access.RW, valid=(0, 4),
                 description="Baud Rate Index: 0 = 9600, 1 = 19200, 2 = 38400, 3 = 57600, "
                 "4 = 115200; takes effect after reset",
                 ref=f"{_CP}, 40002", group="config"),
        Register("reset", _H, 2, Type.U16, access=Access.RW,
                 valid=(COOLPRO_RESET_VALUE, COOLPRO_RESET_VALUE),
                 description="Reset Command: write 0xAA55 to trigger a reset; always reads 0",
                 ref=f"{_CP}, 40003", group="config"),
        # Input registers 0..7 (FC 0x04): live telemetry, milliunits.
        Register("input_voltage_v", _I, 0, Type.U16, 0.001, "V",
                 description="Input Voltage (mV)", ref=f"{_CP}, 30001", group="telemetry"),
        Register("input_current_a", _I, 1, Type.U16, 0.001, "A",
                 description="Input Current (mA)", ref=f"{_CP}, 30002", group="telemetry"),
        Register("output_voltage_v", _I, 2, Type.U16, 0.001, "V",
                 description="Output Voltage (mV)", ref=f"{_CP}, 30003", group="telemetry"),
        Register("output_current_a", _I, 3, Type.U16, 0.001, "A",
                 description="Output Current (mA)", ref=f"{_CP}, 30004", group="telemetry"),
        Register("temperature_c", _I, 4, Type.U16, 0.001, "°C",
                 description="Temperature (m°C); cannot be negative, tops out at 65.535 °C",
                 ref=f"{_CP}, 30005", group="telemetry"),
        Register("uptime_s", _I, 5, Type.U32_LE_WORDS, 1, "s",
                 description="Uptime, low word at 30006, high word at 30007",
                 ref=f"{_CP}, 30006-30007", group="telemetry"),
        Register("status", _I, 7, Type.BITS,
                 description="Status Flags bit field; bits 7..15 reserved",
                 ref=f"{_CP}, 30008", group="telemetry"),
        # Input registers 100..107 (FC 0x04): device information.
        Register("serial_number", _I, 100, Type.U32_LE_WORDS,
                 description="Serial Number, low word at 30101, high word at 30102",
                 ref=f"{_CP}, 30101-30102", group="identity"),
        Register("hardware_revision", _I, 102, Type.U16,
                 description="Hardware Revision", ref=f"{_CP}, 30103", group="identity"),
        Register("firmware_major", _I, 103, Type.U16,
                 description="Firmware Major Version", ref=f"{_CP}, 30104", group="identity"),
        Register("firmware_minor", _I, 104, Type.U16,
                 description="Firmware Minor Version", ref=f"{_CP}, 30105", group="identity"),
        Register("firmware_patch", _I, 105, Type.U16,
                 description="Firmware Patch Version", ref=f"{_CP}, 30106", group="identity"),
        Register("manufactured", _I, 106, Type.U32_LE_WORDS, 1, "s",
                 description="Manufacture Date, Unix time, low word at 30107, high at 30108",
                 ref=f"{_CP}, 30107-30108", group="identity"),
    ),
)


# ---------------------------------------------------------------------------
# Sensor hub


@dataclass(frozen=True)
class Block:
    """A hub block: one register per channel, channel 1 at ``first``."""

    index: int  #: block number, 0..6, in address order
    name: str  #: attribute name of the decoded sequence
    first: int  #: on-wire address of channel 1
    type: Type
    scale: float
    unit: str
    description: str
    min_firmware: tuple[int, int] = (0, 0)  #: first firmware that has it
    markers: tuple[tuple[int, str], ...] = ((0xFFFF, "offline"),)
    ref: str = "[HUB] 3"
    per_channel_scales: tuple[float, ...] = ()  #: scales a channel's configuration picks

    def address(self, channel: int) -> int:
        """On-wire address of ``channel`` (1-based)."""
        return self.first + channel - 1


@dataclass(frozen=True)
class HubMap:
    """The sensor hub's register layout."""

    name: str
    default_address: int
    default_baud: int
    channels: int
    blocks: tuple[Block, ...]
    function_codes: tuple[int, ...]
    exception_codes: dict[int, str]
    max_frame: int  #: bytes; [HUB] 2.1
    max_read: int  #: registers per request that fit the frame
    response_time: float  #: seconds the hub may take to answer, [HUB] 2.1
    addresses: tuple[int, int] = (1, 255)  #: [HUB] 2.3.1, [NOTES]: 0 is broadcast

    @property
    def first(self) -> int:
        """First register of the sweep (channel 1 temperature)."""
        return self.blocks[0].first

    @property
    def count(self) -> int:
        """Registers in the sweep (700)."""
        return self.channels * len(self.blocks)

    def __iter__(self) -> Iterator[Block]:
        return iter(self.blocks)

    def block(self, name: str) -> Block:
        """A block by its attribute name."""
        for b in self.blocks:
            if b.name == name:
                return b
        raise KeyError(name)


_TEMP_DOC = ("bit 15 sign (1 = negative), bits 14..0 magnitude in 0.1 °C; "
             "0xFFFF offline / no temperature")

HUB = HubMap(
    name="hub",
    default_address=1,
    default_baud=9600,
    channels=100,
    function_codes=(0x03,),
    exception_codes={
        0x01: "Invalid protocol type",
        0x02: "Invalid register address (include invalid length of data)",
        0x03: "Invalid written data",
        0x04: "Device is busy",
    },
    max_frame=255,
    max_read=125,
    response_time=0.5,
    blocks=(
        Block(0, "temperature_c", 31, Type.SIGN_MAGNITUDE, 0.1, "°C",
              f"Channel temperature: {_TEMP_DOC}"),
        Block(1, "humidity_pct", 131, Type.U16, 0.1, "%",
              "Channel humidity, 1 % or 0.1 % by sensor type (configuration, per channel); "
              "0xFFFF offline; 0x00FF no humidity (1 % unit); 0x8000 no humidity (0.1 % unit)",
              markers=((0xFFFF, "offline"), (0x00FF, "no sensor (1 % unit)"),
                       (0x8000, "no sensor (0.1 % unit)")),
              per_channel_scales=(1, 0.1)),
        Block(2, "pressure_temperature_c", 231, Type.SIGN_MAGNITUDE, 0.1, "°C",
              f"Pressure sensor temperature: {_TEMP_DOC}"),
        Block(3, "pressure_kpa", 331, Type.U16, 1, "kPa",
              "Pressure sensor pressure, kPa unsigned; 0xFFFF offline / no pressure"),
        Block(4, "voltage_mv", 431, Type.U16, 1, "mV",
              "Channel voltage, mV unsigned; 0xFFFF offline (firmware V2.19 and above)",
              min_firmware=(2, 19)),
        Block(5, "rssi_dbm", 531, Type.I16, 1, "dBm",
              "Channel RSSI, dBm signed 16-bit; 0xFFFF offline (firmware V2.19 and above)",
              min_firmware=(2, 19)),
        Block(6, "temperature2_c", 631, Type.SIGN_MAGNITUDE, 0.1, "°C",
              f"Second temperature: {_TEMP_DOC} (firmware V2.23 and above)",
              min_firmware=(2, 23)),
    ),
)

#: Firmware profiles of [HUB] / [NOTES]: (version, channels, blocks present).
#: V1.07 and below: 50 channels of temperature and humidity only.
HUB_FIRMWARE_PROFILES: dict[str, tuple[int, tuple[str, ...]]] = {
    "1.07": (50, ("temperature_c", "humidity_pct")),
    "2.18": (100, ("temperature_c", "humidity_pct", "pressure_temperature_c",
                   "pressure_kpa")),
    "2.22": (100, ("temperature_c", "humidity_pct", "pressure_temperature_c",
                   "pressure_kpa", "voltage_mv", "rssi_dbm")),
    "2.23": (100, tuple(b.name for b in HUB.blocks)),
}


def markdown_tables() -> str:
    """The register tables of docs/registers.md, rendered from the maps above."""
    lines = [
        "#### CoolPro (default address 40, 9600 8N1)",
        "",
        "| name | FC | address | type | scale | unit | access | description |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in COOLPRO.registers:
        addr = str(r.address) if r.count == 1 else f"{r.address}-{r.address + 1}"
        valid = f" (valid {r.valid[0]}..{r.valid[1]})" if r.valid and r.valid[0] != r.valid[1] \
            else ""
        lines.append(f"| `{r.name}` | 0x{r.function:02X} | {addr} | {r.type.value} | "
                     f"{r.scale:g} | {r.unit} | {r.access.value} | {r.description}{valid} |")
    lines += [
        "",
        "Status bits (input register 7): " + ", ".join(
            f"{bit} `{name}`" for bit, (name, _) in COOLPRO_STATUS_BITS.items())
        + "; bits 7..15 reserved, kept as raw bits.",
        "",
        f"#### Sensor hub (default address {HUB.default_address}, addresses 1..255, FC 0x03 only,"
        f" {HUB.channels} channels)",
        "",
        "| quantity | registers | type | scale | unit | markers | firmware |",
        "|---|---|---|---|---|---|---|",
    ]
    for b in HUB.blocks:
        markers = ", ".join(f"0x{m:04X} {what}" for m, what in b.markers)
        fw = "all" if b.min_firmware == (0, 0) else f"≥ V{b.min_firmware[0]}.{b.min_firmware[1]}"
        scale = (" or ".join(f"{x:g}" for x in b.per_channel_scales) + " (per channel)"
                 if b.per_channel_scales else f"{b.scale:g}")
        lines.append(f"| `{b.name}` | {b.first}..{b.first + HUB.channels - 1} | {b.type.value} | "
                     f"{scale} | {b.unit} | {markers} | {fw} |")
    lines += ["", "Firmware ≤ V1.07: 50 channels of temperature and humidity only."]
    return "\n".join(lines)
