"""What a bench run is asked to do: its options and plan, and the constants
every section shares."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from pymb.bench.contenders import NAMES

__all__ = ["BUSES", "EXTRA_SECTIONS", "QUICK_BUDGET", "SECTIONS", "SEED", "SOFTWARE_BAUD",
           "Options", "Plan", "Progress"]

SECTIONS = ("micro", "plan", "maps", "sweep", "wire", "scaling", "aio", "fleet", "logger",
            "gateway")
#: sections run only when named in --sections (long: the soak takes 30 minutes; collect
#: starts a broker and a PostgreSQL of its own; serve, three simulators and two servers)
EXTRA_SECTIONS = ("soak", "collect", "writes", "serve")
#: --quick: the seconds each section may take on a loaded 2-core machine. The
#: default sections' budgets add up to less than a minute: a section's quick plan
#: is sized to fit its own, a new section declares one (tests/bench checks both),
#: and a run reports what each section took against it.
QUICK_BUDGET = {"micro": 1.0, "plan": 1.0, "maps": 3.0, "sweep": 4.0, "wire": 8.0,
                "scaling": 5.0, "aio": 8.0, "fleet": 9.0, "logger": 9.0, "gateway": 8.0,
                "soak": 65.0, "collect": 60.0, "writes": 60.0, "serve": 30.0}
SOFTWARE_BAUD = 115200  #: the line speed set on the pty for the software comparison
SEED = 0
BUSES = (1, 2, 4, 8)
_TIMEOUT = 2.0  #: every stack's reply timeout, seconds (the hub may take 0.5 s)

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Plan:
    """How much of everything to do."""

    rounds: int  #: interleaved rounds of the sweep comparison
    sweeps: int  #: hub sweeps per contender per round
    reads: int  #: telemetry reads per contender per round
    warm_sweeps: int
    warm_reads: int
    micro_repeat: int
    micro_seconds: float  #: at least this long per timeit repeat
    wire_rounds: int  #: interleaved rounds at emulated 115200
    rounds_9600: int  #: a sweep at 9600 baud takes 1.6 s: one sweep per round, few rounds
    sweeps_115200: int
    scale_seconds: float
    scale_repeats: int

    @classmethod
    def make(cls, quick: bool, rounds: int | None) -> Plan:
        """The full plan (about two minutes on 2 cores) or the quick one."""
        if quick:
            r = rounds or 3
            return cls(r, 4, 8, 1, 2, 5, 0.02, 1, 1, 2, 0.3, 1)
        r = rounds or 20
        return cls(r, 40, 100, 5, 20, 15, 0.2, min(r, 6), min(r, 3), 4, 4.0, 2)


@dataclass
class Options:
    """What the user asked for."""

    quick: bool = False
    only: tuple[str, ...] = NAMES
    rounds: int | None = None
    sections: tuple[str, ...] = SECTIONS
    command: str = "pymb bench"
    progress: Progress | None = None
    plan: Plan = field(init=False)

    def __post_init__(self) -> None:
        self.plan = Plan.make(self.quick, self.rounds)

    def say(self, text: str) -> None:
        """A progress line (stderr), if wanted."""
        if self.progress is not None:
            self.progress(text)
