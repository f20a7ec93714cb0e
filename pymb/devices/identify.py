"""What answers at an address: a CoolPro, a sensor hub (and how many
channels and which blocks), something else, or nothing.

Used by ``pymb scan`` to name what it found and by ``pymb read`` / the
logger to say what answered when a read got no value at all ("address 40
answers like a CoolPro, not a hub"). The questions are asked through an
``ask(address, function, data)`` callable, so the same logic runs over a
client (:func:`client_asker`) or over ``pymb scan``'s raw line, which
attributes every reply to the address it names.

The probes, from the two documents:

- FC 0x04, input registers 100..107 ([CP] device information): a CoolPro
  answers with its identity; the hub answers exception 01 ([HUB] 2.3.2.3:
  it only reads with FC 0x03).
- FC 0x03, register 31 (channel 1 temperature): the hub answers; the
  CoolPro answers exception 02 (its holding registers are 0..2).
- FC 0x03, register 81 (channel 51 temperature): exception 02 on firmware
  V1.07 and below (50 channels); FC 0x03 at the first register of the
  voltage and second-temperature blocks: present from V2.19 and V2.23.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from pymb._native import FunctionCode
from pymb.client import Client
from pymb.devices.coolpro import decode_identity
from pymb.devices.maps import COOLPRO, HUB
from pymb.errors import DeviceException, ModbusConnectionError, ModbusError, ModbusTimeout
from pymb.wire import registers_from_wire

__all__ = ["Answer", "Identity", "client_asker", "identify", "mismatch"]

#: (reply data after the function code) | DeviceException code (int) | None (silence)
Answer = bytes | int | None
Ask = Callable[[int, int, bytes], Answer]

_FC_HOLDING = FunctionCode.READ_HOLDING_REGISTERS
_FC_INPUT = FunctionCode.READ_INPUT_REGISTERS


@dataclass(frozen=True)
class Identity:
    """What answered at one address."""

    address: int
    device: str  #: "coolpro", "hub" or "unknown"
    detail: str  #: serial and firmware, channels and blocks, or what the reply was
    channels: int | None = None  #: hub: 50 or 100
    blocks: tuple[str, ...] = ()  #: hub: the blocks its firmware has

    def describe(self) -> str:
        """``a CoolPro (serial 12345, firmware 1.0.0)``, ``a sensor hub ...``."""
        what = {"coolpro": "a CoolPro", "hub": "a sensor hub"}.get(self.device,
                                                                   "an unknown device")
        return f"{what} ({self.detail})"


def client_asker(client: Client) -> Ask:
    """``ask`` over a client: exceptions become their code, a timeout None."""

    def ask(address: int, function: int, data: bytes) -> Answer:
        try:
            return client.raw_request(function, data, slave=address)
        except DeviceException as e:
            return int(e.code or 0)
        except ModbusConnectionError:
            raise
        except ModbusTimeout:
            return None
        except ModbusError:
            return None  # garbled: as good as no answer for naming a device

    return ask


def _read(ask: Ask, address: int, function: int, first: int, count: int) -> Answer:
    return ask(address, function, struct.pack(">HH", first, count))


def identify(ask: Ask, address: int) -> Identity | None:
    """Ask the questions above; None when nothing answers at all."""
    fc, first, count = COOLPRO.span("identity")
    reply = _read(ask, address, fc, first, count) if address <= 247 else 1
    if isinstance(reply, bytes):
        if len(reply) == 1 + 2 * count and reply[0] == 2 * count:
            i = decode_identity(registers_from_wire(reply[1:]))
            return Identity(address, "coolpro", f"serial {i.serial_number}, firmware "
                            f"{i.firmware_version}, hardware rev {i.hardware_revision}, "
                            f"made {i.manufactured.date().isoformat()}")
        return Identity(address, "unknown", f"a malformed reply to FC 0x04 at {first}")
    if reply is None:
        # Silent to FC 0x04: a hub always answers it (exception 01); try FC 0x03
        # anyway, once, in case a device ignores functions it lacks.
        pass
    elif reply != 1:
        return Identity(address, "unknown",
                        f"answers FC 0x04 at {first} with exception {reply:02X}")
    first_hub = HUB.first
    hub = _read(ask, address, _FC_HOLDING, first_hub, 1)
    if hub is None:
        return None if reply is None else Identity(
            address, "unknown", "answers FC 0x04 with exception 01 and is silent to FC 0x03")
    if isinstance(hub, int):
        return Identity(address, "unknown", f"answers FC 0x04 with exception 01 and FC 0x03 "
                        f"at {first_hub} with exception {hub:02X}")
    # A hub: how many channels, which blocks.
    ch51 = _read(ask, address, _FC_HOLDING, HUB.blocks[0].address(51), 1)
    channels = 50 if ch51 == 2 else HUB.channels
    blocks = ["temperature_c", "humidity_pct"]
    if channels == HUB.channels:
        for name in ("pressure_kpa", "voltage_mv", "temperature2_c"):
            b = HUB.block(name)
            if not isinstance(_read(ask, address, _FC_HOLDING, b.first, 1), bytes):
                break
            blocks += {"pressure_kpa": ["pressure_temperature_c", "pressure_kpa"],
                       "voltage_mv": ["voltage_mv", "rssi_dbm"],
                       "temperature2_c": ["temperature2_c"]}[name]
    firmware = ("V1.07 or below" if channels == 50 else
                "V2.23 or above" if "temperature2_c" in blocks else
                "V2.19..V2.22" if "voltage_mv" in blocks else "below V2.19")
    return Identity(address, "hub", f"{channels} channels, firmware {firmware}",
                    channels, tuple(b for b in (x.name for x in HUB.blocks) if b in blocks))


def mismatch(found: Identity | None, wanted: str, address: int, channels: int) -> str:
    """Why a read of ``wanted`` (``coolpro``/``hub`` with ``channels``) at
    ``address`` got no value, in one phrase."""
    name = {"coolpro": "a CoolPro", "hub": "a hub"}[wanted]
    if found is None:
        return f"nothing answers at address {address}"
    if found.device != wanted:
        like = {"coolpro": "a CoolPro", "hub": "a sensor hub"}.get(found.device,
                                                                  "an unknown device")
        return f"address {address} answers like {like}, not {name} ({found.detail})"
    if wanted == "hub" and found.channels is not None and found.channels < channels:
        firmware = found.detail.split(", ", 1)[-1]
        return (f"address {address} answers like a sensor hub with {found.channels} channels "
                f"({firmware}), not {channels}: read it as hub:{address},"
                f"channels={found.channels}")
    return f"address {address} answers like {name} but supplied no value ({found.detail})"
