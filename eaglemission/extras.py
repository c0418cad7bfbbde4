"""Optional parts of the install (pyproject's extras) and the one-line error when one is missing.

A plugin class that needs an extra says so with ``extra = "mavsdk"`` (a name of
:data:`EXTRAS`); a command that needs one calls :func:`require` before it starts. Presence is
checked with :func:`importlib.util.find_spec` (nothing is imported), so the check is cheap and
a missing extra is reported before anything connects or opens.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Iterable

from eaglemission.errors import PluginError

EXTRAS: dict[str, tuple[str, ...]] = {
    "mavsdk": ("mavsdk", "pymavlink"),
    "genicam": ("harvesters", "genicam"),
    "live": ("foxglove",),
    "ray": ("ray",),
}
"""Extra -> the top-level modules it installs (pyproject ``[project.optional-dependencies]``)."""


class MissingExtra(PluginError):
    """An optional dependency is not installed: the message names the extra to install."""

    def __init__(self, extra: str, what: str, missing: list[str]) -> None:
        self.extra, self.what, self.missing = extra, what, missing
        super().__init__(f"{what} needs the [{extra}] extra ({', '.join(missing)} not "
                         f"installed): pip install 'eaglemission[{extra}]'")


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a broken or half-removed package
        return False


def missing(extra: str) -> list[str]:
    """The modules of ``extra`` that are not installed (empty: all there)."""
    return [m for m in EXTRAS[extra] if not _installed(m)]


def require(extra: str, what: str) -> None:
    """Raise :class:`MissingExtra` when ``extra`` is not fully installed; ``what`` names the
    command or plugin that needs it (``"sitl-vehicle"``, ``"vehicle.type mavsdk"``)."""
    gone = missing(extra)
    if gone:
        raise MissingExtra(extra, what, gone)


def require_for(parts: Iterable[tuple[str, object]]) -> None:
    """:func:`require` for each ``(what, plugin class)`` that declares an ``extra``."""
    for what, cls in parts:
        extra = getattr(cls, "extra", None)
        if isinstance(extra, str) and extra in EXTRAS:
            require(extra, what)
