"""docs/library.md's and docs/simulators.md's Python examples run: against
simulated devices on a pseudo-terminal in place of /dev/ttyUSB0, and the read
plan the guide prints is the one pymb prints."""

from __future__ import annotations

import contextlib
import io

from docblocks import claim_one

from pymb.sim import Simulator


def test_the_facade_examples_run_and_print_the_documented_plan() -> None:
    first = claim_one("docs/library.md", "python", how="run", index=0).text
    plan = claim_one("docs/library.md", "python", how="run", index=1).text
    with Simulator(["coolpro", "hub:250"], seed=2) as sim:
        out = io.StringIO()
        namespace: dict[str, object] = {}
        with contextlib.redirect_stdout(out):
            exec(compile(first.replace("/dev/ttyUSB0", sim.port), "library.md", "exec"),
                 namespace)
            with namespace["client"]:  # type: ignore[attr-defined]
                exec(compile(plan, "library.md", "exec"), namespace)
    printed = out.getvalue().splitlines()
    assert len(printed[0].split()) == 4  # the telemetry line
    documented = [line[2:] for line in plan.splitlines() if line.startswith("# ")]
    assert printed[1:] == documented


def test_the_simulator_example_runs() -> None:
    code = claim_one("docs/simulators.md", "python", how="run").text
    exec(compile("import pymb\n" + code, "simulators.md", "exec"), {})
