"""pytest fixtures for testing your own code against simulated devices.

Installed with pymb as a pytest plugin (entry point ``pymb.testing``), so
the fixtures are there in any project that has pymb; in a source checkout
add ``pytest_plugins = ["pymb.testing"]`` to a conftest or test module.

``pymb_simulator``
    a factory: ``pymb_simulator("coolpro", "hub:250", baud=19200, seed=3)``
    returns a started :class:`pymb.sim.Simulator` (keyword arguments as its
    own); every simulator it made is stopped at teardown.
``coolpro_sim``
    a started simulator with one CoolPro at address 40 (9600 8N1).
``hub_sim``
    a started simulator with one sensor hub at address 1 (9600 8N1).

Example::

    def test_my_logger(coolpro_sim):
        with pymb.RtuClient(coolpro_sim.port, 9600, slave=40) as client:
            coolpro_sim.faults.inject("no_reply")
            ...
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from pymb.sim import Device, Simulator

__all__ = ["coolpro_sim", "hub_sim", "pymb_simulator"]


@pytest.fixture
def pymb_simulator() -> Iterator[Callable[..., Simulator]]:
    """A factory of started simulators, all stopped at teardown."""
    started: list[Simulator] = []

    def make(*devices: str | Device, **kwargs: Any) -> Simulator:
        sim = Simulator(devices or ("coolpro",), **kwargs)
        sim.start()
        started.append(sim)
        return sim

    yield make
    for sim in reversed(started):
        sim.stop()


@pytest.fixture
def coolpro_sim(pymb_simulator: Callable[..., Simulator]) -> Simulator:
    """A started simulator with one CoolPro at address 40."""
    return pymb_simulator("coolpro")


@pytest.fixture
def hub_sim(pymb_simulator: Callable[..., Simulator]) -> Simulator:
    """A started simulator with one sensor hub at address 1."""
    return pymb_simulator("hub")
