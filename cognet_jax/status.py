"""One channel for the status lines of a phase that runs before any progress bar (a search
sizing itself, a measurement with its compile): ``say(line)``. The command line sets
``listener`` to print them on standard error; a program that embeds the library hears nothing
unless it sets one."""

from __future__ import annotations

from collections.abc import Callable

#: called with each line; ``None``: silent (a library)
listener: Callable[[str], None] | None = None


def say(line: str) -> None:
    """Pass ``line`` to the ``listener``, if any."""
    if listener is not None:
        listener(line)
