"""A plain write command nested deeper than the json module recurses is
answered ``invalid``, as any command that is not JSON."""

from __future__ import annotations

import json
import sqlite3

from pymb.logger.commands import CommandDesk
from pymb.store.commands import CommandLog


def test_a_command_nested_too_deep_gets_an_invalid_result() -> None:
    db = sqlite3.connect(":memory:", isolation_level=None)
    desk = CommandDesk(CommandLog(lambda f, durable: f(db)), {}, [], lambda text: None)
    deep = b'{"id": "c-1", "values": ' + b"[" * 100000 + b"]" * 100000 + b"}"
    out = desk.run_command("mqtt", "dev", deep)
    assert out is not None
    doc = json.loads(out)
    assert (doc["ok"], doc["reason"], doc["error"]) == (False, "invalid", "not a JSON object")
