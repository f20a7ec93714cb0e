"""A newcomer's ``TcpClient("10.0.0.5:502")`` (the command line's spelling):
refused when the client is made, naming the call that means it, instead of a
connect that fails to resolve the host name ``10.0.0.5:502``."""

from __future__ import annotations

import pytest

import pymb


@pytest.mark.parametrize(("make", "said"), [
    (lambda: pymb.TcpClient("127.0.0.1:5020"), "TcpClient('127.0.0.1', 5020)"),
    (lambda: pymb.RtuOverTcpClient("gw.lan:4001"), "RtuOverTcpClient('gw.lan', 4001)"),
    (lambda: pymb.UdpClient("10.0.0.5:502"), "UdpClient('10.0.0.5', 502)"),
])
def test_a_host_with_its_port(make: object, said: str) -> None:
    with pytest.raises(pymb.InvalidArgument) as e:
        make()  # type: ignore[operator]
    assert str(e.value).endswith(f"has a port in it: the port is an argument of its own, {said}")
    assert isinstance(e.value, ValueError)


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "::1", "fe80::1", "plc-7.lan"])
def test_names_and_addresses_are_taken(host: str) -> None:
    client = pymb.TcpClient(host, 5020)
    assert (client.host, client.tcp_port) == (host, 5020)
