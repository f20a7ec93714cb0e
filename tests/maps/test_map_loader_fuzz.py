"""Whatever a map file says, the loader answers with a Map or one MapError:
never another exception (random documents of the format's own keys and
values of every TOML kind, hypothesis)."""

from __future__ import annotations

import json
from typing import Any

from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from pymb import maps
from pymb.maps.fields import BLOCK_KEYS, POINT_KEYS

KEYS = sorted(set(POINT_KEYS) | set(BLOCK_KEYS) | {"nmae", "adress"})
WORDS = ["u16", "i16", "u32", "f32", "f64", "u64", "sm16", "bit", "bits", "string", "raw", "bool",
         "u8_hi", "i8_lo", "f16", "holding", "input", "coil", "discrete", "ABCD", "CDAB", "BADC",
         "DCBA", "BA", "GHEFCDAB", "rw", "r", "w", "fast", "both", "high", "low", "ascii",
         "utf-8", "channels", "x", "", "a b", "p", "q", "gauge", "state"]


def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v) if v == v and abs(v) != float("inf") else "nan"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return "{ " + ", ".join(f"{json.dumps(str(k))} = {toml_value(x)}" for k, x in v.items()) + " }"


def loads_or_message(text: str) -> maps.Map | str:
    """The map, or the MapError's message; any other exception propagates."""
    try:
        return maps.loads(text, source="fuzz.toml")
    except maps.MapError as e:
        return str(e)


scalars = st.one_of(st.integers(-70000, 70000), st.sampled_from([0, 1, 2, 4, 65535, 0xFFFF]),
                    st.floats(allow_nan=False, allow_infinity=False, width=32),
                    st.sampled_from(WORDS), st.booleans())
values = st.one_of(scalars, st.lists(scalars, max_size=3),
                   st.dictionaries(st.sampled_from(["0", "1", "0xFFFF", "-1", "x", "channels",
                                                    "humidity_unit", "3"]), scalars, max_size=3))
extras = st.dictionaries(st.sampled_from(KEYS), values, max_size=5)
# most entries start as a plausible point, so that the checks past the first ones run too
base = st.fixed_dictionaries({
    "name": st.sampled_from(["p", "q", "r", "s"]),
    "address": st.integers(0, 12),
    "type": st.sampled_from(["u16", "i16", "u32", "f32", "u64", "sm16", "bit", "bits",
                             "string", "raw", "u8_hi", "f16"]),
})
entries = st.one_of(extras, st.builds(lambda b, e: {**b, **e}, base, extras))


@settings(max_examples=700, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(points=st.lists(st.tuples(st.sampled_from(["point", "block"]), entries), max_size=4),
       options=st.dictionaries(st.sampled_from(["channels", "humidity_unit", "x"]), scalars,
                               max_size=2),
       group=st.booleans())
def test_the_loader_answers_a_map_or_a_map_error(points: list[tuple[str, dict[str, Any]]],
                                                 options: dict[str, Any], group: bool) -> None:
    text = 'schema = "pymb.map/1"\n[device]\nid = "t"\n'
    if options:
        text += "[device.options]\n" + "".join(f"{k} = {toml_value(v)}\n"
                                               for k, v in options.items())
    if group:
        text += "[groups]\nfast = { interval = 1.0 }\n"
    for kind, fields in points:
        if kind == "block" and "address" in fields:
            fields = {("first" if k == "address" else k): v for k, v in fields.items()}
        text += f"[[{kind}]]\n" + "".join(f"{k} = {toml_value(v)}\n" for k, v in fields.items())
    refused = loads_or_message(text)
    if isinstance(refused, str):
        assert refused.startswith("fuzz.toml: ")
        assert "\n" not in refused
        event("refused")
        return
    m = refused
    event(f"loaded with {len(m.points)} points")
    for name, p in m.points.items():  # a map that loads also decodes anything
        regs = [0xFFFF] * p.span
        m.decode_state(name, regs)
        maps.Decoder(m, [name]).read(regs)


DEVICE = ["id", "default_address", "addresses", "address_base", "table", "order", "model"]
LIMITS = ["max_registers", "max_bits", "max_gap", "readable", "split_on_exception"]
TIMING = ["response_timeout", "turnaround", "offline_after", "offline_retry"]
IDENTIFY = ["point", "range", "equals", "regex"]


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(device=st.dictionaries(st.sampled_from(DEVICE), values, max_size=3),
       limits=st.dictionaries(st.sampled_from(LIMITS), values, max_size=3),
       timing=st.dictionaries(st.sampled_from(TIMING), values, max_size=2),
       identify=st.lists(st.dictionaries(st.sampled_from(IDENTIFY), values, max_size=3),
                         max_size=2),
       groups=st.dictionaries(st.sampled_from(["fast", "x y"]), values, max_size=2))
def test_the_sections_answer_a_map_or_a_map_error(device: dict[str, Any], limits: dict[str, Any],
                                                  timing: dict[str, Any],
                                                  identify: list[dict[str, Any]],
                                                  groups: dict[str, Any]) -> None:
    device = {"id": "t", **device}

    def table(name: str, fields: dict[str, Any]) -> str:
        return f"[{name}]\n" + "".join(f"{json.dumps(k)} = {toml_value(v)}\n"
                                       for k, v in fields.items())

    text = ('schema = "pymb.map/1"\n' + table("device", device) + table("device.limits", limits)
            + table("device.timing", timing) + table("groups", groups)
            + '[[point]]\nname = "p"\naddress = 1\ntype = "string"\ncount = 2\n'
            + "".join("[[identify]]\n" + "".join(f"{k} = {toml_value(v)}\n"
                                                 for k, v in rule.items())
                      for rule in identify))
    refused = loads_or_message(text)
    if isinstance(refused, str):
        assert refused.startswith("fuzz.toml: ")
