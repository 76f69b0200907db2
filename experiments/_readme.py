"""Shared helpers of the experiment scripts: the machine line and replacing one generated block
of experiments/README.md (between ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->``)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

README = Path(__file__).resolve().parent / "README.md"


def machine() -> str:
    return (
        f"{platform.machine()}, {platform.processor() or 'cpu'}, {os.cpu_count()} logical CPUs, "
        f"Python {platform.python_version()}"
    )


def replace_block(name: str, body: str, readme: Path = README) -> None:
    """Write ``body`` between the block's markers, appending the block if it is missing."""
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    text = readme.read_text() if readme.exists() else "# Experiments\n"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        _, tail = rest.split(end, 1)
    else:
        head, tail = text.rstrip("\n") + "\n\n", "\n"
    readme.write_text(f"{head}{begin}\n{body.rstrip()}\n{end}{tail}")
    print(f"wrote the {name} block of {readme}")


def finish_of(results: dict) -> dict:
    """A results.json record's ``finish`` (``polish`` in runs saved before the name; ``{}`` for
    a run without one)."""
    return results.get("finish", results.get("polish")) or {}
