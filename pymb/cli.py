"""The ``pymb`` command (also ``python -m pymb``).

Each subcommand lives in its own module, which provides ``add_arguments(parser)``
and ``run(args) -> int``; this file only wires them together and turns
pymb's errors into messages and exit codes (no traceback for a user mistake).
"""

from __future__ import annotations

import argparse
import codecs
import contextlib
import difflib
import importlib
import io
import os
import re
import shlex
import sys
from collections.abc import Sequence

from pymb import __version__
from pymb.errors import (
    InvalidArgument,
    ModbusConnectionError,
    ModbusError,
    OutputError,
    WriteRefused,
    closest_hint,
)

__all__ = [
    "EXIT_CONNECTION",
    "EXIT_DEVICE",
    "EXIT_INTERRUPTED",
    "EXIT_OUTPUT",
    "EXIT_PIPE",
    "EXIT_USAGE",
    "main",
]

EXIT_USAGE = 2  #: bad arguments or configuration
EXIT_DEVICE = 3  #: the device answered wrongly, or not at all
EXIT_CONNECTION = 4  #: the port or connection failed
EXIT_OUTPUT = 5  #: logged data could not be written (disk full, read-only)
EXIT_INTERRUPTED = 130  #: Ctrl-C (128 + SIGINT)
EXIT_PIPE = 141  #: the reader of stdout went away (128 + SIGPIPE), said nothing

#: exception -> exit code, most specific first
_EXIT_CODES: tuple[tuple[type[BaseException], int], ...] = (
    (InvalidArgument, EXIT_USAGE),
    (WriteRefused, EXIT_USAGE),
    (ModbusConnectionError, EXIT_CONNECTION),
    (OutputError, EXIT_OUTPUT),
    (ModbusError, EXIT_DEVICE),
)

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("pymb.commands.demo", "log simulated devices for a few seconds (no hardware)"),
    "read": ("pymb.commands.read", "one reading of a device (CoolPro, sensor hub or a map's)"),
    "watch": ("pymb.commands.watch", "readings refreshed live, with the achieved rate"),
    "log": ("pymb.commands.log",
            "log devices on one or more buses to SQLite, CSV, JSON Lines or InfluxDB"),
    "collect": ("pymb.commands.collect",
                "store what a fleet's boards publish to MQTT in SQLite or PostgreSQL"),
    "export": ("pymb.commands.export", "export a logged SQLite database as CSV"),
    "info": ("pymb.commands.info", "what a logged database holds: devices, span, faults, sizes"),
    "salvage": ("pymb.commands.salvage",
                "copy every readable row of a damaged database into a new one"),
    "plot": ("pymb.commands.plot", "plot a quantity of a logged device to PNG or SVG"),
    "scan": ("pymb.commands.scan", "find the devices that answer on a bus"),
    "write": ("pymb.commands.write", "write points of a device, checked and read back"),
    "config": ("pymb.commands.config", "change a CoolPro's address or baud rate, verified"),
    "map": ("pymb.commands.map", "check, list or show device maps; probe a device's registers"),
    "serve": ("pymb.commands.serve", "share one bus with many Modbus TCP clients (and TLS)"),
    "simulate": ("pymb.commands.simulate",
                 "simulate devices (CoolPro, sensor hub, maps) on a pty or TCP"),
    "bench": ("pymb.bench.cli", "benchmark pymb against other Modbus stacks, side by side"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser. Only ``command``'s module is imported (all of them
    when ``command`` is None): ``pymb read`` and ``pymb log`` never load the
    simulators or the benchmark, which matters on a small board."""
    parser = argparse.ArgumentParser(
        prog="pymb", description="Modbus RTU for real devices, fast."
    )
    parser.add_argument("--version", action="version", version=f"pymb {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if command is None or name == command:
            mod = importlib.import_module(module)
            mod.add_arguments(p)
            p.set_defaults(command_module=mod, command_parser=p)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    _unicode_or_replace()
    # The subcommand is the first word that is not an option (pymb's own
    # options take no value), so only its module is imported.
    command = next((a for a in args_in if not a.startswith("-")), "")
    try:
        parser = build_parser(command if command in COMMANDS else "")
        _options_before_the_command(parser, args_in)
        _misspelt_command(parser, args_in)
        args, extra = parser.parse_known_args(args_in)
    except KeyboardInterrupt:  # Ctrl-C while the command's module loads
        return EXIT_INTERRUPTED
    if extra:
        _unrecognized(parser, args, extra)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    try:
        code = int(args.command_module.run(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return code
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except RuntimeError as e:
        # Ctrl-C at the wrong moment of the main thread's wait in the stdlib's
        # lock code (threading.Condition, under queue.Queue.get, Event.wait,
        # Thread.start) leaves the lock released, and the with block's second
        # release turns the KeyboardInterrupt into this (CPython gh-118433).
        if isinstance(e.__context__, KeyboardInterrupt) and "unlocked lock" in str(e):
            return EXIT_INTERRUPTED
        raise
    except BrokenPipeError:
        return _reader_gone()
    except (ModbusError, OutputError) as e:
        with contextlib.suppress(OSError):
            print(f"pymb {args.command}: {e}", file=sys.stderr)
        return next(code for cls, code in _EXIT_CODES if isinstance(e, cls))


def _options_before_the_command(parser: argparse.ArgumentParser, args_in: list[str]) -> None:
    """Exit 2 for a command's options given before it (``pymb --port
    /dev/ttyUSB0 read coolpro``), with the command line in its order."""
    at = next((i for i, a in enumerate(args_in) if a in COMMANDS), 0)
    if at and args_in[0].startswith("-") and not {"-h", "--help", "--version"} & {
            a.split("=", 1)[0] for a in args_in[:at]}:
        fixed = shlex.join(["pymb", *args_in[at:], *args_in[:at]])
        parser.error(f"options go after the command: {fixed}")


def _misspelt_command(parser: argparse.ArgumentParser, args_in: list[str]) -> None:
    """Exit 2 for a mistyped command with the closest one (``pymb reed``:
    did you mean 'read'?); a word close to none is argparse's to refuse."""
    if args_in and args_in[0] not in COMMANDS and not args_in[0].startswith("-"):
        hint = closest_hint(args_in[0], COMMANDS, cutoff=0.6)
        if hint:
            parser.error(f"unknown command {args_in[0]!r}{hint}")


def _unicode_or_replace() -> None:
    """A stdout that cannot write every character (``PYTHONIOENCODING=ascii``,
    a Latin-1 terminal) shows ``?`` for a unit's ``°`` or an ellipsis instead
    of ending the command with UnicodeEncodeError."""
    out = sys.stdout
    if isinstance(out, io.TextIOWrapper) and codecs.lookup(out.encoding).name != "utf-8":
        with contextlib.suppress(ValueError, OSError):
            out.reconfigure(errors="replace")


def _unrecognized(parser: argparse.ArgumentParser, args: argparse.Namespace,
                  extra: Sequence[str]) -> None:
    """Exit 2 for words the command does not take, in the command's own
    usage and name, with the closest option it does take."""
    target: argparse.ArgumentParser = getattr(args, "command_parser", parser)
    message = f"unrecognized arguments: {' '.join(extra)}"
    options = sorted(set(re.findall(r"(?<![\w-])--([a-z][\w-]*)", target.format_help())))
    for word in extra:
        if word.startswith("--"):
            close = difflib.get_close_matches(word[2:].split("=", 1)[0], options, n=1,
                                              cutoff=0.8)
            if close:
                message += f"; did you mean --{close[0]}?"
                break
    target.error(message)


def _reader_gone() -> int:
    """stdout's reader went away (``pymb read ... | head``): stop quietly, as
    Unix tools do, and keep Python from complaining about it at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass
    return EXIT_PIPE


if __name__ == "__main__":
    sys.exit(main())
