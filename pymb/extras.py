"""pymb's distribution name and its optional extras, for install hints.

The import name and the command are ``pymb``; the distribution is
``pymb-modbus``. PyPI's ``pymb`` is an unrelated project, so no message ever
tells anyone to install that.
"""

from __future__ import annotations

__all__ = ["DISTRIBUTION", "install_hint"]

#: The name pymb is installed by (``pyproject.toml``'s ``[project] name``).
DISTRIBUTION = "pymb-modbus"


def install_hint(extra: str) -> str:
    """The pip command that installs pymb's optional ``extra``."""
    return f"pip install '{DISTRIBUTION}[{extra}]'"
