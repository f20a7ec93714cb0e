"""``pymb config coolpro[:ADDRESS]``: change a CoolPro's address or baud rate, safely.

Validated before any write, confirmed (``--yes`` to skip), and verified by
reading the configuration back from the new address at the new rate after
the reset.
"""

from __future__ import annotations

import argparse
import sys
import time

from pymb.client import RtuClient
from pymb.commands._common import (
    add_connection_args,
    add_device_arg,
    device_from_args,
    make_client,
)
from pymb.devices import CoolPro
from pymb.devices.coolpro import COOLPRO_BAUD_RATES
from pymb.errors import InvalidArgument, ModbusConnectionError, ModbusError

VERIFY_FOR = 5.0  # seconds to wait for the device to come back after a reset


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb config``."""
    add_device_arg(p, hub_options=False)
    add_connection_args(p)
    p.add_argument("--set-address", type=int, metavar="N", help="new address, 1..247")
    p.add_argument("--set-baud", type=int, metavar="BPS",
                   help=f"new baud rate: {', '.join(map(str, COOLPRO_BAUD_RATES))}")
    p.add_argument("--reset", action="store_true",
                   help="reset the device so the changes take effect, then verify")
    p.add_argument("--yes", action="store_true", help="do not ask for confirmation")


def _confirm(question: str) -> bool:
    if not sys.stdin.isatty():
        raise InvalidArgument(f"{question} needs confirmation: run it on a terminal or add --yes")
    try:
        answer = input(f"{question} [y/N] ")
    except EOFError:  # Ctrl-D: no
        print()
        return False
    except KeyboardInterrupt:  # Ctrl-C: the shell's prompt on a line of its own
        print()
        raise
    return answer.strip().lower() in ("y", "yes")


def run(args: argparse.Namespace) -> int:
    """Show, change, reset and verify; Ctrl-C once a write may have gone out
    says what the device may hold (exit 130)."""
    changes = _validate(args)  # everything is checked before any I/O
    left: list[str] = []  #: what the device may hold if interrupted now
    try:
        return _run(args, changes, left)
    except KeyboardInterrupt:
        if left:
            print(f"pymb config: interrupted; {left[-1]}", file=sys.stderr)
        raise


def _run(args: argparse.Namespace, changes: list[str], left: list[str]) -> int:
    with make_client(args) as client:
        cp = CoolPro(client, args.address)
        cfg = cp.read_config()
        print(f"CoolPro at {args.address} on {client.port}: stored address {cfg.address}, "
              f"baud rate {cfg.baud_rate}")
        if not changes and not args.reset:
            return 0
        new_address = args.set_address or cfg.address
        new_baud = args.set_baud or cfg.baud_rate or args.baud
        done = _write_and_reset(args, cp, changes, left,
                                f"address {new_address}, {new_baud} bit/s")
        if done is not None:
            return done
    # After the reset the device answers at the stored address and rate
    # (those just written, or those written earlier and read back above).
    return _verify(args, new_address, new_baud)


def _validate(args: argparse.Namespace) -> list[str]:
    """Check the device and the new settings; the changes, in words."""
    dev = device_from_args(args)
    if dev.map.device.view != "coolpro":  # its settings are written through the CoolPro view
        raise InvalidArgument(f"pymb config changes a CoolPro's settings, not a {dev.type}'s: "
                              "pymb config coolpro[:ADDRESS] ...")
    assert dev.address is not None
    args.address = dev.address
    low, high = CoolPro.ADDRESSES
    if args.set_address is not None and not low <= args.set_address <= high:
        raise InvalidArgument(f"--set-address must be {low}..{high}, got {args.set_address}")
    if args.set_baud is not None and args.set_baud not in COOLPRO_BAUD_RATES:
        raise InvalidArgument(f"--set-baud must be one of {list(COOLPRO_BAUD_RATES)}, "
                              f"got {args.set_baud}")
    changes = []
    if args.set_address is not None:
        changes.append(f"address {args.address} -> {args.set_address}")
    if args.set_baud is not None:
        changes.append(f"baud rate -> {args.set_baud}")
    return changes


def _write_and_reset(args: argparse.Namespace, cp: CoolPro, changes: list[str],
                     left: list[str], after: str) -> int | None:
    """Confirm, write and reset; the exit code when there is nothing to
    verify, None when the device was reset. ``left`` is told what the device
    may hold at each step, ``after`` where it answers after the reset."""
    steps = changes + (["then reset the device"] if changes and args.reset else
                       ["reset the device"] if args.reset else [])
    if not args.yes and not _confirm(f"CoolPro {args.address}: {'; '.join(steps)}?"):
        print("nothing written")
        return 1
    if changes:
        left.append("the new settings may or may not have been stored; stored settings take "
                    f"effect at the device's next reset (pymb config coolpro:{args.address} "
                    "reads them)")
    if args.set_address is not None:
        cp.set_address(args.set_address)
    if args.set_baud is not None:
        cp.set_baud_rate(args.set_baud)
    if args.reset:  # said before the lines that show the step, so a Ctrl-C after one knows
        left.append(f"the reset may or may not have been sent: the CoolPro answers at "
                    f"{after} once reset")
    if changes:
        print("written: " + "; ".join(changes))
    if not args.reset:
        if changes:
            print("the changes take effect after a reset: run again with --reset")
        return 0
    cp.reset()
    left.append(f"the reset was sent: the CoolPro answers at {after} once it restarts")
    print("reset sent")
    return None


def _verify(args: argparse.Namespace, new_address: int, new_baud: int) -> int:
    """Wait for the device to answer at its new address and rate."""
    deadline = time.monotonic() + VERIFY_FOR
    last: Exception | None = None
    while time.monotonic() < deadline:
        time.sleep(0.2)
        client2 = make_client(args)
        if isinstance(client2, RtuClient) and new_baud != args.baud and args.port:
            client2 = RtuClient(args.port, new_baud, args.parity, timeout=args.timeout)
        try:
            with client2:
                cfg = CoolPro(client2, new_address).read_config()
                tele = CoolPro(client2, new_address).read_telemetry()
        except ModbusConnectionError:
            raise
        except ModbusError as e:
            last = e
            continue
        ok = cfg.address == new_address and cfg.baud_rate == new_baud
        print(f"verified: the CoolPro answers at address {new_address}, {new_baud} bit/s "
              f"(uptime {tele.uptime_s} s)" if ok else
              f"MISMATCH: the device reports address {cfg.address}, baud {cfg.baud_rate}")
        return 0 if ok else 3
    print(f"the CoolPro did not answer at address {new_address}, {new_baud} bit/s within "
          f"{VERIFY_FOR:g} s after the reset: {last}", file=sys.stderr)
    return 3
