"""A NaN (and, for seconds, an infinity) in a map is a load error naming the
key: TOML writes them as ``nan`` and ``inf``, and a map that loaded one would
refuse every write (``valid = [nan, 10]``), never poll (``interval = nan``) or
wait forever (``response_timeout = inf``)."""

from __future__ import annotations

import pytest

from pymb import maps

HEAD = 'schema = "pymb.map/1"\n[device]\nid = "t"\ntable = "holding"\n'
POINT = '[[point]]\nname = "a"\naddress = 0\ntype = "u16"\naccess = "rw"\n'


@pytest.mark.parametrize(("text", "point", "key"), [
    ('[groups]\nfast = { interval = nan }\n' + POINT, None, "interval"),
    ('[groups]\nfast = { interval = inf }\n' + POINT, None, "interval"),
    ('[device.timing]\nresponse_timeout = inf\n' + POINT, None, "response_timeout"),
    ('[device.timing]\nturnaround = nan\n' + POINT, None, "turnaround"),
    ('[device.timing]\ninter_request_gap = inf\n' + POINT, None, "inter_request_gap"),
    ('[device.timing]\nafter_connect = nan\n' + POINT, None, "after_connect"),
    ('[device.timing]\noffline_retry = nan\n' + POINT, None, "offline_retry"),
    ('[device.options]\nunit = nan\n' + POINT, None, "unit"),
    (POINT + 'valid = [nan, 10]\n', "a", "valid"),
    (POINT + 'valid = [0, nan]\n', "a", "valid"),
    (POINT + 'deadband = nan\n', "a", "deadband"),
    (POINT + '[[identify]]\npoint = "a"\nrange = [nan, 1]\n', None, "range"),
    (POINT + '[[identify]]\npoint = "a"\nequals = nan\n', None, "equals"),
])
def test_nan_and_endless_seconds_are_refused(text: str, point: str | None, key: str) -> None:
    with pytest.raises(maps.MapError) as info:
        maps.loads(HEAD + text, source="t.toml")
    e = info.value
    assert (e.source, e.point, e.key) == ("t.toml", point, key), str(e)
    assert str(e).startswith("t.toml: ")
    assert "\n" not in str(e)


def test_an_open_valid_bound_and_an_options_unbounded_max_still_load() -> None:
    m = maps.loads(HEAD + '[device.options]\nn = { default = 2, min = 1 }\n'
                   + POINT + 'valid = [-inf, 100]\n', source="t.toml")
    assert m.points["a"].valid == (-float("inf"), 100)
    assert m.encode("a", 100) == [100]
    assert m.configure(n=1000).options["n"] == 1000
