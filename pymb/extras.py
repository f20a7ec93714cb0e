"""pymb's distribution name and its optional extras, for install hints.

The import name and the command are ``pymb``; the distribution is
``pymb-modbus``, installed from a clone or an sdist (it is not published on
PyPI, and PyPI's ``pymb`` is an unrelated project, so no message ever tells
anyone to install either by name). A hint therefore names the extra's own
packages, installed by the Python that runs pymb: a command that works
whichever way pymb was installed.
"""

from __future__ import annotations

import importlib.metadata
import re
import shlex
import sys

__all__ = ["DISTRIBUTION", "extra_requirements", "install_hint"]

#: The name pymb is installed by (``pyproject.toml``'s ``[project] name``).
DISTRIBUTION = "pymb-modbus"


def extra_requirements(extra: str) -> list[str]:
    """The requirements (``matplotlib>=3.7``) of pymb's optional ``extra``, from
    the installed distribution's metadata; empty when pymb runs uninstalled."""
    try:
        requires = importlib.metadata.requires(DISTRIBUTION) or []
    except importlib.metadata.PackageNotFoundError:
        return []
    marker = re.compile(rf"""\bextra\s*==\s*["']{re.escape(extra)}["']""")
    return [r.split(";", 1)[0].strip() for r in requires
            if ";" in r and marker.search(r.split(";", 1)[1])]


def install_hint(extra: str) -> str:
    """A command that installs pymb's optional ``extra``: its packages, by
    the Python that runs pymb (``/path/.venv/bin/python -m pip install
    'matplotlib>=3.7'``); from a clone, ``pip install '.[EXTRA]'`` does the same."""
    reqs = extra_requirements(extra)
    if not reqs:
        return f"pip install '.[{extra}]' in pymb's clone"
    return " ".join([shlex.quote(sys.executable), "-m", "pip", "install",
                     *(shlex.quote(r) for r in reqs)])
