"""The bench's result as a terminal table, Markdown, JSON or a bar chart.

The tables are built once from the result (:func:`tables`) and rendered in
either format, so the Markdown of docs/benchmarks.md says what the terminal said.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from typing import Any

from pymb.bench import (
    collectbench,
    gatebench,
    mapbytes,
    mapwire,
    servebench,
    wear,
    writebench,
)
from pymb.bench.table import Table, X, fmt_time, fmt_x
from pymb.errors import InvalidArgument
from pymb.jsonvalue import nan_to_null

__all__ = ["PLOT_FORMATS", "PLOT_MARK", "Table", "plot", "tables", "to_json", "to_markdown",
           "to_text"]

#: In the metadata of every image :func:`plot` draws: one pymb bench drew may be replaced.
PLOT_MARK = "pymb bench"
PLOT_FORMATS = (".png", ".svg")  #: the file names :func:`plot` draws to

def _workload_table(title: str, note: str, section: dict[str, Any]) -> Table:
    base = section["baseline"]
    rows, footer = [], []
    for r in section["rows"]:
        if "wall_us" not in r:
            footer.append(f"{r['label']}: {r['status']}: {r['reason']}")
            continue
        rows.append([r["label"], fmt_time(r["wall_us"]), fmt_x(r.get("wall_x")),
                     fmt_time(r["cpu_us"]), fmt_x(r.get("cpu_x"))])
    if base is None:
        footer.append("no ratios: the C program did not run (it is the baseline)")
    return Table(title, note, ["contender", "wall", f"{X} C", "CPU", f"{X} C"], rows,
                 [False, True, True, True, True], footer)


def tables(result: dict[str, Any]) -> list[Table]:
    """Every table of the result, in the order shown."""
    m = result["meta"]
    out = [_contenders_table(result["contenders"])]
    if result.get("sweep"):
        out += _sweep_tables(result["sweep"], m["plan"])
    sections: tuple[tuple[str, Callable[[Any], Table | list[Table]]], ...] = (
        ("micro", _micro_table), ("plan", _plan_table), ("maps", _maps_tables),
        ("wire", _wire_table), ("scaling", _scaling_table), ("aio", _aio_tables),
        ("logger", _logger_tables), ("gateway", gatebench.tables),
        ("collect", collectbench.tables), ("fleet", _fleet_table), ("soak", _soak_table),
        ("writes", writebench.tables), ("serve", servebench.tables))
    for key, make in sections:
        made = make(result[key]) if result.get(key) else []
        out += made if isinstance(made, list) else [made]
    if m.get("quick"):
        _mark_quick(out)
    tg = [] if m.get("quick") else (result.get("targets") or [])
    if tg:
        out.append(_targets_table(tg))
    return out


def _contenders_table(contenders: list[dict[str, Any]]) -> Table:
    return Table(
        "Contenders", "", ["contender", "version", "how"],
        [[c["label"], c["version"] or "-", c["how"]] for c in contenders
         if c["status"] == "ok"],
        [False, False, False],
        [f"{c['label']}: {c['status']}: {c['reason']}" for c in contenders
         if c["status"] != "ok"])


def _sweep_tables(sweep: dict[str, Any], plan: dict[str, Any]) -> list[Table]:
    common = (f"simulator in its own process over a pty at {sweep['baud']} 8N1 without "
              f"wire emulation; medians of {plan['rounds']} interleaved rounds")
    return [
        _workload_table(
            "Hub sweep: 700 registers in 6 requests, decoded to engineering values",
            f"{common} x {plan['sweeps']} sweeps, each batch after as many untimed ones "
            f"(steady state); wall and CPU (the contender's own "
            f"process) per sweep; {X} C = median of the per-round ratios to the C program",
            sweep["hub"]),
        _workload_table(
            "CoolPro telemetry: 8 input registers in 1 request, decoded",
            f"{common} x {plan['reads']} reads after as many untimed; the CoolPro's ~8 ms "
            f"gap set to 0 "
            "(pure software cost; with the gap, see the wire-bound table)",
            sweep["telemetry"]),
    ]


def _micro_table(micro: dict[str, Any]) -> Table:
    return Table(
        "Micro: in-process, per call",
        f"timeit, median of {micro['repeat']} repeats",
        ["operation", "pymb (C)", "pure Python", "speed-up", "target"],
        [[r["what"], fmt_time(r["pymb_us"]), fmt_time(r["python_us"]),
          fmt_x(r["speedup"]), f"≤ {r['target_us']:g} µs"] for r in micro["rows"]],
        [False, True, True, True, True],
        [f"pymb: {r['pymb_call']}; pure Python: {r['python_call']}"
         for r in micro["rows"]])


def _plan_table(plan: dict[str, Any]) -> Table:
    return Table(
        f"Planning: the reads of a {plan['points']}-point map",
        f"a fresh planner each time, median of {plan['repeat']}; the plan's predicted wire "
        "time against one request per contiguous run",
        ["points", "plan", "requests", "registers", "predicted wire", "naive wire", "target"],
        [[str(plan["points"]), fmt_time(plan["plan_ms"] * 1e3), str(plan["requests"]),
          str(plan["registers"]), fmt_time(plan["predicted_ms"] * 1e3),
          fmt_time(plan["naive_ms"] * 1e3), f"≤ {plan['target_ms']:g} ms"]],
        [True, True, True, True, True, True, True], [])


def _maps_tables(maps: dict[str, Any]) -> list[Table]:
    return [Table(
        f"Maps: decoding a {maps['points']}-point f32 map",
        f"median of {maps['repeat']} runs: one pymb_map_decode call from Python into "
        "preallocated arrays, the same with the {name: value} dict, and the pure Python "
        "reference codec point by point",
        ["points", "one C call", "with the dict", "pure Python", "target"],
        [[str(maps["points"]), fmt_time(maps["decode_us"]), fmt_time(maps["read_us"]),
          fmt_time(maps["python_us"]), f"≤ {maps['target_us']:g} µs"]],
        [True] * 5, [f"The hub's 700 registers decoded through its map: "
                     f"{fmt_time(maps['hub_map_us'])}"]),
    ] + ([mapwire.table(maps["wire"])] if "wire" in maps else [])


def _wire_table(wire: dict[str, Any]) -> Table:
    rows, footer = [], []
    for r in wire["rows"]:
        if "wall_us" not in r:
            footer.append(f"{r['baud']} baud, {r['label']}: {r['status']}: {r['reason']}")
            continue
        rows.append([str(r["baud"]), r["workload"], r["label"], fmt_time(r["wall_us"]),
                     fmt_time(r["theory_us"]), fmt_x(r.get("theory_x")),
                     fmt_x(r.get("wall_x"))])
    return Table(
        "Wire-bound: the simulator emulating the line speed",
        "median time per sweep (per read) against the least wire time of the frames "
        "(pymb.wire): 10 bits a byte, request and reply, and between them 3.5 characters "
        "or the device's gap, whichever is longer (the CoolPro's 8 ms gap is its silence "
        "after the request, not added to it); no measurement can beat it",
        ["baud", "workload", "contender", "time", "theoretical", f"{X} theory", f"{X} C"],
        rows,
        [True, False, False, True, True, True, True], footer)


def _scaling_table(scaling: dict[str, Any]) -> Table:
    return Table(
        f"Scaling: buses swept in parallel threads of one pymb process, emulated "
        f"{scaling['baud']}",
        f"{scaling['seconds']:g} s per run, median of {scaling['repeats']}; one "
        f"RtuClient + SensorHub per bus; one bus's wire limit is "
        f"{scaling['theory_sweeps_per_s']:.2f} sweeps/s",
        ["buses", "sweeps/s", "speed-up", "CPU (% of a core)", "CPU per sweep"],
        [[str(r["buses"]), f"{r['sweeps_per_s']:.2f}", fmt_x(r["speedup"]),
          f"{r['cpu_pct']:.1f} %", fmt_time(r["cpu_per_sweep_us"])]
         for r in scaling["rows"]],
        [True, True, True, True, True], [])


def _fleet_table(fleet: dict[str, Any]) -> Table:
    if fleet.get("status") != "ok":
        return Table("Fleet", "", ["status"], [[f"skipped: {fleet['reason']}"]], [False], [])

    def ms(v: float | None) -> str:
        return "-" if v is None else fmt_time(v * 1000)

    return Table(
        "Fleet: samples through a local mosquitto (pymb log --mqtt against the bridges' "
        "way)",
        f"throughput: {fleet['burst']:,} samples as fast as each publisher goes, until a "
        f"subscriber has them all (median of {fleet.get('repeats', 1)}); latency: sample "
        f"time to the subscriber at {fleet['rate']:g} samples/s (pymb writes each to "
        "SQLite and publishes it from the open batch); outage: "
        f"{fleet['outage_samples']:,} samples at {fleet['rate']:g}/s with mosquitto "
        f"stopped for {fleet['outage_s']:g} s from a third of the run, as a "
        "persistent-session subscriber sees them",
        ["publisher", "throughput", "latency median", "latency p95",
         f"lost ({fleet['outage_s']:g} s outage)", "duplicated"],
        [[r["label"],
          "-" if r.get("throughput_per_s") is None else f"{r['throughput_per_s']:,.0f}/s",
          ms(r.get("latency_p50_ms")), ms(r.get("latency_p95_ms")),
          f"{r['outage_lost']:,} of {r['outage_sent']:,}" if "outage_sent" in r else "-",
          f"{r['outage_duplicates']:,}" if "outage_sent" in r else "-"]
         for r in fleet["rows"]],
        [False, True, True, True, True, True], [])


def _soak_table(s: dict[str, Any]) -> Table:
    if s.get("status") != "ok":
        return Table("Soak", "", ["status"], [[f"skipped: {s['reason']}"]], [False], [])
    events = s["events"]
    through = ", ".join(f"{k} x{events.count(k)}" for k in sorted(set(events)))
    note = (f"{s['seconds']:g} s of pymb log (a hub and a CoolPro every 0.1 s) forwarding to "
            f"mosquitto, restarted as Restart=on-failure does, through: {through}")
    return Table(
        "Soak: a month in an hour", note,
        ["samples", "received (distinct)", "duplicates", "lost", "taken back by a kill",
         "ids with two samples", "integrity", "logger exits",
         "clock steps", "RSS of the last logger", "descriptors"],
        [[f"{s['samples']:,}", f"{s['received']:,} ({s['distinct']:,})", f"{s['duplicates']:,}",
          f"{s['lost']:,}", f"{s['taken_back']:,}", f"{s['reused']:,}", s["integrity"],
          " ".join(map(str, s["exits"])) or "-",
          f"{s['clock_steps']}", f"{s['rss_kb'][0]:,} -> {s['rss_kb'][1]:,} kB",
          f"{s['fds'][0]} -> {s['fds'][1]}"]],
        [True, True, True, True, True, True, False, False, True, True, True],
        [f"left out: {w}" for w in s["left_out"]])


def _aio_tables(aio: dict[str, Any]) -> list[Table]:
    rows, footer = [], []
    for hub, tele in zip(aio["hub"]["rows"], aio["telemetry"]["rows"], strict=True):
        if "wall_us" not in hub or "wall_us" not in tele:
            footer.append(f"{hub['label']}: {hub['status']}: {hub['reason'] or tele['reason']}")
            continue
        rows.append([hub["label"]] + [f(r.get(k)) for r in (hub, tele) for k, f in (
            ("wall_us", fmt_time), ("wall_x", fmt_x), ("cpu_us", fmt_time), ("cpu_x", fmt_x))])
    footer += [f"{r['label']}: {r['how']}" for r in aio["hub"]["rows"] if r["status"] == "ok"]
    per_call = Table(
        "asyncio: per call, against the blocking calls",
        f"each contender in its own process against its own simulator over a pty at "
        f"{aio['baud']} 8N1 without wire emulation; medians of {aio['rounds']} interleaved "
        f"rounds x {aio['sweeps']} sweeps / {aio['reads']} reads; CPU: the contender's "
        f"process, worker thread included; {X} blocking: median of the per-round ratios",
        ["contender", "sweep wall", f"{X} blocking", "sweep CPU", f"{X} blocking",
         "telemetry wall", f"{X} blocking", "telemetry CPU", f"{X} blocking"],
        rows, [False] + [True] * 8, footer)
    lag = aio["lag"]
    lrows, lfoot = [], []
    for r in lag["rows"]:
        if r["status"] != "ok":
            lfoot.append(f"{r['label']}, {r['line']}: {r['status']}: {r['reason']}")
            continue
        lrows.append([r["label"], r["line"], f"{r['sweeps_per_s']:,.0f}",
                      fmt_time(r["p50_ms"] * 1e3), fmt_time(r["p99_ms"] * 1e3),
                      fmt_time(r["max_ms"] * 1e3), f"{r['cpu_pct']:.0f} %"])
    lag_table = Table(
        f"asyncio: event loop lag, {lag['rows'][0]['hubs']} hubs polled flat out by one loop",
        f"a {lag['period_ms']:g} ms ticker's lateness while every hub is swept again as soon "
        f"as its last sweep ends; {lag['seconds']:g} s runs, median of {lag['repeats']}; each "
        "hub its own simulator process; without emulation the simulators saturate the CPUs",
        ["stack", "line", "sweeps/s", "lag median", "lag p99", "lag max", "CPU (of a core)"],
        lrows, [False, False, True, True, True, True, True], lfoot)
    return [per_call, lag_table]


def _mark_quick(out: list[Table]) -> None:
    """--quick figures are indicative, and the micro table judges no target."""
    for t in out:
        t.title += " [indicative: --quick]"
        if t.title.startswith("Micro") and t.headers[-1] == "target":
            t.headers = list(t.headers[:-1])
            t.rows = [r[:-1] for r in t.rows]
            t.right = list(t.right[:-1])


def _targets_table(tg: list[dict[str, Any]]) -> Table:
    return Table(
        "Targets", "",
        ["target", "goal", "measured", "met"],
        [[t["what"], t["target"],
          "-" if t["measured"] is None else
          (fmt_x(t["measured"]) if t["unit"] == "x" else
           f"{t['measured']:,.0f} B" if t["unit"] == "B" else
           f"{t['measured']:,.1f} MB" if t["unit"] == "MB" else
           f"{t['measured']:,.1f} KB/s" if t["unit"] == "KB/s" else
           f"{t['measured']:,.0f}" if t["unit"] == "values/s" else fmt_time(t["measured"])),
          {True: "yes", False: "NO", None: "-"}[t["met"]]] for t in tg],
        [False, True, True, False], [])


def _logger_tables(s: dict[str, Any]) -> list[Table]:
    runs = s["runs"]
    labels = {"hub": "hub sweep", "coolpro": "CoolPro telemetry",
              "hub_on-change": "hub sweep, --on-change"}
    rows = []
    for key, label in labels.items():
        r = runs[key]
        rows.append([label, fmt_time(r["bare_cpu_us"]), fmt_time(r["log_cpu_us"]),
                     fmt_x(r["cpu_x"]), f"{r['bytes_per_sample']:,.0f} B",
                     f"{r['file_bytes_per_sample']:,.0f} B",
                     f"{r['stored_samples']:,} / {r['samples']:,}"])
    footer = [f"--on-change pairs (CPU): heartbeat {s['heartbeat']:g} s, deadbands "
              + ", ".join(f"{k} {v:g}" for k, v in s["deadband"].items())
              + "; each run starts a new sink, so its bytes are the first sweep's: see the "
              "next table"]
    tables = [Table(
        "Logger: pymb log against the bare read, pair by pair",
        f"{s['rounds']} pairs of {s['seconds']:g} s: the bare facade call, then the real "
        "Logger (poller thread, queue, SQLite on disk, batched commits); CPU of the "
        "process per sample in the logger's steady state (20-95 % of each run), medians; "
        "simulators at 115200 set, no wire emulation; bytes: the data's pages (dbstat: "
        "samples, their time index, hub_changes) over every sample read; with the schema's "
        "fixed pages and the WAL: file + WAL column",
        ["workload", "bare read CPU", "logged CPU", f"{X} bare", "bytes / sample",
         "file + WAL", "stored / read"], rows,
        [False, True, True, True, True, True, True], footer)]
    spans = s.get("spans") or {}
    if spans:
        tables.append(Table(
            "Report by exception: one --on-change run of a simulated hub at wire speed",
            "the hub on a line emulated at 115200 (its sensors report every 2 s, with "
            "noise, and drift slowly); bytes: the data's pages (dbstat) over every sweep "
            "read; saving: against every sweep stored whole (the first table)",
            ["deadbands", "run", "heartbeat", "sweeps read", "sweeps/s", "channel rows stored",
             "bytes / sweep", "saving"],
            [[what, f"{sp['seconds']:g} s", f"{sp['heartbeat']:g} s", f"{sp['samples']:,}",
              f"{sp['sweeps_per_s']:.2f}", f"{sp['channel_rows']:,}",
              f"{sp['bytes_per_sample']:,.0f} B",
              "-" if sp["saving"] is None else f"{100 * sp['saving']:.1f} %"]
             for what, sp in spans.items()],
            [False, True, True, True, True, True, True, True], []))
    qnames = list(s["layouts"][0]["queries"])
    tables.append(Table(
        f"Storage layouts of a hub sweep ({s['layout_sweeps']:,} sweeps each)",
        "bytes on disk per sweep (index included), insert CPU per sweep, and the documented "
        "queries (median of 5; every plan uses the time index)",
        ["layout", "bytes / sweep", "insert CPU", *qnames],
        [[r["layout"], f"{r['bytes_per_sweep']:,.0f} B", fmt_time(r["insert_cpu_us"]),
          *(f"{r['queries'][q]['ms']:.3g} ms" for q in qnames)] for r in s["layouts"]],
        [False, True, True, *([True] * len(qnames))], []))
    tables += [m.table(s[key]) for key, m in (("maps", mapbytes), ("wear", wear)) if s.get(key)]
    return tables


def _header(result: dict[str, Any]) -> list[tuple[str, str]]:
    m = result["meta"]
    took, budget = m.get("section_seconds") or {}, m.get("quick_budget") or {}
    over = [k for k, s in took.items() if m.get("quick") and s > budget.get(k, s)]
    return [
        ("date", m["date"]),
        ("machine", f"{m['cpu']}, {m['cores']} cores, {m['platform']}"),
        ("software", f"{m['python']}, libmodbus {m['libmodbus']}, pymb {m['pymb']}"),
        ("command", m["command"]),
    ] + ([("sections", ", ".join(f"{k} {s:.1f} s" for k, s in took.items())
           + f" ({sum(took.values()):.0f} s" + (f"; over the quick budget: {', '.join(over)}"
                                                 if over else "") + ")")] if took else [])


_QUICK = ("--quick: a smoke test of few rounds and short runs; its figures are indicative, "
          "and it declares no targets")


def to_text(result: dict[str, Any]) -> str:
    """The terminal report."""
    lines = ["pymb bench: pymb against the field, side by side in one run", ""]
    if result["meta"].get("quick"):
        lines[1:1] = [_QUICK]
    lines += [f"  {k:<9} {v}" for k, v in _header(result)]
    for t in tables(result):
        lines += ["", t.title]
        if t.note:
            lines.append(f"  ({t.note})")
        if t.rows:
            widths = [max(len(h), *(len(r[i]) for r in t.rows)) for i, h in enumerate(t.headers)]

            def cells(row: Sequence[str], widths: list[int] = widths, t: Table = t) -> str:
                return "  ".join(c.rjust(w) if right else c.ljust(w)
                                 for c, w, right in zip(row, widths, t.right, strict=True))
            lines.append("  " + cells(t.headers).rstrip())
            lines.append("  " + "  ".join("-" * w for w in widths))
            lines += ["  " + cells(r).rstrip() for r in t.rows]
        lines += [f"  - {f}" for f in t.footer]
    return "\n".join(lines) + "\n"


def _md(cell: str) -> str:
    return cell.replace("|", "\\|")


def to_markdown(result: dict[str, Any]) -> str:
    """The report as Markdown (docs/benchmarks.md's tables)."""
    lines = [f"- **{k}**: {f'`{v}`' if k == 'command' else _md(v)}"
             for k, v in _header(result)]
    if result["meta"].get("quick"):
        lines.insert(0, f"**{_md(_QUICK)}**\n")
    for t in tables(result):
        lines += ["", f"**{_md(t.title)}**" + (f" ({_md(t.note)})" if t.note else ""), ""]
        if t.rows:
            lines.append("| " + " | ".join(_md(h) for h in t.headers) + " |")
            lines.append("|" + "|".join("---:" if r else "---" for r in t.right) + "|")
            lines += ["| " + " | ".join(_md(c) for c in row) + " |" for row in t.rows]
        if t.footer:
            lines.append("")
            lines += [f"- {_md(f)}" for f in t.footer]
    return "\n".join(lines) + "\n"


def to_json(result: dict[str, Any]) -> str:
    """The whole result as JSON (NaN and infinities as null)."""
    return json.dumps(nan_to_null(result), indent=2, ensure_ascii=False) + "\n"


def plot(result: dict[str, Any], path: str) -> None:
    """Bars side by side (wall and CPU per contender, log scale) to ``path``
    (``.png`` or ``.svg``, :data:`PLOT_MARK` in its metadata), written beside
    it and renamed into place when complete.

    Needs matplotlib (the ``bench`` extra); raises ImportError without it, and
    InvalidArgument when ``result`` has neither the sweep nor the micro section.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pymb.store.files import write_beside

    panels = []
    sweep = result.get("sweep") or {}
    for key, title in (("hub", "Hub sweep (700 registers, 6 requests, decoded)"),
                       ("telemetry", "CoolPro telemetry (1 request, decoded)")):
        rows = [r for r in (sweep.get(key) or {}).get("rows", []) if "wall_us" in r]
        if rows:
            panels.append((title, rows))
    micro = (result.get("micro") or {}).get("rows", [])
    n = len(panels) + (1 if micro else 0)
    if n == 0:
        raise InvalidArgument("--plot: nothing to draw: the sweep and micro sections "
                              "have no rows")
    fig, axes = plt.subplots(1, n, figsize=(6.5 * n, 4.8), squeeze=False)
    width = 0.38
    for ax, (title, rows) in zip(axes[0], panels, strict=False):
        xs = range(len(rows))
        wall = [r["wall_us"] for r in rows]
        cpu = [r["cpu_us"] for r in rows]
        bw = ax.bar([x - width / 2 for x in xs], wall, width, label="wall")
        bc = ax.bar([x + width / 2 for x in xs], cpu, width, label="CPU (own process)")
        for bars, key in ((bw, "wall_x"), (bc, "cpu_x")):
            for bar, r in zip(bars, rows, strict=True):
                if r.get(key) is not None:
                    ax.annotate(fmt_x(r[key]), (bar.get_x() + bar.get_width() / 2,
                                                bar.get_height()),
                                ha="center", va="bottom", fontsize=7)
        ax.set_xticks(list(xs), [r["label"].replace(" (", "\n(") for r in rows], fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel("µs per operation (log)")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=8)
    if micro:
        ax = axes[0][n - 1]
        xs = range(len(micro))
        ax.bar([x - width / 2 for x in xs], [r["pymb_us"] for r in micro], width,
               label="pymb (C)")
        ax.bar([x + width / 2 for x in xs], [r["python_us"] for r in micro], width,
               label="pure Python")
        ax.set_xticks(list(xs), [r["what"] for r in micro], fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel("µs per call (log)")
        ax.set_title("Micro: CRC-16 and decode", fontsize=10)
        ax.legend(fontsize=8)
    m = result["meta"]
    fig.suptitle(f"pymb bench, {m['date']}: {m['cpu']}, {m['cores']} cores, {m['python']}, "
                 f"libmodbus {m['libmodbus']}", fontsize=9)
    fig.tight_layout()
    ext = os.path.splitext(path)[1].lower()

    def write(fd: int, _tmp: str) -> None:
        with os.fdopen(fd, "wb") as f:
            if ext == ".svg":
                fig.savefig(f, format="svg", metadata={"Creator": PLOT_MARK})
            else:
                fig.savefig(f, format="png", dpi=120, metadata={"Software": PLOT_MARK})

    try:
        write_beside(path, ".pymb-bench-", ext, write, keep_mode=False)
    finally:
        plt.close(fig)
