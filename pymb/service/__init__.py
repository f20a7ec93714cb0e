"""Running ``pymb log`` as a service: systemd's notify protocol
(:mod:`pymb.service.notify`), events as journal lines
(:mod:`pymb.service.journal`), wall-clock steps (:mod:`pymb.service.clock`)
and SIGHUP as a reload (:mod:`pymb.service.reload`). No dependency: the
unit file is ``contrib/pymb.service``, the guide ``docs/board.md``.
"""
