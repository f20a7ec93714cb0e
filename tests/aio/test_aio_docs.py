"""docs/asyncio.md's examples run: the complete one against the simulator,
as printed, and the poller that runs for ever through a fault."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path
from typing import Any

import pytest
from aiokit import until
from docblocks import claim

import pymb.aio
from pymb.aio import AsyncRtuClient, AsyncSensorHub
from pymb.devices import HubReading
from pymb.sim import Simulator

DOC = (Path(__file__).resolve().parents[2] / "docs" / "asyncio.md").read_text()
BLOCKS = [b.text for b in claim("docs/asyncio.md", "python", how="run")]


def test_the_complete_example_runs(capsys: pytest.CaptureFixture[str]) -> None:
    exec(compile(BLOCKS[0], "docs/asyncio.md", "exec"), {"__name__": "__main__"})
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("CoolPro serial ")
    assert out[1].startswith("raw telemetry [")
    assert re.fullmatch(r"hub: \d+ of 100 channels read a temperature", out[2])
    assert out[2] != "hub: 0 of 100 channels read a temperature"
    assert [re.fullmatch(r"output \d+\.\d{3} V", line) is not None for line in out[3:6]] == \
        [True] * 3
    assert out[6] == "no reply: ModbusTimeout"
    assert out[7] == "stopped waiting; the next sweep is whole: 100 channels"
    assert len(out) == 8


def test_the_poller_that_runs_for_ever_survives_a_fault(
        capsys: pytest.CaptureFixture[str]) -> None:
    namespace: dict[str, Any] = {"asyncio": asyncio, "pymb": pymb,
                                 "AsyncSensorHub": AsyncSensorHub}
    exec(compile(BLOCKS[1], "docs/asyncio.md", "exec"), namespace)
    stored: list[HubReading] = []

    async def main(sim: Simulator) -> None:
        async with AsyncRtuClient(sim.port, 9600, timeout=0.3) as client:
            sim.faults.inject("no_reply", address=1)
            task = asyncio.ensure_future(
                namespace["log_forever"](AsyncSensorHub(client, 1), stored.append))
            await until(lambda: len(stored) >= 2, "two readings after the fault")
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    with Simulator(["hub:1"]) as sim:
        asyncio.run(main(sim))
    assert capsys.readouterr().out.startswith("hub: ")


def test_every_public_name_is_documented() -> None:
    for name in pymb.aio.__all__:
        if name not in ("AsyncClient", "poll"):
            assert f"`{name}" in DOC, name
