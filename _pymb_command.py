"""The ``pymb`` command's entry point, outside the ``pymb`` package: Ctrl-C
while pymb itself loads (the package, its C extension) ends the command
with exit code 130 and no traceback, as at any later moment. The command
line is ``pymb.cli``."""

from __future__ import annotations

import signal


def main() -> int:
    """Load ``pymb.cli`` and run it; 130 for a Ctrl-C while it loads."""
    try:
        from pymb.cli import main as run
    except KeyboardInterrupt:
        return 128 + signal.SIGINT
    return run()


if __name__ == "__main__":
    raise SystemExit(main())
