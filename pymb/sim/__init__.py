"""Simulated Modbus devices, for tests, demos and benchmarks: any map's
(:class:`MapSimDevice`), the CoolPro and the sensor hub among them.

Each device does what its document and the project's notes say (register
maps, function and exception codes, silence, write semantics, timing), with
values that move like real ones, deterministically from a seed, and faults
that can be switched on by script or by probability. Any Modbus RTU master
can talk to them on a pseudo-terminal; Modbus TCP is served too.

From Python::

    from pymb.sim import Simulator
    with Simulator(["coolpro", "hub:250"]) as sim:
        with pymb.RtuClient(sim.port, 9600, slave=40) as client:
            client.read_input_registers(0, 8)

From the shell: ``pymb simulate coolpro hub`` prints the pseudo-terminal to
open. In pytest: the fixtures of :mod:`pymb.testing`.
"""

from __future__ import annotations

from pymb.sim.bus import Bus, BusStats
from pymb.sim.clock import SimClock
from pymb.sim.devices import Channel, CoolProDevice, Device, HubDevice
from pymb.sim.faults import KINDS as FAULT_KINDS
from pymb.sim.faults import Fault, Faults
from pymb.sim.mapsim import MapSimDevice
from pymb.sim.simulator import Simulator, SimulatorProcess, make_device

__all__ = [
    "FAULT_KINDS",
    "Bus",
    "BusStats",
    "Channel",
    "CoolProDevice",
    "Device",
    "Fault",
    "Faults",
    "HubDevice",
    "MapSimDevice",
    "SimClock",
    "Simulator",
    "SimulatorProcess",
    "make_device",
]
