"""What the whole test suite shares: one root, one subprocess environment,
one timeout, and the fixtures more than one file uses.

The helpers here are imported by name (``from conftest import ROOT``): the
tests directory is on the path, as it is for peers.py and reference.py.
"""

from __future__ import annotations

import os
from pathlib import Path

#: The source checkout: ``python -m pymb`` children run this pymb.
ROOT = Path(__file__).resolve().parents[1]

#: The environment of a ``python -m pymb`` child: this checkout first on the path.
PYMB_ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(
    p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))

#: A client's reply timeout where a test waits for one to pass: short, so the
#: suite stays fast; longer under valgrind or qemu (PYMB_TEST_TIMEOUT).
TIMEOUT = float(os.environ.get("PYMB_TEST_TIMEOUT", "0.25"))
