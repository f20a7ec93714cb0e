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
from pymb.devices.coolpro import IDENTITY_REQUEST, decode_identity
from pymb.devices.hubreading import BLOCKS, CHANNELS, HUB_FIRMWARE_PROFILES
from pymb.errors import (
    DeviceException,
    GatewayPathUnavailable,
    GatewayTargetFailed,
    ModbusConnectionError,
    ModbusError,
    ModbusTimeout,
)
from pymb.wire import registers_from_wire

__all__ = ["FOUND_NAMES", "WANTED_NAMES", "Answer", "Identity", "client_asker", "identify",
           "mismatch"]

#: (reply data after the function code) | DeviceException code (int) | None (silence)
Answer = bytes | int | None
Ask = Callable[[int, int, bytes], Answer]

_FC_HOLDING = FunctionCode.READ_HOLDING_REGISTERS

#: how a phrase names a device of each kind identification knows: read
#: (``wanted``), and found answering (:attr:`Identity.device`)
WANTED_NAMES = {"coolpro": "a CoolPro", "hub": "a hub"}
FOUND_NAMES = {"coolpro": "a CoolPro", "hub": "a sensor hub"}


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
        return f"{FOUND_NAMES.get(self.device, 'an unknown device')} ({self.detail})"



def client_asker(client: Client) -> Ask:
    """``ask`` over a client: exceptions become their code, a timeout None.
    Exceptions 0x0A and 0x0B are a gateway's, not the device's (no path to
    it, no answer from it): None, as no answer is."""

    def ask(address: int, function: int, data: bytes) -> Answer:
        try:
            return client.raw_request(function, data, slave=address)
        except (GatewayPathUnavailable, GatewayTargetFailed):
            return None
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
    fc, first, count = IDENTITY_REQUEST
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
    first_hub = BLOCKS[0].address
    hub = _read(ask, address, _FC_HOLDING, first_hub, 1)
    if hub is None:
        return None if reply is None else Identity(
            address, "unknown", "answers FC 0x04 with exception 01 and is silent to FC 0x03")
    if isinstance(hub, int):
        return Identity(address, "unknown", f"answers FC 0x04 with exception 01 and FC 0x03 "
                        f"at {first_hub} with exception {hub:02X}")
    # A hub: how many channels, which blocks, and so which firmware profile.
    ch51 = _read(ask, address, _FC_HOLDING, first_hub + 50, 1)
    profiles = _hub_profiles()
    if ch51 == 2:  # no channel 51: the profile with the fewest channels
        at = min(range(len(profiles)), key=lambda k: profiles[k][1])
    else:
        # each later profile adds blocks: probe the first block each adds
        full = [k for k, p in enumerate(profiles) if p[1] == CHANNELS]
        at = full[0]
        for k in full[1:]:
            added = [b for b in BLOCKS if b.name in profiles[k][2]
                     and b.name not in profiles[at][2]]
            if not added or not isinstance(_read(ask, address, _FC_HOLDING, added[0].address, 1),
                                           bytes):
                break
            at = k
    _, channels, blocks = profiles[at]
    return Identity(address, "hub", f"{channels} channels, firmware {_firmware_range(at)}",
                    channels, tuple(b.name for b in BLOCKS if b.name in blocks))


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(x) for x in text.split("."))


def _hub_profiles() -> list[tuple[str, int, frozenset[str]]]:
    """HUB_FIRMWARE_PROFILES in version order: (the last version of each, its
    channels, its blocks); a profile covers the versions above the one before."""
    return sorted(((v, ch, frozenset(b)) for v, (ch, b) in HUB_FIRMWARE_PROFILES.items()),
                  key=lambda p: _version(p[0]))


def _firmware_range(i: int) -> str:
    """The firmware versions profile ``i`` covers, in words."""
    profiles = _hub_profiles()
    last = profiles[i][0]
    if i == 0:
        return f"V{last} or below"
    major, _, minor = profiles[i - 1][0].partition(".")
    first = f"{major}.{int(minor) + 1:0{len(minor)}d}"  # 1.07 -> 1.08, 2.18 -> 2.19
    return f"V{first} or above" if i == len(profiles) - 1 else f"V{first}..V{last}"


def mismatch(found: Identity | None, wanted: str, address: int, channels: int) -> str:
    """Why a read of ``wanted`` (``coolpro``/``hub`` with ``channels``, or
    another map's id) at ``address`` got no value, in one phrase."""
    name = WANTED_NAMES.get(wanted)
    if name is None:  # another map's device (backoff = true): it refused every point
        if found is None:
            return f"address {address} refused every point of the {wanted} map"
        name = wanted
    if found is None:
        return f"nothing answers at address {address}"
    like = FOUND_NAMES.get(found.device, "an unknown device")
    if found.device != wanted:
        return f"address {address} answers like {like}, not {name} ({found.detail})"
    if found.channels is not None and found.channels < channels:
        firmware = found.detail.split(", ", 1)[-1]
        return (f"address {address} answers like {like} with {found.channels} channels "
                f"({firmware}), not {channels}: read it as {wanted}:{address},"
                f"channels={found.channels}")
    return f"address {address} answers like {name} but supplied no value ({found.detail})"
