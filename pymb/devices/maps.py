"""The two devices' register maps, as the facades and simulators see them.

The rows come from the shipped map files (``pymb/maps/builtin/coolpro.toml``
and ``hub.toml``, read through :func:`pymb.maps.builtin`), the one place a
register number appears; this module only turns their points into the
facades' ``Register`` and ``Block`` rows and keeps the device facts the map
format has no field for (baud rate, function codes, exception texts). The
facades, the simulators, the CLI's output and the register tables of
docs/registers.md are derived from these rows.

Sources:
  [CP]    CoolPro Modbus RTU Communications Protocol, CP-MODBUS-RTU rev 1
  [HUB]   RS485 Modbus Communication Protocol V1.5 (100-channel sensor hub)
  [NOTES] docs/device-notes.md, the project's reading of both
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import StrEnum

from pymb import maps
from pymb._native import MAX_READ_REGISTERS
from pymb.devices.coolpro import COOLPRO_BAUD_RATES
from pymb.devices.hubreading import HUB_FIRMWARE_PROFILES
from pymb.errors import InvalidArgument

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
    max_read: int = MAX_READ_REGISTERS  #: registers per read, [MB-AP] 6.3, 6.4

    def __getitem__(self, name: str) -> Register:
        for r in self.registers:
            if r.name == name:
                return r
        raise InvalidArgument(f"no register {name!r}; use one of "
                              f"{', '.join(r.name for r in self.registers)}")

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

_CP_MAP = maps.builtin("coolpro")
_FUNCTION = {"holding": 0x03, "input": 0x04}

#: [CP] "Frame timing": the fixed ~8 ms inter-frame gap; the CoolPro answers no sooner
#: than this after a request ends ([NOTES] "timing"): the map's turnaround.
COOLPRO_GAP_S = _CP_MAP.timing.turnaround
#: [CP] "Reset Command": write this to holding register 2 (the only value its
#: ``valid`` range allows).
COOLPRO_RESET_VALUE = int((_CP_MAP.points["reset"].valid or (0, 0))[0])

#: [CP] "Status Flags bit field": what each flag of the map's ``status`` means.
_STATUS_MEANING = {
    "SYSTEM_STARTUP": "Device is initialising (cleared once startup completes)",
    "DAILY_RESET": "Daily reset has occurred (uptime counter reset)",
    "INPUT_MEASUREMENT_FAULT": "Fault communicating with the input measurement sensor",
    "OUTPUT_MEASUREMENT_FAULT": "Fault communicating with the output measurement sensor",
    "CALIBRATION_INVALID": "Stored calibration data failed validation",
    "CALIBRATION_MISSING": "No calibration data stored",
    "TEMPERATURE_SENSOR_FAULT": "Fault communicating with the temperature sensor",
}
#: bit -> (name, description), the names from the map's ``flags``. Bits 7..15
#: are reserved and reported as raw bits.
COOLPRO_STATUS_BITS: dict[int, tuple[str, str]] = {
    bit: (name, _STATUS_MEANING.get(name, ""))
    for bit, name in sorted(_CP_MAP.points["status"].flags.items())
}


def _register(p: maps.Point) -> Register:
    if p.type == "u32" and p.order == "CDAB":
        kind = Type.U32_LE_WORDS
    elif p.flags:
        kind = Type.BITS
    else:
        kind = Type(p.type)
    valid = None if p.valid is None else (int(p.valid[0]), int(p.valid[1]))
    return Register(p.name, _FUNCTION[p.table], p.address, kind, _scale(p), p.unit,
                    Access(p.access), p.description, valid, p.ref, p.group or "")


def _scale(p: maps.Point) -> float:
    """The point's scale, 1 for none (an int where it is whole, as the rows had it)."""
    s = 1.0 if p.scale is None else p.scale
    return int(s) if s.is_integer() else s


COOLPRO = DeviceMap(
    name=_CP_MAP.id,
    default_address=_CP_MAP.device.default_address,
    default_baud=9600,  # [CP] ch. 02: 9600 8N1 out of the box
    function_codes=(0x03, 0x04, 0x06),
    exception_codes={
        0x01: "Illegal Function: function code not supported",
        0x02: "Illegal Data Address: register address invalid",
        0x03: "Illegal Data Value: value out of range",
        0x04: "Slave Device Failure: device cannot process the request",
    },
    registers=tuple(_register(p) for p in _CP_MAP.points.values()),
    addresses=_CP_MAP.device.addresses,
    max_read=_CP_MAP.limits.max_registers,
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
        raise InvalidArgument(
            f"unknown block {name!r}; use one of {', '.join(b.name for b in self.blocks)}")


_HUB_MAP = maps.builtin("hub")
_HUB_TYPES = {"sm16": Type.SIGN_MAGNITUDE, "u16": Type.U16, "i16": Type.I16}


def _firmware(text: str) -> tuple[int, int]:
    major, _, minor = text.partition(".")
    return (int(major), int(minor)) if text else (0, 0)


def _blocks() -> tuple[Block, ...]:
    """One Block per block of the map; a block with a variant per option value
    (the humidity's markers per unit) lists every variant's markers, in the
    order of the option's values."""
    spec = _HUB_MAP.device
    out: list[Block] = []
    for p in _HUB_MAP.points.values():
        markers = [(raw, state.replace("_", " ")) for raw, state in p.markers.items()]
        scales: tuple[float, ...] = ()
        for option in p.when:
            values = spec.option_values.get(option, ())
            scales = tuple(values)
            markers = [(raw, name) for raw, name in markers if all(
                raw in _HUB_MAP.configure({option: v}).points[p.name].markers for v in values)]
            for v in values:
                variant = _HUB_MAP.configure({option: v}).points[p.name]
                markers += [(raw, f"{state.replace('_', ' ')} ({v:g} {p.unit} unit)")
                            for raw, state in variant.markers.items()
                            if raw not in dict(markers)]
        out.append(Block(len(out), p.name, p.address, _HUB_TYPES[p.type], _scale(p),
                         p.unit, p.description,
                         _firmware(p.min_firmware), tuple(markers), p.ref,
                         per_channel_scales=scales))
    return tuple(out)


HUB = HubMap(
    name=_HUB_MAP.id,
    default_address=_HUB_MAP.device.default_address,
    default_baud=9600,  # [HUB] 2.1
    channels=int(_HUB_MAP.options["channels"]),
    function_codes=(0x03,),
    exception_codes={
        0x01: "Invalid protocol type",
        0x02: "Invalid register address (include invalid length of data)",
        0x03: "Invalid written data",
        0x04: "Device is busy",
    },
    max_frame=255,
    max_read=_HUB_MAP.limits.max_registers,
    response_time=0.5,  # [HUB] 2.1: the hub answers within 500 ms
    blocks=_blocks(),
    addresses=_HUB_MAP.device.addresses,
)



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
