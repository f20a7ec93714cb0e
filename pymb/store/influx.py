"""InfluxDB line protocol, for files and stdout (``pymb log --format influx``).

So that Telegraf's ``inputs.execd`` can run pymb and feed its outputs::

    [[inputs.execd]]
      command = ["pymb", "log", "--port", "/dev/ttyUSB0", "--device", "hub:250",
                 "--format", "influx", "--out", "-", "--quiet"]
      signal = "none"
      data_format = "influx"

One line per CoolPro sample (measurement ``pymb_coolpro``) and per hub channel
(``pymb_hub``, tag ``channel``); tags ``bus``, ``device``, ``address``; the
decoded values as float fields (``status`` and ``uptime_s`` as integers), a
quantity with no value as a string field ``{quantity}_state`` saying why
(``no_sensor``, ``offline``, ...); events as ``pymb_event`` (tags ``kind``,
``bus``, ``device``; fields ``message``, ``code``). Timestamps in nanoseconds
(to the microsecond). A map device's sample is one line of measurement
``pymb_<map id>`` (``-`` as ``_``) with a tag ``group`` and a field per
point (``{point}_{N}`` for channel N of a block): integers as integers
(``i``; a ``u64`` point, which may pass 2**63, always unsigned, ``u``),
floats as floats, flags as booleans, text as strings, and
``{point}_state`` where it has no value.
"""

from __future__ import annotations

from pymb.devices.mapreading import MapReading
from pymb.devices.readings import has_own_view, map_reading, reading_dict
from pymb.maps import Value
from pymb.store.records import DeviceInfo, Event, Sample
from pymb.store.text import JsonlSink

__all__ = ["InfluxSink", "event_line", "sample_lines"]


def _tag(v: object) -> str:
    return str(v).replace("\\", "\\\\").replace(",", "\\,").replace("=", "\\=") \
        .replace(" ", "\\ ").replace("\n", "\\n")


def _str(v: str) -> str:
    return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def _ns(t: float) -> int:
    return round(t * 1e6) * 1000


def _tags(d: DeviceInfo) -> str:
    return f"bus={_tag(d.bus)},device={_tag(d.name)},address={d.address}"


def _field(name: str, v: Value, state: object, unsigned: bool = False) -> str:
    if v is None:
        return f"{name}_state={_str(str(state))}"
    if isinstance(v, bool):
        return f"{name}={'true' if v else 'false'}"
    if isinstance(v, int):
        return f"{name}={v}{'u' if unsigned else 'i'}"
    if isinstance(v, float):
        return f"{name}={v!r}"
    if isinstance(v, list):  # raw registers
        return f"{name}={_str(''.join(f'{r:04X}' for r in v))}"
    return f"{name}={_str(str(v))}"


def _map_line(sample: Sample, data: MapReading) -> str:
    fields = []
    for name, v in data.values.items():
        st = data.states.get(name)
        if isinstance(v, list) and data.map.points[name].block:
            states = st if isinstance(st, list) else [st] * len(v)
            fields += [_field(f"{name}_{c}", cv, cs)
                       for c, (cv, cs) in enumerate(zip(v, states, strict=False), 1)]
        else:  # a u64 is an unsigned field whatever its value: one type per field
            fields.append(_field(name, v, st, data.map.points[name].type == "u64"))
    d = sample.device
    tags = (f"bus={_tag(d.bus)},device={_tag(d.name)},address={d.address},"
            f"group={_tag(data.group or '-')}")
    measurement = "pymb_" + "".join(c if c.isalnum() else "_" for c in data.map.id)
    return f"{measurement},{tags} {','.join(fields)} {_ns(sample.time_utc)}"


def sample_lines(sample: Sample) -> list[str]:
    """A sample as line protocol (one line, or one per hub channel)."""
    if not has_own_view(sample.data):
        return [_map_line(sample, map_reading(sample.data))]
    d = reading_dict(sample.data)  # the values of sample_dict
    tags = _tags(sample.device)
    ts = _ns(sample.time_utc)
    if "states" in d:  # a reading by channel (a hub's)
        values, states = d["values"], d["states"]
        lines = []
        for ch in range(len(next(iter(values.values()), []))):
            fields = []
            for q, vs in values.items():
                v = vs[ch]
                if v is None:
                    fields.append(f"{q}_state={_str(states[q][ch])}")
                else:
                    fields.append(f"{q}={float(v)!r}")
            lines.append(f"pymb_hub,{tags},channel={ch + 1} {','.join(fields)} {ts}")
        return lines
    fields = []
    for q, v in d["values"].items():
        if v is None:
            fields.append(f"{q}_state=\"no_value\"")
        elif isinstance(v, int):  # a count or bit field (a CoolPro's status)
            fields.append(f"{q}={v}i")
        else:
            fields.append(f"{q}={float(v)!r}")
    return [f"pymb_coolpro,{tags} {','.join(fields)} {ts}"]


def event_line(e: Event) -> str:
    """An event as line protocol."""
    tags = f"kind={_tag(e.kind)},bus={_tag(e.bus)}"
    if e.device is not None:
        tags += f",device={_tag(e.device.name)}"
    fields = f"message={_str(e.message)}"
    if e.code is not None:
        fields += f",code={int(e.code)}i"
    return f"pymb_event,{tags} {fields} {_ns(e.time_utc)}"


class InfluxSink(JsonlSink):
    """Line protocol to a file or stdout (the text-file handling of the JSONL sink)."""

    def write(self, sample: Sample) -> None:
        """Write the sample's lines."""
        try:
            self.f.write("\n".join(sample_lines(sample)) + "\n")
        except OSError as e:
            raise self._failed(e) from None

    def event(self, e: Event) -> None:
        """Write the event's line."""
        try:
            self.f.write(event_line(e) + "\n")
        except OSError as err:
            raise self._failed(err) from None
