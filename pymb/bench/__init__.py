"""``pymb bench``: pymb against the Modbus stacks a user would pick instead,
side by side in one run, against pymb's simulators over pseudo-terminals.

Each contender runs in its own long-lived process (its CPU is its own) with
its own simulator process; rounds are interleaved so machine drift hits all
alike; the figures are medians and ratios to a plain C program on libmodbus.
See :mod:`pymb.bench.cli` for the command and :mod:`pymb.bench.runner` for
what is measured.
"""

from __future__ import annotations

__all__: list[str] = []
