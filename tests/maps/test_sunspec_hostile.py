"""SunSpec discovery against hostile devices written from the SunSpec
specification, not from pymb: a Modbus TCP server on 127.0.0.1
(tests/hostile_gateway.py) holding a register image pysunspec2 built, that
refuses some registers (exception 02), stays silent at others, or stops its
chain early; read through the public API and the ``pymb`` command."""

from __future__ import annotations

import json
from collections.abc import Collection, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from conftest import run_pymb
from hostile_gateway import Hostile, Request
from peerkit import mbap, registers
from peers import PtyPeer
from sunspec_peer import image

import pymb
from pymb.devices import MapDevice
from pymb.maps import sunspec

INVERTER: list[tuple[int, dict[str, Any]]] = [
    (1, {"Mn": "Acme Solar", "Md": "AS-10K"}),
    (103, {"W": 3342, "W_SF": -1, "PhVphA": 2301, "PhVphB": 2299, "V_SF": -1}),
    (160, {"DCA_SF": -2, "N": 3, "module": [{"DCA": 812}, {"DCA": 15}, {"DCA": 7}]}),
    (705, {"Ena": 1, "NPt": 3, "NCrv": 2, "V_SF": -1, "DeptRef_SF": 0, "RspTms_SF": 0,
           "Crv": [{"ActPt": 3, "Pt": [{"V": 900}, {"V": 1000}, {"V": 1100}]},
                   {"ActPt": 2, "Pt": [{"V": 950}, {"V": 1050}, {}]}]}),
]
M103 = 40070  # SunS, then model 1 (ID, L, 66 registers): model 103's ID
M160 = M103 + 52
M705 = M160 + 70
CURVES = ([90.0, 100.0, 110.0], [95.0, 105.0, None])


@contextmanager
def device(regs: Sequence[int], *, base: int = 40000, unit: int = 1,
           refuse: Collection[int] = (), silent: Collection[int] = (), most: int = 125,
           log: list[tuple[int, int, bool]] | None = None) -> Iterator[Hostile]:
    """Serve ``regs`` from holding register ``base`` as ``unit``: a read
    touching a register in ``refuse`` or outside the image is answered with
    exception 02, one of more than ``most`` registers with 03, one touching
    ``silent`` not at all; ``log`` gets (address, count, refused) of each."""
    held = {base + i: v for i, v in enumerate(regs)}

    def script(n: int, req: Request, conn: object) -> bytes | None:
        tid, u, fc, address, count = req
        span = range(address, address + count)
        if log is not None:
            log.append((address, count, count > most))
        if u != unit or any(a in silent for a in span):
            return None
        if count > most:
            return mbap(tid, u, bytes((fc | 0x80, 3)))
        if fc != 3 or any(a in refuse or a not in held for a in span):
            return mbap(tid, u, bytes((fc | 0x80, 2)))
        return mbap(tid, u, bytes((fc,)) + registers([held[a] for a in span]))

    server = Hostile(script)
    try:
        yield server
    finally:
        server.close()


def _read(port: int, unit: int = 1) -> tuple[sunspec.Discovery, dict[str, Any],
                                              dict[str, Any]]:
    with pymb.TcpClient("127.0.0.1", port, timeout=1.0) as c:
        found = sunspec.discover(lambda a, n: c.read_holding_registers(a, n, slave=unit))
        dev = MapDevice(c, found.map(unit), unit)
        values = dev.read()
        return found, values, dict(dev.states)


def test_an_end_marker_without_its_length_ends_the_chain() -> None:
    """SunSpec's end model is ID 0xFFFF, L 0; a device that stops at the
    0xFFFF (the L register refused) has ended its chain all the same, as
    pysunspec2 reads it (ID and L apart). ``sunspec`` alone is unit 1."""
    regs = image(INVERTER)[:-1]
    with device(regs) as server:
        found, values, _ = _read(server.port)
        r = run_pymb("read", "sunspec", "--tcp", f"127.0.0.1:{server.port}", "--json")
    assert [m.id for m in found.models] == [1, 103, 160, 705]
    assert found.end == 40000 + len(regs) + 1
    assert values["inverter_three_phase.W"] == pytest.approx(334.2)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    assert json.loads(r.stdout)["values"]["mppt.module.DCA"] == pytest.approx([8.12, 0.15, 0.07])


def test_a_chain_that_stops_without_an_end_marker_is_one_line() -> None:
    regs = image(INVERTER)[:-2]  # no end marker: the next register is refused
    with device(regs) as server:
        r = run_pymb("map", "probe", "1", "--sunspec", "--tcp", f"127.0.0.1:{server.port}")
    assert r.returncode == 3
    assert r.stderr == ("pymb map: the SunSpec model chain breaks at register "
                        f"{40000 + len(regs)}: the device will not read it (exception 02) and "
                        "no end marker (0xFFFF) came before it\n")


@pytest.mark.parametrize("refused", [[M103 + 12], [M103 + 2, M103 + 3], [M705 + 5]])
def test_registers_a_device_refuses_in_a_model_read_no_value_the_rest_read(
        refused: list[int]) -> None:
    """Exception 02 on part of a model (one register, the first two, the
    count point NPt): the model is read in parts around them, the points
    there read no value (``unsupported``), every other point reads, said
    once; the refused NPt is the count that fills the model's L."""
    with device(image(INVERTER), refuse=refused) as server:
        found, values, states = _read(server.port)
        r = run_pymb("read", "sunspec:1", "--tcp", f"127.0.0.1:{server.port}", "--json")
    assert [m.id for m in found.models] == [1, 103, 160, 705]
    m = found.map(1)
    for name, p in m.points.items():
        if p.block:
            continue
        if set(range(p.address, p.address + p.count)) & set(refused):
            assert values[name] is None, name
            assert states[name] == "unsupported", name
    if M103 + 12 not in refused:  # W_SF's own register
        assert values["inverter_three_phase.W"] == pytest.approx(334.2)
    assert values["mppt.module.DCA"] == pytest.approx([8.12, 0.15, 0.07])
    assert values["DERVoltVar.Crv[1].Pt.V"] == pytest.approx(CURVES[0])
    assert values["DERVoltVar.Crv[2].Pt.V"] == pytest.approx(CURVES[1])
    assert r.returncode == 0, r.stderr
    (note,) = r.stderr.splitlines()
    first = M103 if refused[0] < M705 else M705
    assert note.startswith(f"pymb: sunspec:1: model {103 if first == M103 else 705} at {first}")
    assert "the device refuses to read registers " + (
        f"{refused[0]}..{refused[-1]}" if len(refused) > 1 else str(refused[0])) in note


def test_a_model_longer_than_sunspec_defines_reads_its_own_points_only() -> None:
    """L larger than the model's points (model 103 with 7 registers more,
    model 160, whose modules L counts, with room for 3 modules and 7
    registers, model 705 with 20 more): the extra registers are ignored, a
    group counted by a point (NCrv, NPt) takes no instance more than that
    point says, the next model is found after the longer L."""
    full = image(INVERTER)
    m103 = full[M103 - 40000:M160 - 40000]
    m160 = full[M160 - 40000:M705 - 40000]
    m705 = full[M705 - 40000:-2]
    regs = [*full[:M103 - 40000], 103, 57, *m103[2:], *[7] * 7,
            160, m160[1] + 7, *m160[2:], *[9] * 7,
            705, m705[1] + 20, *m705[2:], *[900] * 20, 0xFFFF, 0]
    with device(regs) as server:
        found, values, _ = _read(server.port)
    assert [(m.id, m.length) for m in found.models] == [(1, 66), (103, 57), (160, 75),
                                                        (705, m705[1] + 20)]
    assert not found.notes
    assert values["inverter_three_phase.W"] == pytest.approx(334.2)
    assert values["mppt.module.DCA"] == pytest.approx([8.12, 0.15, 0.07])
    assert values["DERVoltVar.Crv[1].Pt.V"] == pytest.approx(CURVES[0])
    assert values["DERVoltVar.Crv[2].Pt.V"] == pytest.approx(CURVES[1])
    assert "DERVoltVar.Crv[3].Pt.V" not in values


@pytest.mark.parametrize(("regs", "said"), [
    ([64999, 20000, 0, 0], "SunSpec model 64999 at 50002 says L = 20000, past register 65535"),
    ([64999, 0] * 257, "the SunSpec model chain from 50000 has more than 256 models without "
     "its end marker (0xFFFF)"),
])
def test_a_chain_running_past_65535_or_without_end_is_refused_in_one_line(
        regs: list[int], said: str) -> None:
    """``SunS`` at 50000, then a vendor model whose L runs past register
    65535, or 257 empty vendor models."""
    with device([0x5375, 0x6E53, *regs], base=50000) as server:
        r = run_pymb("map", "probe", "1", "--sunspec", "--tcp", f"127.0.0.1:{server.port}")
    assert r.returncode == 3
    assert r.stderr == f"pymb map: {said}\n"


def test_suns_at_two_bases_the_first_in_order_is_read() -> None:
    """``SunS`` at 0 and at 40000: 40000 is tried first, and read."""
    regs = image(INVERTER)
    other = image([(1, {"Mn": "Other"})])
    image_at = {40000 + i: v for i, v in enumerate(regs)} | dict(enumerate(other))
    first, last = min(image_at), max(image_at)
    with device([image_at.get(a, 0) for a in range(first, last + 1)], base=first) as server:
        found, _, _ = _read(server.port)
    assert found.base == 40000
    assert found.manufacturer == "Acme Solar"


def test_a_base_that_times_out_is_passed_over() -> None:
    """Silence at 40000 (the reply timeout), ``SunS`` at 0: the device is
    found at 0, over the same connection."""
    with device(image(INVERTER), base=0, silent={40000, 40001}) as server:
        found, values, _ = _read(server.port)
    assert found.base == 0
    assert values["inverter_three_phase.W"] == pytest.approx(334.2)


def test_a_device_at_unit_126_answers_as_126_only() -> None:
    with device(image(INVERTER), unit=126) as server:
        tcp = f"127.0.0.1:{server.port}"
        found, _, _ = _read(server.port, unit=126)
        r = run_pymb("read", "sunspec:126", "--tcp", tcp, "--json", "--timeout", "0.3")
        wrong = run_pymb("read", "sunspec:1", "--tcp", tcp, "--timeout", "0.3")
    assert found.manufacturer == "Acme Solar"
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["values"]["inverter_three_phase.W"] == pytest.approx(334.2)
    assert wrong.returncode == 3
    assert wrong.stderr == ("pymb read: no SunSpec device: 'SunS' (0x5375 0x6E53) is at none of "
                            "holding registers 40000, 0, 50000 (40000: ModbusTimeout; 0: "
                            "ModbusTimeout; 50000: ModbusTimeout)\n")


def test_an_end_marker_at_65535_and_a_common_model_of_65() -> None:
    """The legacy common model (L = 65, without its pad) reads whole, no
    note; a chain whose end marker's ID is register 65535 ends there."""
    common = image(INVERTER[:1])[2:-2]
    assert common[1] == 66
    legacy = [1, 65, *common[2:67]]
    filler = 65535 - 50000 - 2 - len(legacy) - 2
    regs = [0x5375, 0x6E53, *legacy, 64999, filler, *[0] * filler, 0xFFFF]
    with device(regs, base=50000) as server:
        found, values, _ = _read(server.port)
    assert found.end == 65537
    assert [(m.id, m.length) for m in found.models] == [(1, 65)]
    assert found.skipped == ((64999, 50069, filler),)
    assert [n for n in found.notes if "shorter" in n] == []
    assert values["common.Mn"] == "Acme Solar"
    assert "common.DA" in values


def test_discovery_and_reading_over_rtu() -> None:
    """The same device on a serial line (RTU on a pseudo-terminal), unit 7:
    ``pymb map probe --sunspec`` and ``pymb read sunspec:7`` over ``--port``."""
    regs = image(INVERTER)
    with PtyPeer(slaves={7}) as peer:
        peer.memory.holding[40000:40000 + len(regs)] = regs
        probe = run_pymb("map", "probe", "7", "--sunspec", "--port", peer.port, "--json")
        r = run_pymb("read", "sunspec:7", "--port", peer.port, "--json")
    assert probe.returncode == 0, probe.stderr
    info = json.loads(probe.stdout)
    assert [m["id"] for m in info["models"]] == [1, 103, 160, 705]
    assert info["manufacturer"] == "Acme Solar"
    assert r.returncode == 0, r.stderr
    values = json.loads(r.stdout)["values"]
    assert values["inverter_three_phase.W"] == pytest.approx(334.2)
    assert values["DERVoltVar.Crv[2].Pt.V"] == pytest.approx(CURVES[1])


@pytest.mark.parametrize("chain", [[64999, 2, 1, 2], []])
def test_a_device_with_no_model_pymb_knows_is_one_line(tmp_path: Path,
                                                       chain: list[int]) -> None:
    """Only a vendor's model, or none: the probe says so in one line (as
    ``read`` does), exit 2, and saves nothing."""
    saved = tmp_path / "device.toml"
    with device([0x5375, 0x6E53, *chain, 0xFFFF, 0]) as server:
        tcp = f"127.0.0.1:{server.port}"
        probe = run_pymb("map", "probe", "1", "--sunspec", "--tcp", tcp, "--save", str(saved))
        read = run_pymb("read", "sunspec:1", "--tcp", tcp)
    said = ("'sunspec:1': the device has no SunSpec model pymb knows ("
            + ("model 64999 at 40002 (L = 2) skipped: pymb does not know it" if chain
               else "no models") + ")\n")
    assert (probe.returncode, probe.stderr) == (2, "pymb map: " + said)
    assert (read.returncode, read.stderr) == (2, "pymb read: " + said)
    assert not saved.exists()


def test_the_probe_names_the_maker_in_utf8() -> None:
    regs = image([(1, {"Mn": "M\u00fcller Solar", "Md": "\u00c9t\u00e9"})])
    with device(regs) as server:
        r = run_pymb("map", "probe", "1", "--sunspec", "--tcp", f"127.0.0.1:{server.port}")
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0] == ("SunSpec device, unit 1: 'SunS' at holding 40000; "
                                        "M\u00fcller Solar \u00c9t\u00e9")


def test_a_device_that_reads_fewer_registers_a_request_is_asked_no_more() -> None:
    """Exception 03 to any read of more than 40 registers: discovery reads
    in smaller parts, and the map it builds asks no more than the most that
    read, so that no poll is refused, nor read a point at a time."""
    log: list[tuple[int, int, bool]] = []
    with device(image(INVERTER), most=40, log=log) as server:
        with pymb.TcpClient("127.0.0.1", server.port, timeout=1.0) as c:
            found = sunspec.discover(lambda a, n: c.read_holding_registers(a, n, slave=1))
            dev = MapDevice(c, found.map(1), 1)
            del log[:]
            values = dev.read()
            polled = list(log)
        r = run_pymb("map", "probe", "1", "--sunspec", "--tcp", f"127.0.0.1:{server.port}")
    assert 20 <= found.max_registers <= 40
    assert found.map(1).limits.max_registers == found.max_registers
    assert f"note: the device reads at most {found.max_registers} registers a request" in r.stdout
    assert polled
    assert not any(refused for _, _, refused in polled)
    assert values["inverter_three_phase.W"] == pytest.approx(334.2)
    assert values["DERVoltVar.Crv[2].Pt.V"] == pytest.approx(CURVES[1])


def test_a_base_that_answers_garbled_is_passed_over() -> None:
    """A reply at 40000 that is no proper answer (a byte count its frame does
    not hold: ``ProtocolError``), ``SunS`` at 0: found at 0, as a base that
    times out or refuses is passed over, and the probe says what each base did."""
    regs = image(INVERTER)
    asked: list[int] = []

    def read(address: int, count: int) -> Sequence[int]:
        asked.append(address)
        if address >= 40000:
            raise pymb.ProtocolError("byte count does not match the frame")
        return regs[address:address + count]

    found = sunspec.discover(read)
    assert found.base == 0
    assert found.manufacturer == "Acme Solar"
    assert asked[0] == 40000
