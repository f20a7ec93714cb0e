"""``pymb bench``: pymb against the stacks a user would pick instead.

With no arguments it runs everything (a few minutes on 2 cores) and prints
the side-by-side table; ``--json`` and ``--markdown`` print the same result
for machines and for docs/benchmarks.md; ``--plot FILE.png`` draws the bars.
Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys

from pymb.bench import report, runner
from pymb.bench.contenders import NAMES
from pymb.bench.options import EXTRA_SECTIONS
from pymb.bench.runner import SECTIONS, Options
from pymb.errors import InvalidArgument
from pymb.extras import install_hint

__all__ = ["add_arguments", "run"]


def _names(text: str, allowed: tuple[str, ...], what: str) -> tuple[str, ...]:
    names = tuple(n.strip().lower() for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in allowed]
    if bad or not names:
        raise InvalidArgument(f"--{what} takes names from {', '.join(allowed)}; "
                              f"got {text!r}")
    return tuple(n for n in allowed if n in names)


def _drawn_by_bench(path: str) -> bool:
    """Whether ``path`` is an image ``pymb bench --plot`` drew (its metadata says so)."""
    try:
        with open(path, "rb") as f:
            return report.PLOT_MARK.encode() in f.read(8192)
    except OSError:
        return False


def check_plot(path: str, sections: tuple[str, ...]) -> None:
    """Fail now, not after minutes of measuring, if the bars cannot go to ``path``:
    a name matplotlib would not draw as PNG or SVG, sections with no bars, a path
    that cannot be written, or a file pymb bench did not draw (never overwritten)."""
    if os.path.isdir(path):
        raise InvalidArgument(f"--plot {path} is a directory; give a file name")
    if os.path.splitext(path)[1].lower() not in report.PLOT_FORMATS:
        raise InvalidArgument(f"--plot {path}: the file name must end in .png or .svg")
    if not {"sweep", "micro"} & set(sections):
        raise InvalidArgument(f"--plot draws the sweep and micro sections: add one of them "
                              f"to --sections {','.join(sections)}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise InvalidArgument(f"--plot {path}: no such directory {folder}")
    if not os.access(path if os.path.exists(path) else folder, os.W_OK):
        raise InvalidArgument(f"--plot {path}: permission denied")
    if os.path.exists(path) and not _drawn_by_bench(path):
        raise InvalidArgument(f"--plot {path} exists and is not an image pymb bench drew: "
                              "refusing to overwrite it; give another name")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The command's options."""
    parser.add_argument("--quick", action="store_true",
                        help="fewer rounds and shorter runs (a smoke test, not a measurement)")
    parser.add_argument("--only", metavar="NAME[,NAME]",
                        help=f"contenders to run, from {','.join(NAMES)} (default: all); "
                             "ratios need c")
    parser.add_argument("--sections", metavar="NAME[,NAME]",
                        help=f"what to measure, from {','.join(SECTIONS)} (default: all), "
                             f"or {','.join(EXTRA_SECTIONS)} (only when named: a 30-minute soak; "
                             "a fleet into SQLite and PostgreSQL)")
    parser.add_argument("--rounds", type=int, metavar="N",
                        help="interleaved rounds of the sweep comparison (default 20, --quick 3; "
                             "the wire-bound one does at most 6, at 9600 baud at most 3)")
    out = parser.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="print the result as JSON")
    out.add_argument("--markdown", action="store_true",
                     help="print the result as Markdown (docs/benchmarks.md's tables)")
    parser.add_argument("--plot", metavar="FILE.png",
                        help="also draw the bars of the sweep and micro sections side by side, "
                             "to FILE.png or FILE.svg (needs matplotlib; never over a file "
                             "pymb bench did not draw)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")


def _command(args: argparse.Namespace) -> str:
    argv = sys.argv[1:]
    if argv[:1] == ["bench"]:
        return shlex.join(["pymb", *argv])
    words = ["pymb", "bench"]
    if args.quick:
        words.append("--quick")
    for flag in ("only", "sections", "rounds", "plot"):
        value = getattr(args, flag)
        if value is not None:
            words += [f"--{flag}", str(value)]
    words += [f"--{f}" for f in ("json", "markdown", "quiet") if getattr(args, f)]
    return shlex.join(words)


def run(args: argparse.Namespace) -> int:
    """Run the bench as the options say; 0 when it ran (targets missed or not)."""
    if args.rounds is not None and not 1 <= args.rounds <= 1000:
        raise InvalidArgument(f"--rounds must be 1..1000, got {args.rounds}")
    only = _names(args.only, NAMES, "only") if args.only else NAMES
    sections = _names(args.sections, SECTIONS + EXTRA_SECTIONS, "sections") \
        if args.sections else SECTIONS
    if args.plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise InvalidArgument(
                f"--plot needs matplotlib: {install_hint('bench')}") from None
        check_plot(args.plot, sections)

    def progress(text: str) -> None:
        print(f"pymb bench: {text}", file=sys.stderr, flush=True)

    opts = Options(quick=args.quick, only=only, rounds=args.rounds, sections=sections,
                   command=_command(args), progress=None if args.quiet else progress)
    result = runner.run(opts)
    if args.json:
        sys.stdout.write(report.to_json(result))
    elif args.markdown:
        sys.stdout.write(report.to_markdown(result))
    else:
        sys.stdout.write(report.to_text(result))
    if args.plot:
        report.plot(result, args.plot)
        if not args.quiet:
            progress(f"bars drawn in {args.plot}")
    return 0
