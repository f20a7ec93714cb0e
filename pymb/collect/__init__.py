"""The central side of a fleet: ``pymb collect`` (``pymb.collect/1``).

Boards publish with ``pymb log --mqtt``; a :class:`~pymb.collect.collector.Collector`
subscribes (plain JSON, or Sparkplug B as a host application) with a
persistent session, stores each value once in ``pymb_values``
(:mod:`pymb.collect.sqlstore`: SQLite or PostgreSQL) and acknowledges a
message only after its rows are committed. Several collectors share the
stream through an MQTT shared subscription (``--share``). Needs the extra
``pymb-modbus[collect]`` (paho-mqtt 2.x and, for PostgreSQL, psycopg 3).
"""

from __future__ import annotations

from pymb.collect.collector import CollectConfig, Collector, CollectStats
from pymb.collect.sqlstore import Store, open_store

__all__ = ["CollectConfig", "CollectStats", "Collector", "Store", "open_store"]
