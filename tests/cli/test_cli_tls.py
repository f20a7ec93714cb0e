"""``--tcp mbaps://HOST[:PORT]`` on the command line and ``[bus.tls]`` in
``pymb log``'s TOML file, against ``pymb serve --tls`` in front of simulated
devices: docs/security.md's command lines and TOML run as written (the port
aside); refused certificates exit 4 in one line; option mistakes exit 2."""

from __future__ import annotations

import json
import re
import shlex
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import run_pymb
from docblocks import assert_shaped, claim, claim_one
from servekit import Served
from tlskit import make_certs
from wire_peers import pymodbus_server

from pymb.errors import InvalidArgument
from pymb.logger.config import config_from_toml, load_config
from pymb.sim.simulator import SimulatorProcess


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_certs(tmp_path_factory.mktemp("clitls"))


@pytest.fixture(scope="module")
def sim() -> Iterator[SimulatorProcess]:
    with SimulatorProcess(["coolpro", "eastron-sdm120:2", "--tcp", "127.0.0.1:0"],
                          quiet=True) as s:
        yield s


def _serve(certs: Path, sim: SimulatorProcess, server: str = "server") -> Served:
    return Served("--tcp", sim.endpoint, "--tls", "--cert", str(certs / f"{server}.pem"),
                  "--key", str(certs / f"{server}.key"), "--ca", str(certs / "ca.pem"),
                  "--write-roles", "operator", "--quiet")


@pytest.fixture(scope="module")
def served(certs: Path, sim: SimulatorProcess) -> Iterator[Served]:
    with _serve(certs, sim) as s:
        yield s


def _argv(text: str, port: int) -> list[str]:
    argv = shlex.split(text)
    assert argv[:2] == ["pymb", "read"]
    return [a.replace("mbaps://localhost", f"mbaps://localhost:{port}")
            .replace("mbaps://127.0.0.1", f"mbaps://127.0.0.1:{port}") for a in argv[1:]]


def test_the_guides_read_over_tls(certs: Path, served: Served) -> None:
    block = claim_one("docs/security.md", "sh", how="run", contains="mbaps://localhost --ca")
    r = run_pymb(*_argv(block.text, served.port), cwd=certs, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "Input Voltage" in r.stdout
    assert "Temperature" in r.stdout


def test_the_guides_wrong_name_exits_4_in_one_line(certs: Path, served: Served) -> None:
    block = claim_one("docs/security.md", "sh", how="run", contains="--server-name")
    r = run_pymb(*_argv(block.text, served.port), cwd=certs, timeout=60)
    assert r.returncode == 4, r.stderr
    assert r.stdout == ""
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    assert_shaped(claim_one("docs/security.md", "text", how="compare",
                            contains="Hostname mismatch"), lines)


@pytest.mark.parametrize(("server", "ca", "words"), [
    ("server-expired", "ca.pem", "certificate has expired"),
    ("server", "other/ca.pem", "(not signed by the CA given)"),
    ("server", None, "(not signed by any of the system's trusted CAs)"),
])
def test_refused_server_certificates_exit_4_in_one_line(
        certs: Path, sim: SimulatorProcess, server: str, ca: str | None, words: str) -> None:
    cas = [] if ca is None else ["--ca", str(certs / ca)]
    with _serve(certs, sim, server) as s:
        r = run_pymb("read", "coolpro:40", "--tcp", f"mbaps://127.0.0.1:{s.port}", *cas,
                     "--cert", str(certs / "operator.pem"), "--key",
                     str(certs / "operator.key"), timeout=60)
    assert r.returncode == 4, r.stderr
    assert r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith(f"pymb read: cannot open 127.0.0.1:{s.port}: the server's "
                               "certificate was refused: ")
    assert words in r.stderr


def test_a_map_device_read_as_json_by_a_viewer(certs: Path, served: Served) -> None:
    viewer = ["--ca", str(certs / "ca.pem"), "--cert", str(certs / "viewer.pem"), "--key",
              str(certs / "viewer.key"), "--server-name", "localhost"]
    r = run_pymb("read", "eastron-sdm120:2", "--tcp", f"mbaps://127.0.0.1:{served.port}",
                 *viewer, "--json", timeout=60)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["values"]["voltage_v"] == pytest.approx(230.5)


@pytest.mark.parametrize(("args", "words"), [
    (["--tcp", "127.0.0.1:502", "--ca", "ca.pem"], "need --tcp mbaps://HOST[:PORT]"),
    (["--port", "/dev/ttyUSB0", "--cert", "operator.pem"], "need --tcp mbaps://HOST[:PORT]"),
    (["--tcp", "mbaps://127.0.0.1", "--ca", "nope.pem"], "--ca 'nope.pem': no such file"),
    (["--tcp", "mbaps://127.0.0.1", "--key", "operator.key"], "--key needs --cert"),
    (["--tcp", "mbaps://127.0.0.1", "--cert", "operator.pem", "--key", "viewer.key"],
     "is not the private key of"),
    (["--tcp", "mbaps://127.0.0.1", "--cert", "operator.pem"], "holds no private key"),
    (["--tcp", "mbaps://", "--ca", "ca.pem"], "--tcp needs mbaps://HOST[:PORT]"),
    (["--rtu-over-tcp", "mbaps://127.0.0.1"], "RTU over TCP has no TLS"),
    # Modbus over UDP and ASCII have no TLS: the options are refused, not ignored
    (["--udp", "127.0.0.1:502", "--ca", "ca.pem"],
     "need --tcp mbaps://HOST[:PORT], not --udp 127.0.0.1:502"),
    (["--ascii", "--port", "/dev/ttyUSB0", "--cert", "operator.pem", "--key", "operator.key"],
     "need --tcp mbaps://HOST[:PORT]"),
    # a URL where HOST:PORT goes is a mistake, not a host name to resolve
    (["--udp", "mbaps://127.0.0.1:802"], "--udp needs HOST:PORT, got 'mbaps://127.0.0.1:802'"),
    (["--tcp", "mbap://127.0.0.1:502"], "--tcp needs HOST:PORT, got 'mbap://127.0.0.1:502'"),
    # an IPv6 address without its brackets is not a host name ':' to resolve
    (["--tcp", "::1:502"], "--tcp: an IPv6 address goes in brackets, [ADDRESS]:PORT"),
    (["--udp", "fe80::1:502"], "--udp: an IPv6 address goes in brackets"),
])
def test_option_mistakes_exit_2_before_anything_is_sent(certs: Path, args: list[str],
                                                        words: str) -> None:
    r = run_pymb("read", "coolpro:40", *args, cwd=certs, timeout=60)
    assert r.returncode == 2, r.stderr
    assert words in r.stderr
    assert r.stderr.count("\n") == 1, r.stderr


def test_the_guides_logger_toml_logs_over_tls(certs: Path, served: Served) -> None:
    (block,) = claim("docs/security.md", "toml", how="run")
    toml = block.text.replace('"mbaps://localhost"', f'"mbaps://localhost:{served.port}"')
    assert toml != block.text
    (certs / "logger.toml").write_text(toml)
    cfg = load_config(certs / "logger.toml")
    tls = cfg.buses[0].tls
    assert tls is not None
    assert tls.ca == str(certs / "ca.pem")  # relative to the file
    r = run_pymb("log", "--config", "logger.toml", "--seconds", "3", "--quiet", cwd=certs,
                 timeout=60)
    assert r.returncode == 0, r.stderr
    r = run_pymb("info", str(certs / "plant.sqlite"), timeout=60)
    for device in ("coolpro:40", "eastron-sdm120:2"):  # a facade and a map device
        m = re.search(rf"{device} on gateway \(mbaps://localhost:{served.port}\): (\d+) samples",
                      r.stdout)
        assert m is not None, r.stdout
        assert int(m.group(1)) > 0, r.stdout
    assert "faults      none" in r.stdout, r.stdout


@pytest.mark.parametrize(("bus", "words"), [
    ('tcp = "10.0.0.1:502"\n[bus.tls]\nca = "ca.pem"', 'tls needs tcp = "mbaps://HOST[:PORT]"'),
    ('tcp = "mbaps://10.0.0.1"\npipeline = 4', "pipeline is for a plain tcp bus"),
    ('tcp = "mbaps://10.0.0.1"\n[bus.tls]\ncafile = "ca.pem"', "unknown key 'cafile'"),
    ('tcp = "mbaps://10.0.0.1"\n[bus.tls]\nca = "nope.pem"', "[bus.tls]: ca"),
    ('tcp = "mbaps://10.0.0.1"\n[bus.tls]\ncheck_hostname = "no"', "check_hostname must be"),
])
def test_toml_tls_mistakes_are_named(certs: Path, bus: str, words: str) -> None:
    import tomllib
    text = f'[[bus]]\nname = "g"\n{bus}\n[[bus.device]]\ntype = "coolpro"\n'
    with pytest.raises(InvalidArgument, match=None) as e:
        config_from_toml(tomllib.loads(text), certs / "x.toml")
    assert words in str(e.value)


def test_the_logger_retries_a_refused_certificate_and_exits_4(certs: Path, served: Served,
                                                              tmp_path: Path) -> None:
    r = run_pymb("log", "coolpro:40", "--tcp", f"mbaps://127.0.0.1:{served.port}", "--ca",
                 str(certs / "ca.pem"), "--cert", str(certs / "operator.pem"), "--key",
                 str(certs / "operator.key"), "--server-name", "gateway.example",
                 "--seconds", "2", "--out", str(tmp_path / "log.sqlite"), "--quiet", timeout=60)
    assert r.returncode == 4, r.stderr
    lines = r.stderr.splitlines()
    refused = "the server's certificate was refused: Hostname mismatch"
    assert sum("retrying in" in line and refused in line for line in lines) >= 2, r.stderr
    assert lines[-1].startswith("pymb log: bus bus1 never opened its port: ")
    assert refused in lines[-1]
    assert "Traceback" not in r.stderr


def test_scan_over_tls_against_pymodbus(certs: Path) -> None:
    with pymodbus_server("tls", str(certs)) as port:
        r = run_pymb("scan", "--tcp", f"mbaps://127.0.0.1:{port}", "--ca", str(certs / "ca.pem"),
                     "--cert", str(certs / "operator.pem"), "--key", str(certs / "operator.key"),
                     "--server-name", "localhost", "--range", "1,17", "--json", timeout=120)
    assert r.returncode == 0, r.stderr
    found = {d["address"] for d in json.loads(r.stdout)["found"]}
    assert found == {1, 17}
