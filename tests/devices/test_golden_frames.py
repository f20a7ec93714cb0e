"""The facades on the wire, against the frames of the device documents: each
request the facade sends must be byte for byte the document's, CRC included,
and the document's reply must decode to the document's values. The frames are
data copied from the documents (the section named beside each); a CRC the
document leaves as ``[CRC]`` is appended by tests/peerkit.py's bitwise CRC,
written from the documents and nothing of pymb's. Nothing here reads the
shipped maps: a mistyped address or scale there fails these tests.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from peerkit import rtu
from wire_peers import RawPty

import pymb
from pymb.devices import CoolPro, SensorHub, State

# [CP] ch. 04 "CRC-16": the two frames the document gives with their CRC.
CP_READ_VIN = bytes.fromhex("28 04 00 00 00 01 36 33")
CP_VIN_REPLY = bytes.fromhex("28 04 02 5F B4 DD 71")
# [CP] ch. 02 "0x03 Read Holding Registers" and ch. 06 "configuration writes".
CP_READ_CONFIG = rtu(bytes.fromhex("28 03 00 00 00 03"))
CP_CONFIG_REPLY = rtu(bytes.fromhex("28 03 06 00 28 00 00 00 00"))
CP_WRITE_ADDRESS_42 = rtu(bytes.fromhex("28 06 00 00 00 2A"))  # the reply is its echo
CP_RESET = rtu(bytes.fromhex("28 06 00 02 AA 55"))  # the reply is its echo
# [CP] ch. 02 "0x04 Read Input Registers" (Vin, Iin, Vout, Iout), ch. 06 "READ
# TEMPERATURE" (0x64C8) and ch. 04 "32-bit values" (uptime 70000 = 0x1170, 0x0001):
# the facade reads the 8 telemetry registers in one request.
CP_READ_TELEMETRY = rtu(bytes.fromhex("28 04 00 00 00 08"))
CP_TELEMETRY_REPLY = rtu(bytes.fromhex("28 04 10 5F B4 0C B2 5D C0 0C 80 64 C8 11 70 00 01 00 00"))
# [CP] ch. 06 "READ SERIAL NUMBER" (low 0x3039, high 0x0000), in the facade's one
# request for the 8 registers of device information (offsets 100..107).
CP_READ_IDENTITY = rtu(bytes.fromhex("28 04 00 64 00 08"))
CP_IDENTITY_REPLY = rtu(bytes.fromhex("28 04 10 30 39 00 00" + " 00 00" * 6))
# [CP] ch. 05 "EXCEPTION RESPONSE": function + 0x80, code 0x02 (Illegal Data Address).
CP_TELEMETRY_EXCEPTION = rtu(bytes.fromhex("28 84 02"))

# [HUB] 2.3 "Protocol format" and 3 "Register Address Dispatch": channel 1's
# temperature at 31 (0x001F), humidity at 131 (0x0083). Appendix 1's "Read 12
# channel temperature" and "Read 12 channel humidity" show no bytes: these are
# those reads, at the hub's address 1.
HUB_READ_12_TEMPERATURES = rtu(bytes.fromhex("01 03 00 1F 00 0C"))
# 25.0 °C, -25.0 °C (bit 15: negative), 0xFFFF offline, 0.0 °C, 102.3 °C, then 7 x 20.0 °C
HUB_TEMPERATURES_REPLY = rtu(bytes.fromhex("01 03 18 00 FA 80 FA FF FF 00 00 03 FF"
                                           + " 00 C8" * 7))
HUB_READ_12_HUMIDITIES = rtu(bytes.fromhex("01 03 00 83 00 0C"))
# unit 0.1 %: 50.0 %, 0x8000 no humidity sensor, 0xFFFF offline, then 9 x 42.5 %
HUB_HUMIDITIES_REPLY = rtu(bytes.fromhex("01 03 18 01 F4 80 00 FF FF" + " 01 A9" * 9))


@contextmanager
def device(frames: dict[bytes, bytes]) -> Iterator[tuple[pymb.RtuClient, list[bytes]]]:
    """A responder that answers each request in ``frames`` with its reply
    (anything else: silence), and a client on its line."""
    with RawPty(lambda i, frame: [(0, frames[frame])] if frame in frames else []) as peer, \
            pymb.RtuClient(peer.port, 9600, timeout=0.5) as client:
        yield client, peer.requests


def test_the_documents_crc_frame_through_the_client() -> None:
    with device({CP_READ_VIN: CP_VIN_REPLY}) as (client, sent):
        assert list(client.read_input_registers(0, 1, slave=40)) == [24500]
    assert sent == [CP_READ_VIN]


def test_coolpro_telemetry_is_the_documents_frame_and_values() -> None:
    with device({CP_READ_TELEMETRY: CP_TELEMETRY_REPLY}) as (client, sent):
        t = CoolPro(client, 40).read_telemetry()
    assert sent == [CP_READ_TELEMETRY]
    assert (t.input_voltage_v, t.input_current_a, t.output_voltage_v, t.output_current_a,
            t.temperature_c, t.uptime_s, int(t.status)) == (24.5, 3.25, 24.0, 3.2, 25.8, 70000, 0)


def test_coolpro_identity_is_the_documents_frame_and_serial() -> None:
    with device({CP_READ_IDENTITY: CP_IDENTITY_REPLY}) as (client, sent):
        assert CoolPro(client, 40).read_identity().serial_number == 12345
    assert sent == [CP_READ_IDENTITY]


def test_coolpro_configuration_reads_and_writes_are_the_documents_frames() -> None:
    frames = {CP_READ_CONFIG: CP_CONFIG_REPLY, CP_WRITE_ADDRESS_42: CP_WRITE_ADDRESS_42,
              CP_RESET: CP_RESET}
    with device(frames) as (client, sent):
        cp = CoolPro(client, 40)
        config = cp.read_config()
        cp.set_address(42)
        cp.reset()
    assert sent == [CP_READ_CONFIG, CP_WRITE_ADDRESS_42, CP_RESET]
    assert (config.address, config.baud_rate) == (40, 9600)
    assert cp.address == 42


def test_coolpro_exception_response_is_the_documents_code() -> None:
    with device({CP_READ_TELEMETRY: CP_TELEMETRY_EXCEPTION}) as (client, _), \
            pytest.raises(pymb.IllegalDataAddress):
        CoolPro(client, 40).read_telemetry()


def test_hub_temperatures_are_the_documents_frame_and_encoding() -> None:
    with device({HUB_READ_12_TEMPERATURES: HUB_TEMPERATURES_REPLY}) as (client, sent):
        r = SensorHub(client, 1).read(["temperature_c"], range(1, 13))
    assert sent == [HUB_READ_12_TEMPERATURES]
    values = list(r.temperature_c[:12])
    assert values[:2] + values[3:] == [25.0, -25.0, 0.0, 102.3] + [20.0] * 7
    assert r.state("temperature_c", 3) is State.OFFLINE


def test_hub_humidities_are_the_documents_frame_and_markers() -> None:
    with device({HUB_READ_12_HUMIDITIES: HUB_HUMIDITIES_REPLY}) as (client, sent):
        r = SensorHub(client, 1, humidity_unit=0.1).read(["humidity_pct"], range(1, 13))
    assert sent == [HUB_READ_12_HUMIDITIES]
    assert r.humidity_pct[0] == 50.0
    assert [r.state("humidity_pct", ch) for ch in (1, 2, 3)] == [
        State.VALUE, State.NO_SENSOR, State.OFFLINE]
    assert list(r.humidity_pct[3:12]) == [42.5] * 9
