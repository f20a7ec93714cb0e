"""``python -m pymb``: the same as the ``pymb`` command."""

import sys

from pymb.cli import main

sys.exit(main())
