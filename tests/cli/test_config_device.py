"""``pymb config`` changes the settings of a device read through the
CoolPro's view (its map's ``[device] view``): any other device is a one-line
usage error before any I/O (the port is never opened)."""

from __future__ import annotations

from conftest import run_pymb


def test_pymb_config_of_another_device_is_a_one_line_error() -> None:
    for device, kind in (("hub:7", "hub"), ("eastron-sdm120", "eastron-sdm120")):
        r = run_pymb("config", device, "--port", "/nonexistent/tty", "--set-address", "5")
        assert r.returncode == 2, r.stderr
        assert r.stdout == ""
        assert r.stderr == ("pymb config: pymb config changes a CoolPro's settings, "
                            f"not a {kind}'s: pymb config coolpro[:ADDRESS] ...\n")
