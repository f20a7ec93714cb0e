"""The status line of ``pymb log`` and ``pymb demo`` on the terminal: one line,
redrawn in place, that always fits."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TextIO

from pymb.logger import Logger

__all__ = ["StatusLine", "status_text"]


def status_text(logger: Logger, elapsed: float) -> str:
    """The one-line status: samples, rate, faults, skipped slots, time, state."""
    s = logger.stats
    rate = s.samples / elapsed if elapsed > 0 else 0.0
    skipped = (f"  skipped {s.skipped_slots}"
               if s.skipped_slots or any(b.interval > 0 for b in logger.config.buses) else "")
    with s.lock:
        gone = sum(len(v) for v in s.unsupported.values())
        down = [n for n, k in s.device_faults.items() if k and n in s.problems]
    health = f"  unsupported {gone}" if gone else ""
    if down:
        health += f"  failing {len(down)}: {', '.join(down[:3])}" + (
            f" +{len(down) - 3}" if len(down) > 3 else "")
    return (f"{s.samples:,} samples  {rate:,.1f}/s  faults {s.faults}{skipped}{health}  "
            f"{elapsed:.1f} s  {s.status}")


class StatusLine:
    """A :class:`~pymb.logger.Logger`'s ``tick``: the status line on ``out``
    (redrawn in place on a terminal; elsewhere only the final one), with
    ``extra()`` appended (the forwarder's part)."""

    def __init__(self, out: TextIO | None, extra: Callable[[], str] | None = None) -> None:
        self.out = out
        self.extra = extra

    def __call__(self, logger: Logger, elapsed: float, final: bool) -> None:
        """Draw the line (the last time when ``final``)."""
        out = self.out
        if out is None:
            return
        line = status_text(logger, elapsed)
        if self.extra is not None:
            line += "  " + self.extra()
        try:
            if out.isatty():
                # One line that fits: a line that wrapped could not be redrawn in place.
                try:  # a serial console says 0 columns: as none
                    width = os.get_terminal_size(out.fileno()).columns or 80
                except (OSError, ValueError):
                    width = 80
                if len(line) > width - 1:
                    line = line[:max(0, width - 2)] + "…"
                out.write("\r\x1b[K" + line + ("\n" if final else ""))
            elif final:
                out.write(line + "\n")
            out.flush()
        except OSError:
            self.out = None  # the terminal went away: keep logging
