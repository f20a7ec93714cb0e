"""``pymb plot DB DEVICE QUANTITY``: one quantity of a logged device over
time, as a PNG or SVG file of a given size (matplotlib: the ``plot`` extra).

Never overwrites a file pymb did not write (``--force`` to do it anyway):
the image carries ``pymb plot`` in its metadata, and it is written beside
its path and renamed into place only when complete."""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
from datetime import UTC, datetime
from typing import Any, cast

from pymb.commands._data import check_database, parse_times
from pymb.errors import InvalidArgument
from pymb.extras import install_hint
from pymb.store import Series, series
from pymb.store.files import write_beside

__all__ = ["add_arguments", "figure", "parse_size", "run"]

MARK = "pymb plot"  #: in every image's metadata: an image pymb wrote may be replaced
DPI = 100
FORMATS = (".png", ".svg")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb plot``."""
    p.add_argument("database", help="a database written by pymb log / pymb demo")
    p.add_argument("device", help="the device: its name (e.g. hub-250) or TYPE[:ADDRESS]")
    p.add_argument("quantity", help="e.g. temperature_c, humidity_pct, output_voltage_v")
    p.add_argument("--channel", type=int, help="the hub channel (a hub needs one)")
    p.add_argument("--since", help="from this time on (ISO 8601, UTC unless it says otherwise)")
    p.add_argument("--until", help="before this time (ISO 8601)")
    p.add_argument("-o", "--out", metavar="FILE",
                   help="FILE.png or FILE.svg (default: DEVICE-QUANTITY[-chN].png here)")
    p.add_argument("--size", default="1000x500", metavar="WxH",
                   help="the image's size in pixels (default 1000x500)")
    p.add_argument("--force", action="store_true",
                   help="overwrite FILE even if it is not an image pymb plot wrote")


def parse_size(text: str) -> tuple[int, int]:
    """``WxH`` in pixels, each 100..10000."""
    m = re.fullmatch(r"(\d+)x(\d+)", text.strip())
    if m is None or not all(100 <= int(v) <= 10000 for v in m.groups()):
        raise InvalidArgument(f"--size needs WIDTHxHEIGHT in pixels, each 100..10000 "
                              f"(e.g. 1000x500), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def figure(s: Series, size: tuple[int, int]) -> Any:
    """The plot of ``s`` as a matplotlib Figure of ``size`` pixels (at 100 dpi)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size[0] / DPI, size[1] / DPI), dpi=DPI)
    ax = fig.add_subplot()
    times = [datetime.fromtimestamp(t, UTC) for t in s.times]
    ax.plot(cast(Any, times), s.values, linewidth=1, marker="." if len(times) <= 200 else None)
    where = f"channel {s.channel} " if s.channel is not None else ""
    ax.set_title(f"{s.device} {where}{s.quantity}")
    ax.set_ylabel(f"{s.quantity} [{s.unit}]" if s.unit else s.quantity)
    ax.set_xlabel("time (UTC)")
    ax.grid(True, alpha=0.3)
    fig.autofmt_xdate()
    return fig


def _mine(path: str) -> bool:
    """Whether ``path`` is an image ``pymb plot`` wrote (its metadata says so)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8192)
    except OSError:
        return False
    return MARK.encode() in head


def _save(fig: Any, out: str, size: tuple[int, int]) -> None:
    """Write beside ``out``, then rename into place."""
    ext = os.path.splitext(out)[1].lower()

    def write(fd: int, tmp: str) -> None:
        with os.fdopen(fd, "wb") as f:
            if ext == ".png":
                fig.savefig(f, format="png", dpi=DPI, metadata={"Software": MARK})
            else:
                fig.savefig(f, format="svg", metadata={"Creator": MARK})
        if ext == ".svg":
            _svg_pixels(tmp, size)

    write_beside(out, ".pymb-plot-", ext, write, keep_mode=False)


def _svg_pixels(path: str, size: tuple[int, int]) -> None:
    """matplotlib sizes an SVG in points: say the pixels asked for (the
    viewBox keeps the drawing's own units)."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    text = re.sub(r'<svg([^>]*?) width="[^"]*" height="[^"]*"',
                  rf'<svg\1 width="{size[0]}px" height="{size[1]}px"', text, count=1)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)


def run(args: argparse.Namespace) -> int:
    """Read the series, draw it, write the file."""
    size = parse_size(args.size)
    since, until = parse_times(args.since, args.until)
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise InvalidArgument(f"drawing needs matplotlib: {install_hint('plot')}") from None
    out = args.out
    if out is not None:
        if os.path.splitext(out)[1].lower() not in FORMATS:
            raise InvalidArgument(f"-o {out}: the file name must end in .png or .svg")
        if os.path.isdir(out):
            raise InvalidArgument(f"-o {out} is a directory; give a file name")
    check_database(args.database)
    s = series(args.database, args.device, args.quantity, channel=args.channel, since=since,
               until=until)
    span = " in that span" if since or until else ""
    if not s.times:
        raise InvalidArgument(f"no samples of {s.device}'s {s.quantity} in "
                              f"{args.database}{span}")
    if all(math.isnan(v) for v in s.values):
        raise InvalidArgument(f"{s.device}'s {s.quantity} has no value in {args.database}"
                              f"{span}: none of its {len(s.times):,} sample(s) holds one "
                              "(offline, no sensor or unsupported); nothing to draw")
    if out is None:
        out = f"{s.device}-{s.quantity}" + (f"-ch{s.channel}" if s.channel else "") + ".png"
    if os.path.exists(out):
        if os.path.samefile(out, args.database):
            raise InvalidArgument(f"-o {out} is the database: refusing to write onto it")
        if not args.force and not _mine(out):
            raise InvalidArgument(f"{out} exists and is not an image pymb plot wrote: "
                                  "refusing to overwrite it (--force to do it anyway)")
    _save(figure(s, size), out, size)
    print(f"plotted {len(s.times):,} samples of {s.device}'s {s.quantity} to {out}",
          file=sys.stderr)
    return 0
