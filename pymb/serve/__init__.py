"""``pymb serve``: a Modbus TCP server (plain, or Modbus/TCP Security over TLS)
in front of one upstream line, so that many clients share one serial bus or
one device that accepts a single connection.

Requests are taken and checked by the C core (:mod:`pymb._native.serve`),
routed by unit id (:class:`UnitMap`), and sent upstream: one transaction at
a time by one thread that owns a serial line (:class:`Upstream`), or several
in flight at once to a Modbus TCP upstream (:class:`PipelinedUpstream`);
each client's transaction ids are kept. With TLS, a client's role comes from its
certificate (:mod:`pymb.serve.roles`) and only the roles named may write.
"""

from __future__ import annotations

from pymb.serve.pipeline import PipelinedUpstream
from pymb.serve.roles import ROLE_OID, role_of
from pymb.serve.server import Server, ServeStats, UnitMap
from pymb.serve.upstream import Upstream

__all__ = ["ROLE_OID", "PipelinedUpstream", "ServeStats", "Server", "UnitMap", "Upstream",
           "role_of"]
