"""The ``pymb`` subcommands, one module each (see :mod:`pymb.cli`)."""
