"""The simulator serves RTU over TCP to pymodbus, an independent master."""

from __future__ import annotations

import pytest

import pymb


def test_simulator_serves_rtu_over_tcp_to_pymodbus() -> None:
    pm_client = pytest.importorskip("pymodbus.client")
    framer = pytest.importorskip("pymodbus").FramerType.RTU
    from pymb.sim import Simulator

    with Simulator(["coolpro", "hub:250"], transport="rtu-over-tcp", seed=3) as sim:
        # held still, the image read after the request is the one served (the
        # hub refreshes its values whenever the line is quiet for 0.25 s)
        sim.clock.freeze()
        c = pm_client.ModbusTcpClient(sim.host, port=sim.tcp_port, framer=framer, timeout=2,
                                      retries=0)
        assert c.connect()
        try:
            rr = c.read_input_registers(0, count=8, device_id=40)
            assert not rr.isError()
            assert len(rr.registers) == 8
            rr = c.read_holding_registers(31, count=100, device_id=250)
            assert not rr.isError()
            assert list(rr.registers) == list(
                sim.device(250).registers(31, 100))  # type: ignore[attr-defined]
        finally:
            c.close()
        with pymb.RtuOverTcpClient(sim.host, sim.tcp_port, slave=250) as mine:
            assert len(mine.read_holding_registers(31, 700)) == 700
        sim.faults.inject("bad_crc")
        with pymb.RtuOverTcpClient(sim.host, sim.tcp_port, slave=40) as mine, \
                pytest.raises(pymb.ProtocolError, match="CRC"):
            mine.read_input_registers(0, 8)
