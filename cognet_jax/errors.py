"""Errors caused by what a user gave the library (a config field, a file), as opposed to bugs.

Every such error derives from ``InputError``; its ``str()`` is one line that names the field or
the file (and line). The CLI prints exactly that line and exits with status 2
(``cognet_jax.cli``); ``--debug`` shows the traceback. This module imports nothing but the
standard library, so the ``.dpomdp`` parser (``cognet_jax.io.dpomdp``) stays free of JAX.
"""

from __future__ import annotations

import json
import re
from pathlib import Path


class InputError(ValueError):
    """Base class of the errors a user can fix by changing their input."""


class CorruptFileError(InputError):
    """A file the library wrote earlier (results, policy, checkpoint, VAE) cannot be read back:
    truncated, edited, or of another kind. ``path`` and ``reason`` are kept."""

    def __init__(self, path: str | Path, reason: str):
        self.path, self.reason = str(path), reason
        super().__init__(f"{path}: corrupt or not a cognet-jax file ({reason})")


class MismatchError(InputError):
    """A saved policy or checkpoint does not fit the model or settings it is asked to run with."""


class UsageError(InputError):
    """A command-line argument out of range (one line, exit 2)."""


class SimulatorError(InputError):
    """A simulator's ``reset`` or ``step`` fails, or returns arrays of other shapes or types than
    its declared sizes (``envs.base.check_simulator``): the simulator's code, not this library."""


class OneLineWarning(UserWarning):
    """A warning the command line prints as one ``warning:`` line."""


class ConfigWarning(OneLineWarning):
    """A setting that has no effect as given (the run goes on)."""


class SimulatorWarning(OneLineWarning):
    """A simulator that works but will make a search slow or noisy (``check_simulator``); the
    command line prints it as one ``warning:`` line."""


class ResourceError(InputError):
    """A setting asks for more memory than the budget allows (one line, with the numbers)."""


def read_json(path: str | Path, required: tuple[str, ...] = ()) -> dict:
    """The JSON object in ``path``; ``CorruptFileError`` if it is not valid JSON, not an object,
    or lacks one of the ``required`` keys (a missing file raises ``FileNotFoundError``)."""
    path = Path(path)
    text = path.read_bytes()
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise CorruptFileError(path, f"not valid JSON: {err}") from None
    if not isinstance(data, dict):
        raise CorruptFileError(path, "expected a JSON object")
    missing = [k for k in required if k not in data]
    if missing:
        raise CorruptFileError(path, f"missing {', '.join(missing)}")
    return data


#: a frame of a Python traceback as XLA quotes it in a failed callback's error message
_FRAME = re.compile(r'File "([^"]+)", line (\d+), in ([\w<>.]+)')


def callback_failure(err: BaseException) -> str | None:
    """``FILE:LINE in FUNCTION(): ERROR`` of the innermost frame quoted in ``err``'s message,
    when ``err`` is XLA's report of a Python callback (``jax.pure_callback``, ...) that raised;
    ``None`` otherwise."""
    text = " ".join(str(err).split())
    if "callback" not in text.lower():
        return None
    frames = list(_FRAME.finditer(text))
    if not frames:
        return None
    last = frames[-1]
    error = text[last.end() :].strip() or "an error"
    return f"{last.group(1)}:{last.group(2)} in {last.group(3)}(): {error}"
