"""The contenders as processes: the reference their data is checked against,
the lineup of workers on their simulators, and the interleaved rounds that
time them."""

from __future__ import annotations

import math
import statistics
import sys
from array import array
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from pymb import _native
from pymb.bench import cprogram
from pymb.bench.contenders import CONTENDERS, Contender, probe
from pymb.bench.options import _TIMEOUT, SEED, SOFTWARE_BAUD, Options
from pymb.bench.procs import Child, ChildError, Children
from pymb.bench.worker import CP_ADDRESS, CP_COUNT, CP_SLAVE, HUB_SLAVE
from pymb.devices.coolpro import decode_telemetry
from pymb.devices.hub import decode_hub
from pymb.devices.hubreading import BLOCKS, CHANNELS, HUB_REGISTERS, block_index
from pymb.sim import HubDevice, Simulator

__all__ = ["Lineup", "RaceEntry", "Reference", "hub_registers", "race", "summary", "verify"]

#: the C program's letter for each hub block type (sign-magnitude, signed, unsigned)
_KINDS = {"sm16": "S", "i16": "I", "u16": "U"}


# -- the reference the contenders are checked against -------------------------------------


class Reference:
    """The simulated hub's layout (from the seed, values off): which register
    reads 0xFFFF or "no humidity" and which holds a value. Every contender's
    sweep must match it register by register, and its decoded values must
    equal pymb's decoder's on its own raw registers."""

    def __init__(self) -> None:
        regs = hub_registers()
        humidity = block_index("humidity_pct")
        self._h0 = humidity * CHANNELS
        # the hub's default unit's (0.1 %): the map's humidity block as it loads
        self._no_humidity = next(raw for raw, state in BLOCKS[humidity].markers.items()
                                 if state == "no_sensor")
        self.kinds = [self._kind(i, r) for i, r in enumerate(regs)]
        self.k_off = self.kinds.index("off")
        self.k_val = self.kinds.index("val")

    def _kind(self, i: int, r: int) -> str:
        if r == 0xFFFF:
            return "off"
        if self._h0 <= i < self._h0 + CHANNELS and r == self._no_humidity:
            return "none"
        return "val"

    def check_sweep(self, raw: Sequence[int], values: Sequence[float]) -> None:
        """Raise ValueError unless ``raw``/``values`` are a correct sweep."""
        if len(raw) != HUB_REGISTERS or len(values) != HUB_REGISTERS:
            raise ValueError(f"{len(raw)} registers and {len(values)} values, "
                             f"not {HUB_REGISTERS}")
        for i, r in enumerate(raw):
            if self._kind(i, r) != self.kinds[i]:
                raise ValueError(f"register {BLOCKS[0].address + i} reads {r:#06x}: the simulated "
                                 f"hub's layout says {self.kinds[i]}")
        expected = decode_hub(array("H", raw)).values
        _same_values("decoded sweep", values, expected)

    @staticmethod
    def check_telemetry(raw: Sequence[int], values: Sequence[float]) -> None:
        """Raise ValueError unless ``values`` decode ``raw`` as pymb does."""
        if len(raw) != CP_COUNT:
            raise ValueError(f"telemetry is {CP_COUNT} registers, got {len(raw)}")
        t = decode_telemetry(array("H", raw))
        _same_values("decoded telemetry", values,
                     [t.input_voltage_v, t.input_current_a, t.output_voltage_v,
                      t.output_current_a, t.temperature_c, float(t.uptime_s),
                      float(t.status)])


def _same_values(what: str, got: Sequence[float], want: Sequence[float]) -> None:
    if len(got) != len(want):
        raise ValueError(f"{what}: {len(got)} values, not {len(want)}")
    for i, (g, w) in enumerate(zip(got, want, strict=True)):
        if math.isnan(w) != math.isnan(g) or (
                not math.isnan(w) and not math.isclose(g, w, rel_tol=1e-9, abs_tol=1e-9)):
            raise ValueError(f"{what}: value {i} is {g!r}, pymb's decoder says {w!r}")


def hub_registers(seed: int = SEED) -> array[int]:
    """Registers 31..730 of the software comparison's simulated hub, as the
    simulator builds it from ``seed`` (not started: the layout, values at t=0)."""
    dev = Simulator(_software_devices(), seed=seed).device(HUB_SLAVE)
    assert isinstance(dev, HubDevice)
    return dev.registers()


def _software_devices(baud: int = SOFTWARE_BAUD) -> list[str]:
    return [f"hub:{HUB_SLAVE},dynamic=0,baud={baud}", f"coolpro:{CP_SLAVE},gap=0,baud={baud}"]


# -- contenders as processes ---------------------------------------------------------------


@dataclass
class RaceEntry:
    """One contender in one section: its state and its measurements."""

    contender: Contender
    version: str = ""
    status: str = "ok"  #: ok, skipped, failed
    reason: str = ""
    child: Child | None = None
    rounds: dict[str, list[tuple[int, list[int]]]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The contender's name."""
        return self.contender.name

    def fail(self, reason: str, children: Children | None = None) -> None:
        """Mark it failed and stop its process."""
        self.status, self.reason = "failed", reason
        if self.child is not None and children is not None:
            children.stop(self.child)
        self.child = None

    def start(self, argv: Sequence[str], children: Children) -> None:
        """Start its worker (``argv``) and wait for its ``ready``; failed if it cannot."""
        self.child = children.start(self.contender.label, argv)
        try:
            line = self.child.readline(60.0)
            if not line.startswith("ready"):
                raise ChildError(line.partition(" ")[2] or line)
        except ChildError as err:
            self.fail(f"cannot start: {err}", children)


class Lineup:
    """Builds the C program once and starts contender processes."""

    def __init__(self, opts: Options, children: Children, tmp: str) -> None:
        self.opts = opts
        self.children = children
        self.tmp = tmp
        self.c_exe: str | None = None
        self.c_warnings = ""
        self.ref = Reference()
        self.versions: dict[str, str] = {}
        self.reasons: dict[str, str] = {}
        for c in CONTENDERS:
            if c.name not in opts.only:
                continue
            if c.name == "c":
                self._build_c()
            else:
                reason, version = probe(c)
                self.versions[c.name] = version
                if reason:
                    self.reasons[c.name] = reason

    def _build_c(self) -> None:
        try:
            self.c_exe, self.c_warnings = cprogram.build(self.tmp)
        except (cprogram.CBuildError, OSError, ValueError) as e:
            self.reasons["c"] = f"cannot build the C program: {e}"
            return
        cc = cprogram.compiler_version()
        self.versions["c"] = f"{cc}, libmodbus {_native.LIBMODBUS_VERSION}" if cc else \
            f"libmodbus {_native.LIBMODBUS_VERSION}"

    def entries(self, names: Sequence[str] | None = None) -> list[RaceEntry]:
        """Entries for the chosen contenders (in the table's order)."""
        out = []
        for c in CONTENDERS:
            if c.name not in self.opts.only or (names is not None and c.name not in names):
                continue
            e = RaceEntry(c, version=self.versions.get(c.name, ""))
            if c.name in self.reasons:
                e.status, e.reason = "skipped", self.reasons[c.name]
            out.append(e)
        return out

    def start(self, e: RaceEntry, port: str, baud: int) -> None:
        """Start ``e``'s worker on ``port``; marks it failed if it cannot."""
        if e.name == "c":
            assert self.c_exe is not None
            argv = [self.c_exe, port, str(baud), str(HUB_SLAVE), str(BLOCKS[0].address),
                    str(HUB_REGISTERS), str(CHANNELS),
                    "".join("H" if b.name == "humidity_pct" else _KINDS[b.type]
                            for b in BLOCKS),
                    str(CP_SLAVE), str(CP_ADDRESS), str(CP_COUNT),
                    str(self.ref.k_off), str(self.ref.k_val)]
        else:
            argv = [sys.executable, "-m", "pymb.bench.worker", e.name, port, str(baud),
                    str(self.ref.k_off), str(self.ref.k_val), str(_TIMEOUT)]
        e.start(argv, self.children)


def _ask(e: RaceEntry, command: str, n: int, children: Children) -> tuple[int, list[int]] | None:
    """One batch: (CPU ns, wall ns per operation); None (and failed) on error."""
    assert e.child is not None
    try:
        fields = e.child.ask(f"{command} {n}", 30.0 + 5.0 * n).split()
        cpu, walls = int(fields[0]), [int(x) for x in fields[1:]]
        if len(walls) != n:
            raise ChildError(f"answered {len(walls)} timings for {n}")
        return cpu, walls
    except (ChildError, ValueError, IndexError) as err:
        e.fail(f"{command}: {err}", children)
        return None


def verify(e: RaceEntry, ref: Reference, children: Children, telemetry: bool) -> None:
    """Check one sweep (and telemetry read) of ``e`` against ``ref``; failed if wrong."""
    assert e.child is not None
    try:
        raw = [int(x) for x in e.child.ask("verify", 60.0).split()]
        values = [float(x) for x in e.child.expect_ok(10.0).split()]
        ref.check_sweep(raw, values)
        if telemetry:
            raw = [int(x) for x in e.child.ask("tverify", 30.0).split()]
            values = [float(x) for x in e.child.expect_ok(10.0).split()]
            ref.check_telemetry(raw, values)
    except (ChildError, ValueError) as err:
        e.fail(f"verification failed: {err}", children)


def race(entries: Sequence[RaceEntry], workload: str, command: str, rounds: int, n: int,
          warm: int, children: Children, opts: Options, label: str,
          settle: bool = True) -> None:
    """Interleaved rounds of ``command n`` across the running entries (each
    timed batch after as many untimed operations, unless not ``settle``)."""
    live = [e for e in entries if e.status == "ok"]
    if warm:
        for e in live:
            _ask(e, command, warm, children)
    for r in range(rounds):
        live = [e for e in entries if e.status == "ok"]
        if not live:
            return
        opts.say(f"{label}: round {r + 1}/{rounds}")
        k = r % len(live)
        for e in live[k:] + live[:k]:  # the order rotates: none always runs first
            # As many untimed operations first: each contender is timed in its
            # steady state, not while its process (and the line's) re-warm
            # after the others' turns, which penalises large processes after
            # long turns (pymodbus, minimalmodbus) by 20-30% on this machine.
            if settle and _ask(e, command, n, children) is None:
                continue
            got = _ask(e, command, n, children)
            if got is not None:
                e.rounds.setdefault(workload, []).append(got)


def _stop_all(entries: Sequence[RaceEntry], sims: Sequence[Any], children: Children) -> None:
    """Stop every contender's worker and every simulator of a section."""
    for e in entries:
        if e.child is not None:
            children.stop(e.child)
            e.child = None
    for s in sims:
        children.stop(s)


def summary(entries: Sequence[RaceEntry], workload: str, per: int,
            baseline: str = "c") -> dict[str, Any]:
    """Medians and the paired ratios to ``baseline`` (the C program) for one workload."""
    base = next((e for e in entries if e.name == baseline and e.status == "ok"), None)
    rows = []
    for e in entries:
        row: dict[str, Any] = {"name": e.name, "label": e.contender.label,
                               "version": e.version, "status": e.status, "reason": e.reason,
                               "how": e.contender.how}
        data = e.rounds.get(workload, [])
        if e.status == "ok" and data:
            walls = [w / 1e3 for _, ws in data for w in ws]
            cpus = [cpu / 1e3 / len(ws) for cpu, ws in data]
            row.update(
                wall_us=statistics.median(walls),
                cpu_us=statistics.median(cpus),
                rounds=len(data),
                per_round=per,
                round_wall_us=[statistics.median(ws) / 1e3 for _, ws in data],
                round_cpu_us=cpus,
            )
            bdata = base.rounds.get(workload, []) if base is not None else []
            if base is not None and len(bdata) == len(data):
                row["wall_x"] = statistics.median(
                    statistics.median(ws) / statistics.median(bws)
                    for (_, ws), (_, bws) in zip(data, bdata, strict=True))
                row["cpu_x"] = statistics.median(
                    (c / len(ws)) / (bc / len(bws)) if bc else math.inf
                    for (c, ws), (bc, bws) in zip(data, bdata, strict=True))
        elif e.status == "ok":
            row.update(status="failed", reason="no measurement")
        rows.append(row)
    return {"baseline": baseline if base is not None else None, "rows": rows}
