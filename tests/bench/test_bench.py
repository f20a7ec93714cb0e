"""``pymb bench``: the structure of its output, skipped contenders saying why,
ratios taken against the C program, nothing left running. No timing
assertions: speed targets live in the benchmark's output, never in tests."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
from array import array
from pathlib import Path
from typing import Any

import pytest
from conftest import PYMB, PYMB_ENV, ROOT
from docblocks import claim_one

import pymb
from pymb.bench import cprogram, pure, report, runner
from pymb.bench.contenders import CONTENDERS, NAMES
from pymb.bench.options import EXTRA_SECTIONS, QUICK_BUDGET, SECTIONS
from pymb.bench.runner import Options, RaceEntry, summary
from pymb.bench.worker import SPANS, Canary
from pymb.child import Child, pymb_argv
from pymb.cli import main
from pymb.devices import HUB
from pymb.devices.hub import decode_hub
from pymb.devices.hubreading import HUB_REGISTERS


def _have_c() -> bool:
    return shutil.which("cc") is not None and subprocess.run(
        ["pkg-config", "--exists", "libmodbus"], check=False).returncode == 0


needs_c = pytest.mark.skipif(not _have_c(), reason="no cc or libmodbus development files")


def _children() -> list[str]:
    """Command lines of this process's live children (zombies excluded)."""
    me = os.getpid()
    out = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[1]) == me and fields[0] != "Z":
            out.append(cmd)
    return out


def _bench(capsys: pytest.CaptureFixture[str], *args: str) -> dict[str, Any]:
    assert main(["bench", "--quick", "-q", "--json", *args]) == 0
    result: dict[str, Any] = json.loads(capsys.readouterr().out)
    return result


# -- the pure-Python pieces the Python contenders use ----------------------------------------


def test_pure_crc_matches_the_documents_and_pymb() -> None:
    # [NOTES] worked values: 28 04 00 00 00 01 -> 0x3336; 28 04 02 5F B4 -> 0x71DD.
    assert pure.crc16(bytes.fromhex("280400000001")) == 0x3336
    assert pure.crc16(bytes.fromhex("2804025FB4")) == 0x71DD
    data = bytes(range(255))
    assert pure.crc16(data) == pymb.crc16(data)
    req = pure.read_request(0x28, 0x04, 0, 1)
    assert req == bytes.fromhex("280400000001") + bytes((0x36, 0x33))


def test_pure_decoders_match_pymb() -> None:
    regs = runner.hub_registers(seed=3)
    regs[131 - 31] = 0x00FF  # channel 1's humidity: "no sensor" in the 1 % unit only
    for unit in (0.1, 1):
        got = pure.decode_hub(list(regs), unit)
        want = decode_hub(regs, unit).values
        assert len(got) == HUB_REGISTERS
        assert math.isnan(got[100]) == (unit == 1)
        for g, w in zip(got, want, strict=True):
            assert (math.isnan(g) and math.isnan(w)) or g == pytest.approx(w, rel=1e-12)
    # [NOTES]: 5F B4 0C B2 5D C0 0C 80 = 24.5 V, 3.25 A, 24.0 V, 3.20 A; uptime 4464, 1 = 70000 s.
    t = pure.decode_telemetry([0x5FB4, 0x0CB2, 0x5DC0, 0x0C80, 25000, 4464, 1, 0x0041])
    assert t == pytest.approx([24.5, 3.25, 24.0, 3.2, 25.0, 70000.0, 65.0])


def test_sweep_is_six_requests_of_at_most_125() -> None:
    assert len(SPANS) == 6
    assert all(n <= HUB.limits.max_registers for _, n in SPANS)
    assert SPANS[0][0] == HUB.points["temperature_c"].address == 31
    assert sum(n for _, n in SPANS) == HUB_REGISTERS


def test_canary_catches_a_wrong_sweep() -> None:
    canary = Canary(0, 1)
    raw = [0xFFFF, 215] + [0] * (HUB_REGISTERS - 2)
    values = [math.nan, 21.5] + [0.0] * (HUB_REGISTERS - 2)
    canary.check(raw, values)
    with pytest.raises(RuntimeError):
        canary.check([*raw[1:], 0], values)  # shifted by one register
    with pytest.raises(RuntimeError):
        canary.check(raw, [0.0, 21.5, *values[2:]])  # not decoded
    with pytest.raises(RuntimeError):
        canary.check(raw[:-1], values[:-1])


def test_reference_rejects_shifted_registers() -> None:
    ref = runner.Reference()
    regs = runner.hub_registers()
    ref.check_sweep(list(regs), list(decode_hub(regs).values))
    shifted = [*regs[1:], 0]
    with pytest.raises(ValueError, match="layout"):
        ref.check_sweep(shifted, list(decode_hub(array("H", shifted)).values))
    wrong = list(decode_hub(regs).values)
    wrong[ref.k_val] += 1.0
    with pytest.raises(ValueError, match="decoder"):
        ref.check_sweep(list(regs), wrong)


# -- ratios ------------------------------------------------------------------------------------


def _entry(name: str, rounds: list[tuple[int, list[int]]]) -> RaceEntry:
    c = next(c for c in CONTENDERS if c.name == name)
    e = RaceEntry(c, version="1")
    e.rounds["hub"] = rounds
    return e


def test_ratios_are_paired_per_round_against_c() -> None:
    c = _entry("c", [(1000, [100, 110, 90]), (2000, [200, 200, 200]), (900, [100, 100, 100])])
    p = _entry("pymb", [(1500, [150, 160, 140]), (2000, [220, 230, 210]),
                        (900, [100, 100, 100])])
    rows = {r["name"]: r for r in summary([c, p], "hub", 3)["rows"]}
    assert rows["c"]["wall_x"] == 1.0
    assert rows["c"]["cpu_x"] == 1.0
    assert rows["pymb"]["wall_x"] == pytest.approx(statistics.median([1.5, 1.1, 1.0]))
    assert rows["pymb"]["cpu_x"] == pytest.approx(statistics.median([1.5, 1.0, 1.0]))
    assert rows["pymb"]["wall_us"] == pytest.approx(
        statistics.median([150, 160, 140, 220, 230, 210, 100, 100, 100]) / 1e3)


def test_no_c_program_means_no_ratios() -> None:
    p = _entry("pymb", [(1500, [150, 160, 140])])
    c = _entry("c", [])
    c.status, c.reason = "skipped", "no C compiler"
    section = summary([c, p], "hub", 3)
    assert section["baseline"] is None
    row = next(r for r in section["rows"] if r["name"] == "pymb")
    assert "wall_x" not in row
    assert "cpu_x" not in row
    table = report._workload_table("t", "n", section)
    assert any("no ratios" in f for f in table.footer)
    assert any("no C compiler" in f for f in table.footer)


# -- end to end --------------------------------------------------------------------------------


@needs_c
def test_c_program_builds_warning_free(tmp_path: Path) -> None:
    exe, warnings = cprogram.build(str(tmp_path))
    assert os.access(exe, os.X_OK)
    assert warnings == ""  # -Wall -Wextra clean


@needs_c
def test_c_program_runs_clean_under_the_sanitizers(capsys: pytest.CaptureFixture[str],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # csrc/examples/bench_sweep.c built with ASan and UBSan, swept and verified
    # against the simulated hub and CoolPro: any finding aborts it, failing the run.
    monkeypatch.setenv("PYMB_BENCH_CFLAGS", "-O1 -g -fsanitize=address,undefined "
                       "-fno-sanitize-recover=all -fno-omit-frame-pointer")
    monkeypatch.setenv("ASAN_OPTIONS", "detect_leaks=1:abort_on_error=1")
    result = _bench(capsys, "--only", "c", "--sections", "sweep")
    (c,) = result["contenders"]
    assert c["status"] == "ok", c
    rows = result["sweep"]["hub"]["rows"] + result["sweep"]["telemetry"]["rows"]
    assert [r["status"] for r in rows] == ["ok", "ok"], rows


@needs_c
def test_sweep_compare_times_both_reads_in_c(tmp_path: Path) -> None:
    # csrc/examples/sweep_compare: docs/benchmarks.md's measurement of pymb's C path
    # against plain libmodbus, in C, for the hub sweep and the CoolPro read.
    made = subprocess.run(["make", "-s", "-C", str(ROOT / "csrc"), "build/sweep_compare"],
                          capture_output=True, text=True, timeout=300, check=False)
    assert made.returncode == 0, made.stderr
    # The two commands as docs/benchmarks.md shows them (3 rounds instead of 30).
    block = claim_one("docs/benchmarks.md", "sh", how="run", contains="sweep_compare")
    simulate, compare = (shlex.split(line, comments=True) for line in block.lines()[:2])
    assert simulate[:2] == ["pymb", "simulate"]
    assert compare[0] == "./csrc/build/sweep_compare"
    link = tmp_path / "line"
    sim = Child("simulator", pymb_argv(*simulate[1:], "--link", str(link)))
    try:
        sim.readline(30)
        argv = [str(ROOT / compare[0]), *(str(link) if a == "/dev/pts/N" else a
                                          for a in compare[1:-1]), "3"]
        r = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    finally:
        sim.stop()
    assert r.returncode == 0, r.stderr
    assert "hub sweep, medians of 3 interleaved rounds" in r.stdout
    assert "CoolPro telemetry (8 input registers, decoded)" in r.stdout
    ratios = re.findall(r"\((\d+\.\d+)x, (\d+\.\d+)x\)", r.stdout)
    assert len(ratios) == 2, r.stdout
    assert all(float(x) > 0 for pair in ratios for x in pair)


@needs_c
def test_quick_run_structure_and_ratios(capsys: pytest.CaptureFixture[str]) -> None:
    result = _bench(capsys, "--only", "pymb,c", "--sections", "micro,sweep")
    meta = result["meta"]
    for key in ("date", "cpu", "cores", "python", "libmodbus", "pymb", "command"):
        assert meta[key], key
    assert meta["command"].startswith("pymb bench")
    assert [c["name"] for c in result["contenders"]] == ["c", "pymb"]
    assert all(c["status"] == "ok" and c["version"] for c in result["contenders"])

    for workload in ("hub", "telemetry"):
        section = result["sweep"][workload]
        assert section["baseline"] == "c"
        rows = {r["name"]: r for r in section["rows"]}
        c, p = rows["c"], rows["pymb"]
        assert c["wall_x"] == 1.0
        assert c["cpu_x"] == 1.0
        for r in (c, p):
            assert r["wall_us"] > 0
            assert r["cpu_us"] > 0
            assert r["rounds"] == result["meta"]["plan"]["rounds"]
        # the ratio is the median of per-round ratios to the C program's round
        assert p["wall_x"] == pytest.approx(statistics.median(
            a / b for a, b in zip(p["round_wall_us"], c["round_wall_us"], strict=True)))
        assert p["cpu_x"] == pytest.approx(statistics.median(
            a / b for a, b in zip(p["round_cpu_us"], c["round_cpu_us"], strict=True)))

    micro = {r["name"]: r for r in result["micro"]["rows"]}
    assert set(micro) == {"crc16", "decode"}
    for r in micro.values():
        assert r["speedup"] == pytest.approx(r["python_us"] / r["pymb_us"])

    # --quick declares no targets; what a full run would judge comes from the same figures.
    assert result["targets"] == []
    targets = {t["what"]: t for t in runner.targets(result)}
    assert targets["hub sweep wall time, pymb / C"]["measured"] == pytest.approx(
        result["sweep"]["hub"]["rows"][1]["wall_x"])
    assert all(t["met"] in (True, False) for t in targets.values())
    assert _children() == []


def test_skipped_contenders_say_why(monkeypatch: pytest.MonkeyPatch,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    real = importlib.util.find_spec

    def find_spec(name: str, *a: Any) -> Any:
        return None if name == "minimalmodbus" else real(name, *a)

    monkeypatch.setattr("pymb.bench.contenders.importlib.util.find_spec", find_spec)
    monkeypatch.setenv("CC", "no-such-compiler-for-pymb")
    assert main(["bench", "--quick", "-q", "--only", "c,minimalmodbus",
                 "--sections", "sweep"]) == 0
    text = capsys.readouterr().out
    assert "minimalmodbus: skipped: not installed" in text
    assert f"{sys.executable} -m pip install 'pymodbus" in text
    assert "C (libmodbus): skipped: cannot build the C program: no C compiler" in text
    assert "no ratios" in text

    result = _bench(capsys, "--only", "c,minimalmodbus", "--sections", "sweep")
    for c in result["contenders"]:
        assert c["status"] == "skipped"
        assert c["reason"]
    assert _children() == []


def test_unknown_names_are_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--only", "pymb,modbus-tk"]) == 2
    assert "--only takes names from" in capsys.readouterr().err
    assert main(["bench", "--sections", "fast"]) == 2
    assert main(["bench", "--rounds", "0"]) == 2


@needs_c
def test_interrupt_stops_every_child(monkeypatch: pytest.MonkeyPatch) -> None:
    def interrupted(*args: Any, **kw: Any) -> None:
        assert len(_children()) >= 4  # two simulators and two contenders are running
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "race", interrupted)
    assert main(["bench", "--quick", "-q", "--only", "pymb,c", "--sections", "sweep"]) == 130
    assert _children() == []


def test_reports_from_one_result(tmp_path: Path) -> None:
    result = _synthetic()
    text = report.to_text(result)
    md = report.to_markdown(result)
    for out in (text, md):
        assert "Hub sweep" in out
        assert "CoolPro telemetry" in out
        assert "Targets" in out
        assert "pymb bench --quick" in out
    assert "| contender | wall |" in md
    assert "|---|---:|" in md
    assert "`pymb bench --quick`" in md
    json.loads(report.to_json(result))
    pytest.importorskip("matplotlib")
    png = tmp_path / "bars.png"
    report.plot(result, str(png))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_quick_report_is_indicative_and_declares_no_targets(capsys: pytest.CaptureFixture[str],
                                                           tmp_path: Path) -> None:
    result = _synthetic(quick=True)
    result["targets"] = []
    for out in (report.to_text(result), report.to_markdown(result)):
        assert "indicative" in out
        assert "declares no targets" in out
        assert "Targets" not in out
        assert "≤ 1 µs" not in out
        assert all("[indicative: --quick]" in t.title for t in report.tables(result))
    # --plot to a path that cannot be written fails at once, before any measuring.
    assert main(["bench", "--quick", "--plot", str(tmp_path / "no" / "such" / "dir.png")]) == 2
    assert "no such directory" in capsys.readouterr().err
    assert main(["bench", "--quick", "--plot", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def _synthetic(quick: bool = False) -> dict[str, Any]:
    def rows(base: float) -> dict[str, Any]:
        out = []
        for i, c in enumerate(CONTENDERS[:3]):
            out.append({"name": c.name, "label": c.label, "version": "1", "status": "ok",
                        "reason": "", "how": c.how, "wall_us": base * (1 + i),
                        "cpu_us": base / 4 * (1 + i), "wall_x": 1.0 + i, "cpu_x": 1.0 + i})
        return {"baseline": "c", "rows": out}

    opts = Options(quick=quick, command="pymb bench --quick")
    result = {"meta": runner.meta(opts),
              "contenders": [{"name": c.name, "label": c.label, "version": "1",
                              "status": "ok", "reason": "", "how": c.how}
                             for c in CONTENDERS],
              "sweep": {"baud": 115200, "hub": rows(400.0), "telemetry": rows(40.0)},
              "micro": {"repeat": 5, "rows": [
                  {"name": "crc16", "what": "CRC", "pymb_us": 0.5, "python_us": 12.0,
                   "speedup": 24.0, "target_us": 1.0, "pymb_call": "a", "python_call": "b"}]}}
    result["targets"] = runner.targets(result)
    return result


@pytest.mark.slow
@needs_c
def test_whole_quick_bench_as_a_user_runs_it(tmp_path: Path) -> None:
    """``python -m pymb bench --quick --json --plot``: every section, every contender."""
    env = PYMB_ENV
    png = tmp_path / "bench.png"
    done = subprocess.run([*PYMB, "bench", "--quick", "--json",
                           "--plot", str(png)], capture_output=True, text=True, timeout=600,
                          env=env)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert {"micro", "sweep", "wire", "scaling", "targets"} <= set(result)
    assert [c["name"] for c in result["contenders"]] == list(NAMES)
    for c in result["contenders"]:
        assert c["status"] == "ok" or c["reason"]
    assert [r["buses"] for r in result["scaling"]["rows"]] == [1, 2, 4, 8]
    assert {r["baud"] for r in result["wire"]["rows"]} == {9600, 115200}
    assert png.exists()
    assert "pymb bench: scaling" in done.stderr  # progress on stderr, JSON alone on stdout


def test_fleet_section_through_a_real_mosquitto(capsys: pytest.CaptureFixture[str]) -> None:
    """pymb's forwarder loses nothing across the 3 s broker outage; the figures are
    there for every publisher, side by side."""
    result = _bench(capsys, "--only", "pymb", "--sections", "fleet")
    fleet = result["fleet"]
    assert fleet["status"] == "ok", fleet
    rows = {r["label"]: r for r in fleet["rows"]}
    assert set(rows) == {"pymb (SQLite outbox, QoS 1)", "paho, QoS 0", "paho, QoS 1"}
    pymb = rows["pymb (SQLite outbox, QoS 1)"]
    assert pymb["outage_lost"] == 0
    assert pymb["burst_lost"] == 0
    assert pymb["outage_sent"] == fleet["outage_samples"]
    for r in rows.values():
        assert r["throughput_per_s"] > 0
        assert r["latency_p50_ms"] > 0
    from pymb.bench import report
    assert "Fleet: samples through a local mosquitto" in report.to_markdown(result)


def test_logger_section_measures_pairs_bytes_and_layouts(
        capsys: pytest.CaptureFixture[str]) -> None:
    """``pymb bench --sections logger``: bytes and CPU per sample against the bare
    read, report by exception, the layouts, and the logger's targets."""
    result = _bench(capsys, "--only", "pymb", "--sections", "logger")
    s = result["logger"]
    # bytes per stored sample of each group of the shipped maps
    assert {r["map"] for r in s["maps"]} == {"eastron-sdm120", "eastron-sdm630", "generic-vfd"}
    for r in s["maps"]:
        assert r["bytes_per_sample"] >= r["blob_bytes"] > 0
    for key in ("hub", "coolpro", "hub_on-change"):
        r = s["runs"][key]
        assert r["samples"] > 0
        assert r["bare_cpu_us"] > 0
        assert r["log_cpu_us"] > 0
        assert len(r["pairs"]) == s["rounds"]
        assert r["cpu_x"] > 0
    assert s["runs"]["hub"]["stored_samples"] == s["runs"]["hub"]["samples"]
    assert 1400 < s["runs"]["hub"]["bytes_per_sample"] < 4000  # 1,400 bytes of registers
    assert s["runs"]["hub_on-change"]["stored_samples"] < s["runs"]["hub_on-change"]["samples"]
    for sp in s["spans"].values():
        assert sp["samples"] > 0
        assert sp["channel_rows"] >= 100
    assert [r["layout"] for r in s["layouts"]] == ["format2", "ints", "format1"]
    for r in s["layouts"]:
        assert all("samples_time" in q["plan"] for q in r["queries"].values())
    assert result["targets"] == []  # --quick judges no target, but the section has them
    from pymb.bench import logbench

    whats = [t[0] for t in logbench.targets(s)]
    assert any("per hub sweep" in w for w in whats)
    assert any("CoolPro" in w for w in whats)
    text = report.to_text(result)
    assert "Logger: pymb log against the bare read" in text
    assert "issue" not in text.lower()  # no history of the work in the program's output
    assert "Storage layouts" in text
    # SD wear: every kind at both rates, pymb and the naive logger, measured
    wear = {(r["mode"], r["kind"], r["interval"]): r for r in s["wear"]
            if r["commit_interval"] is None}
    assert len(wear) == 8
    assert [(r["kind"], r["interval"]) for r in s["wear"] if r["commit_interval"]] == [
        ("hub", 1.0), ("coolpro", 1.0)]  # beside them, each committed every LONGER_COMMIT s
    for r in wear.values():
        assert r["samples"] > 0
        assert r["stored"] > 0
    for kind in ("hub", "coolpro"):  # one commit per sample writes far more per sample
        assert wear["naive", kind, 0.0]["written_per_sample"] > \
            wear["pymb", kind, 0.0]["written_per_sample"]
    assert any("bytes written / stored" in w for w in whats)
    assert any("KB written per second, CoolPro every 1 s" in w for w in whats)
    assert all(r.get("steady_bps") is None or r["steady_bps"] > 0 for r in s["wear"])
    assert "SD wear: bytes written to the disk per sample" in text


def test_every_section_has_a_quick_budget_and_the_default_ones_fit_a_minute() -> None:
    """``--quick`` is sized per section: each section (the extra ones too)
    declares the seconds its quick plan may take, and those of a default run
    add up to less than a minute."""
    assert set(QUICK_BUDGET) == set(SECTIONS) | set(EXTRA_SECTIONS)
    assert all(v > 0 for v in QUICK_BUDGET.values())
    assert sum(QUICK_BUDGET[s] for s in SECTIONS) < 60


def test_a_run_times_each_section_against_its_budget(
        capsys: pytest.CaptureFixture[str]) -> None:
    result = _bench(capsys, "--only", "pymb", "--sections", "plan,micro")
    took = result["meta"]["section_seconds"]
    assert list(took) == ["micro", "plan"]  # in the order run
    assert all(s > 0 for s in took.values())
    assert result["meta"]["quick_budget"] == {"plan": QUICK_BUDGET["plan"],
                                              "micro": QUICK_BUDGET["micro"]}
    text = report.to_text(result)
    line = next(ln for ln in text.splitlines() if ln.startswith("  sections "))
    assert re.fullmatch(r"  sections  micro [\d.]+ s, plan [\d.]+ s \(\d+ s(; over the quick "
                        r"budget: [a-z, ]+)?\)", line), line
    result["meta"]["section_seconds"]["plan"] = 99.0
    # (micro may be over its own on a loaded machine too)
    assert re.search(r"over the quick budget: (micro, )?plan\)", report.to_text(result))


def test_each_target_shows_its_measure_in_its_unit() -> None:
    tg = [{"what": w, "target": "-", "measured": v, "unit": u, "met": True}
          for w, v, u in [("kb", 5.3, "KB/s"), ("t", 2.4, "us"), ("r", 1.25, "x"),
                          ("b", 2077.0, "B"), ("m", 46.3, "MB"), ("n", 2572102.0, "values/s")]]
    shown = {row[0]: row[2] for row in report._targets_table(tg).rows}
    assert shown == {"kb": "5.3 KB/s", "t": "2.4 µs", "r": "1.25\u00d7", "b": "2,077 B",
                     "m": "46.3 MB", "n": "2,572,102"}
